"""Online calibration: the estimate and its uncertainty after every pose.

Two kinds of engine over the measurement model of the batch solve:

* :class:`ISAM2Engine`: the same GTSAM factors (``factors`` package); each pose adds its joint
  variables and factors, and iSAM2 updates incrementally (QR factorisation, per-variable
  relinearisation thresholds, the parameters' set loose so that their factors are relinearised
  only when the parameters have moved). Probed balls enter as their fitted centres with the
  fit's full covariance (to first order what the probe points say about the centre).
* :class:`KalmanEngine`: a filterpy filter whose state is the parameter vector (random-walk
  process model, drift zero by default). Each pose's measurement is its ball centres (fitted to
  the probe points with the quality checks of ``fgcal measure``, or measured) and/or its pose;
  the joint readings' noise is folded into the measurement noise. ``ekf`` is an iterated EKF
  (a plain EKF was seen to diverge from the nominal start), ``ukf`` an unscented filter.

Both start from the nominal model with the weak prior of :data:`fgcal.calibrate.WEAK_PRIOR`
(before five poses the parameters are not determined by the data). A pose that fails the
quality checks, or whose innovation is implausible, is rejected with the reason and leaves the
state untouched. No I/O here.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import gtsam
import numpy as np

import factors as fx
from .calibrate import WEAK_PRIOR, CalibrationOptions, _sigmas
from .dataset import Dataset
from .errors import FgcalError
from .graph import Sigmas
from .model import ParameterSet, RobotModel
from .spherefit import chi2_quantile, fit_spheres_checked
from .transforms import pose_matrices

__all__ = ["PoseData", "pose_records", "weak_prior", "UpdateReport", "ISAM2Engine", "KalmanEngine", "make_engine"]

log = logging.getLogger(__name__)

INNOVATION_FALSE_ALARM = 1e-6


@dataclass
class PoseData:
    """Everything measured at one pose (file order): joints (rad) and the levels present."""

    pose: int
    q: np.ndarray
    probes: list[tuple[str, np.ndarray]] = field(default_factory=list)  # (ball, points (n, 3))
    centres: list[tuple[str, np.ndarray]] = field(default_factory=list)  # (ball, xyz (3,))
    T: np.ndarray | None = None


def _rows_by_pose(obs, pose_ids):
    """Row indices of ``obs`` per pose id, in file order: one sort, not one scan per pose."""
    if obs is None:
        return {}
    order = np.argsort(obs.pose, kind="stable")
    sorted_pose = obs.pose[order]
    lo = np.searchsorted(sorted_pose, pose_ids, side="left")
    hi = np.searchsorted(sorted_pose, pose_ids, side="right")
    return {int(p): order[a:z] for p, a, z in zip(pose_ids, lo, hi)}


def pose_records(ds: Dataset, levels=None, poses=None) -> list[PoseData]:
    """The dataset's poses in ``joints.csv`` order with their measurements (``levels`` to choose).

    ``poses``: only these pose ids (the others are not read). Linear in the dataset's size.
    """
    levels = ds.levels() if levels is None else list(levels)
    ids = np.asarray(ds.pose_ids, dtype=int)
    keep = np.ones(len(ids), bool) if poses is None else np.isin(ids, np.fromiter(poses, dtype=int))
    ids, joints = ids[keep], ds.joints_rad[keep]
    probes = _rows_by_pose(ds.probes, ids) if "probes" in levels else {}
    centres = _rows_by_pose(ds.centres, ids) if "centres" in levels else {}
    pose_rows = _rows_by_pose(ds.poses, ids) if "poses" in levels else {}
    out = []
    for pid, q in zip(ids.tolist(), joints):
        rec = PoseData(pid, q)
        if probes:
            rows = probes[pid]
            balls = ds.probes.ball[rows]
            for b in dict.fromkeys(balls.tolist()):
                rec.probes.append((b, ds.probes.xyz[rows[balls == b]]))
        if centres:
            rec.centres += [(str(ds.centres.ball[i]), ds.centres.xyz[i]) for i in centres[pid]]
        if pose_rows and len(pose_rows[pid]):
            i = pose_rows[pid][0]
            rec.T = pose_matrices(ds.poses.xyz[i], ds.poses.quat[i])
        out.append(rec)
    return out


def weak_prior(params: ParameterSet) -> np.ndarray:
    """Standard deviations (P,) of the weak prior, internal units."""
    return WEAK_PRIOR.sigmas(params.names)


@dataclass
class UpdateReport:
    pose: int
    accepted: bool
    reason: str = "ok"


def _good_centres(rec: PoseData, tooling, sigma_cmm: float, min_balls: int = 3):
    """Fitted centres (ball, xyz, cov) of a pose's probed balls, or a rejection reason."""
    good, bad = [], []
    usable = [(b, p) for b, p in rec.probes if len(p) >= 3]
    bad += [f"ball {b}: {len(p)} probe points" for b, p in rec.probes if len(p) < 3]
    fits = fit_spheres_checked([p for _, p in usable], tooling.radius, max(sigma_cmm, 1e-6))
    for (ball, _), fit in zip(usable, fits):
        if fit.ok:
            good.append((ball, fit.centre, fit.covariance))
        else:
            bad.append(f"ball {ball}: {fit.status}")
    if rec.probes and len(good) < min_balls:
        return None, f"{len(good)} good ball(s) of {len(rec.probes)}; a pose needs {min_balls}" + (
            f" ({'; '.join(bad)})" if bad else "")
    return good, None


class _Engine:
    def __init__(self, ds: Dataset, model: RobotModel, options: CalibrationOptions = CalibrationOptions(),
                 names=None):
        self.ds = ds
        self.model = model
        self.params = model.parameters() if names is None else ParameterSet(model, tuple(names))
        self.held = model.nominal.copy()
        self.sigmas: Sigmas = _sigmas(ds, model, options)
        self.prior_sigma = weak_prior(self.params)
        self.n_accepted = 0

    def estimate(self):
        """``(theta (P,), covariance (P, P))`` in internal units."""
        raise NotImplementedError


class ISAM2Engine(_Engine):
    """Incremental smoothing over the same factors as the batch graph."""

    def __init__(self, ds, model, options=CalibrationOptions(), names=None, theta_threshold=(0.05, 1e-4),
                 factorization="CHOLESKY", window: int = 50):
        """``window``: poses whose joint variables stay in the tree; older ones are marginalised
        (their information stays, as a linear factor on the parameters), which keeps each update's
        cost flat (measured at 1000 poses: the estimate moved by 1e-6 sigma)."""
        super().__init__(ds, model, options, names)
        self.window = window
        self._live: list[int] = []
        p = gtsam.ISAM2Params()
        p.setFactorization(factorization)
        # The default wildfire threshold (1e-3 in variable units) would leave angle updates below
        # 0.06 deg unpropagated: back-substitute everything the new pose touches.
        p.setOptimizationParams(gtsam.ISAM2GaussNewtonParams(0.0))
        thresholds = gtsam.ISAM2ThresholdMap()
        is_angle = self.params.is_angle
        thresholds.insert(("k", np.where(is_angle, theta_threshold[1], theta_threshold[0])))
        # Relinearising the parameters re-evaluates every factor of every pose: allow it only when
        # they move by 0.05 mm / 1e-4 rad (measured: within 0.003 sigma of the batch solve; at
        # 0.5 mm / 1e-3 rad the systematic second-order error reached 0.14 sigma).
        thresholds.insert(("q", np.full(6, 1e-5)))
        p.setRelinearizeThreshold(thresholds)
        p.relinearizeSkip = 1
        self.isam = gtsam.ISAM2(p)
        self.t_key = fx.theta_key()
        self._linpoint = None
        self._started = False
        self._keep = []  # the factors' closures reference their arguments: keep them alive

    def update(self, rec: PoseData) -> UpdateReport:
        sig = self.sigmas
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        if not self._started:
            graph.add(fx.parameter_prior(self.t_key, self.params.nominal(), self.prior_sigma))
            values.insert(self.t_key, self.params.nominal())
        i = rec.pose
        joint_vars = bool(np.all(np.asarray(sig.joint) > 0))
        qargs = {"q_key": fx.joint_key(i)} if joint_vars else {"q_fixed": rec.q}
        good = None
        if rec.probes:
            good, reason = _good_centres(rec, self.ds.tooling, self.ds.noise.cmm_sigma)
            if good is None:
                return UpdateReport(i, False, reason)
        if not (rec.probes or rec.centres or rec.T is not None):
            return UpdateReport(i, False, "no measurements")
        if joint_vars:
            graph.add(fx.joint_prior(fx.joint_key(i), rec.q, sig.joint))
            values.insert(fx.joint_key(i), rec.q.copy())
        # Each probed ball enters through its fitted centre with the fit's full covariance: to
        # first order the same information as its probe points around a centre variable, without
        # the stiff kinematic factor that would need relinearising at every step.
        if good:
            cov = np.zeros((3 * len(good), 3 * len(good)))
            for k, (_, _, c) in enumerate(good):
                cov[3 * k:3 * k + 3, 3 * k:3 * k + 3] = c
            graph.add(fx.ball_centres_factor(self.params.index, self.held,
                                             [self.ds.tooling.balls[b] for b, _, _ in good], [c for _, c, _ in good],
                                             cov, t_key=self.t_key, **qargs))
        for ball, xyz in rec.centres:
            graph.add(fx.ball_centre_factor(self.params.index, self.held, self.ds.tooling.balls[ball], sig.centre,
                                            t_key=self.t_key, c_measured=xyz, **qargs))
        if rec.T is not None:
            graph.add(fx.pose_factor(self.params.index, self.held, rec.T, sig.pose_rotation, sig.pose_position,
                                     t_key=self.t_key, **qargs))
        self._keep.append(graph)
        self.isam.update(graph, values)
        self._linpoint = self.isam.getLinearizationPoint()  # keep a reference (DESIGN.md section 5)
        if joint_vars:
            self._live.append(i)
            while len(self._live) > self.window:
                old = gtsam.KeyList()
                old.push_back(fx.joint_key(self._live.pop(0)))
                self.isam.marginalizeLeaves(old)
        self._started = True
        self.n_accepted += 1
        return UpdateReport(i, True)

    def finish(self) -> None:
        """Nothing to do: the thresholds keep the linearisation current (see ``__init__``)."""

    def estimate(self):
        if not self._started:
            return self.params.nominal(), np.diag(self.prior_sigma**2)
        return self.isam.calculateEstimateVector(self.t_key), self.isam.marginalCovariance(self.t_key)


class KalmanEngine(_Engine):
    """A filterpy filter over the parameter vector: iterated EKF (``ekf``) or unscented (``ukf``)."""

    def __init__(self, ds, model, options=CalibrationOptions(), names=None, kind="ekf", drift=None,
                 max_iterations=20):
        super().__init__(ds, model, options, names)
        from filterpy.kalman import ExtendedKalmanFilter

        if kind not in ("ekf", "ukf"):
            raise FgcalError(f"unknown filter {kind!r} (ekf, ukf)")
        self.kind = kind
        P = len(self.params)
        self.kf = ExtendedKalmanFilter(dim_x=P, dim_z=1)
        self.kf.x = self.params.nominal().copy()
        self.kf.P = np.diag(self.prior_sigma**2)
        self.kf.Q = np.zeros((P, P)) if drift is None else np.diag(np.asarray(drift, dtype=float) ** 2)
        self.max_iterations = max_iterations
        self._ukf = None

    # the measurement: stacked residual e(theta) = h(theta) - z, its Jacobian, and R
    def _measurement(self, rec: PoseData):
        sig = self.sigmas
        parts = []  # (kind, payload)
        if rec.probes:
            good, reason = _good_centres(rec, self.ds.tooling, self.ds.noise.cmm_sigma)
            if good is None:
                return None, reason
            for ball, centre, cov in good:
                parts.append(("centre", (self.ds.tooling.balls[ball], centre, cov)))
        for ball, xyz in rec.centres:
            parts.append(("centre", (self.ds.tooling.balls[ball], xyz, np.eye(3) * sig.centre**2)))
        if rec.T is not None:
            parts.append(("pose", rec.T))
        if not parts:
            return None, "no measurements"
        Rj = np.diag(np.broadcast_to(np.asarray(sig.joint, dtype=float) ** 2, (len(rec.q),)))

        centre_parts = [p for k, p in parts if k == "centre"]
        offsets = np.array([p[0] for p in centre_parts]).reshape(-1, 3)
        zs = np.array([p[1] for p in centre_parts]).reshape(-1, 3)
        T_meas = next((p for k, p in parts if k == "pose"), None)
        R_blocks = [p[2] for p in centre_parts]
        if T_meas is not None:
            R_blocks.append(np.diag([sig.pose_rotation**2] * 3 + [sig.pose_position**2] * 3))
        m = sum(len(b) for b in R_blocks)
        R0 = np.zeros((m, m))
        k = 0
        for block in R_blocks:
            R0[k:k + len(block), k:k + len(block)] = block
            k += len(block)

        def evaluate(theta):
            e, Jt, Jq = [], [], []
            if len(offsets):
                ee, jt, jq = fx.pose_ball_centres_error(theta, rec.q, offsets, zs, self.params.index, self.held)
                e.append(ee.ravel())
                Jt.append(jt.reshape(-1, jt.shape[-1]))
                Jq.append(jq.reshape(-1, 6))
            if T_meas is not None:
                ee, jt, jq = fx.pose_error(theta, rec.q[None], T_meas[None], self.params.index, self.held)
                e.append(ee[0])
                Jt.append(jt[0])
                Jq.append(jq[0])
            Jq = np.vstack(Jq)
            return np.concatenate(e), np.vstack(Jt), R0 + Jq @ Rj @ Jq.T  # joint noise folded in

        return evaluate, None

    def update(self, rec: PoseData) -> UpdateReport:
        evaluate, reason = self._measurement(rec)
        if evaluate is None:
            return UpdateReport(rec.pose, False, reason)
        x0 = self.kf.x.copy()
        P0 = self.kf.P + self.kf.Q  # random-walk prediction
        if self.kind == "ekf":
            x = x0.copy()
            sigma0 = np.sqrt(np.diag(P0))
            for _ in range(self.max_iterations):
                e, H, R = evaluate(x)
                innovation = -e - H @ (x0 - x)
                S = H @ P0 @ H.T + R
                K = np.linalg.solve(S, H @ P0).T
                x_new = x0 + K @ innovation
                # Relinearise while the step is a noticeable fraction of the prior's spread: the
                # error of a linearisation that far off is second order, ~1e-2 of a sigma.
                if np.max(np.abs(x_new - x) / sigma0) < 0.1:
                    break
                x = x_new
            d2 = float(innovation @ np.linalg.solve(S, innovation))
            if d2 > chi2_quantile(1 - INNOVATION_FALSE_ALARM, len(innovation)):
                return UpdateReport(rec.pose, False, f"innovation implausible (chi-square {d2:.3g} for "
                                                     f"{len(innovation)} measurements)")
            # Commit through filterpy's update, linearised at the iterated point.
            self.kf.x, self.kf.P = x0, P0
            self.kf.update(np.zeros(len(e)), HJacobian=lambda _x: H, Hx=lambda _x: e + H @ (_x - x), R=R)
        else:
            from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

            e0, H0, R = evaluate(x0)
            S = H0 @ P0 @ H0.T + R
            d2 = float(e0 @ np.linalg.solve(S, e0))
            if self.n_accepted >= 10 and d2 > chi2_quantile(1 - INNOVATION_FALSE_ALARM, len(e0)):
                return UpdateReport(rec.pose, False, f"innovation implausible (chi-square {d2:.3g} for "
                                                     f"{len(e0)} measurements)")
            n = len(x0)
            if self._ukf is None:  # one filter, reused: each pose brings its own hx, R and size
                points = MerweScaledSigmaPoints(n, alpha=0.1, beta=2.0, kappa=3.0 - n)
                self._ukf = UnscentedKalmanFilter(dim_x=n, dim_z=len(e0), dt=1.0, fx=lambda s, dt: s,
                                                  hx=None, points=points)
            ukf = self._ukf
            ukf.x, ukf.P, ukf.Q = x0.copy(), P0.copy(), np.zeros((n, n))
            ukf.predict()
            ukf.update(np.zeros(len(e0)), R=R, hx=lambda s: evaluate(s)[0])
            self.kf.x, self.kf.P = ukf.x.copy(), 0.5 * (ukf.P + ukf.P.T)
        self.n_accepted += 1
        return UpdateReport(rec.pose, True)

    def finish(self) -> None:
        """Nothing to do: a filter's state is final after each update."""

    def estimate(self):
        return self.kf.x.copy(), self.kf.P.copy()

    def state(self) -> dict:
        return {"x": self.kf.x.tolist(), "P": self.kf.P.tolist()}

    def restore(self, state: dict, n_accepted: int) -> None:
        self.kf.x = np.array(state["x"], dtype=float)
        self.kf.P = np.array(state["P"], dtype=float)
        self.n_accepted = n_accepted


def make_engine(kind: str, ds: Dataset, model: RobotModel, options=CalibrationOptions(), **kw):
    if kind == "isam2":
        return ISAM2Engine(ds, model, options, **kw)
    if kind in ("ekf", "ukf"):
        return KalmanEngine(ds, model, options, kind=kind, **kw)
    raise FgcalError(f"unknown engine {kind!r} (isam2, ekf, ukf)")

