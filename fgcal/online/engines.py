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

Both start from the nominal model with the weak prior of :data:`fgcal.estimation.calibrate.WEAK_PRIOR`
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
from fgcal.estimation.calibrate import WEAK_PRIOR, CalibrationOptions, _sigmas
from fgcal.measurements.dataset import Dataset
from fgcal.errors import FgcalError
from fgcal.estimation.graph import Sigmas
from fgcal.robots.model import ParameterSet, RobotModel
from fgcal.measurements.dataset import DistanceObservations, PointObservations, PoseObservations
from fgcal.measurements.spherefit import best_of_candidates, chi2_quantile, fit_spheres_batch, fit_spheres_checked, mirror_through_points
from fgcal.robots.transforms import matrix_to_quaternion, pose_matrices

__all__ = ["PoseData", "pose_records", "records_dataset", "weak_prior", "UpdateReport", "NoiseTracker",
           "ISAM2Engine", "KalmanEngine", "make_engine"]

log = logging.getLogger(__name__)

INNOVATION_FALSE_ALARM = 1e-6
MIRROR_CHI2 = chi2_quantile(1 - INNOVATION_FALSE_ALARM, 1)  # a mirror image this close in fit is a candidate


@dataclass
class PoseData:
    """Everything measured at one pose (file order): joints (rad) and the levels present."""

    pose: int
    q: np.ndarray
    probes: list[tuple[str, np.ndarray]] = field(default_factory=list)  # (ball, points (n, 3))
    centres: list[tuple[str, np.ndarray]] = field(default_factory=list)  # (ball, xyz (3,))
    T: np.ndarray | None = None
    distances: list[tuple[str, float]] = field(default_factory=list)  # (ball, ballbar length mm)

    def measured(self) -> bool:
        return bool(self.probes or self.centres or self.T is not None or self.distances)


def _rows_by_pose(obs, pose_ids):
    """Row indices of ``obs`` per pose id, in file order: one sort, not one scan per pose."""
    if obs is None:
        return {}
    order = np.argsort(obs.pose, kind="stable")
    sorted_pose = obs.pose[order]
    lo = np.searchsorted(sorted_pose, pose_ids, side="left")
    hi = np.searchsorted(sorted_pose, pose_ids, side="right")
    return {int(p): order[a:z] for p, a, z in zip(pose_ids, lo, hi)}


def pose_records(ds: Dataset, levels=None, poses=None, model=None) -> list[PoseData]:
    """The dataset's poses in ``joints.csv`` order with their measurements (``levels`` to choose).

    ``poses``: only these pose ids (the others are not read). Linear in the dataset's size.
    ``model`` converts the readings (prismatic joints are mm); all revolute without it.
    """
    levels = ds.levels() if levels is None else list(levels)
    ids = np.asarray(ds.pose_ids, dtype=int)
    keep = np.ones(len(ids), bool) if poses is None else np.isin(ids, np.fromiter(poses, dtype=int))
    ids = ids[keep]
    joints = (model.joints_to_internal(ds.joints_deg) if model is not None else ds.joints_rad)[keep]
    probes = _rows_by_pose(ds.probes, ids) if "probes" in levels else {}
    centres = _rows_by_pose(ds.centres, ids) if "centres" in levels else {}
    pose_rows = _rows_by_pose(ds.poses, ids) if "poses" in levels else {}
    distance_rows = _rows_by_pose(ds.distances, ids) if "distances" in levels else {}
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
        if distance_rows:
            rec.distances += [(str(ds.distances.ball[i]), float(ds.distances.length[i])) for i in distance_rows[pid]]
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


def _good_centres(rec: PoseData, tooling, sigma_cmm: float, min_balls: int = 3, prediction=None, flip=()):
    """Fitted centres (ball, xyz, cov) of a pose's probed balls, or a rejection reason.

    ``prediction`` (ball -> xyz, mm): where the current estimate puts each ball. As in the batch
    solve, of the centres that fit a cap of points equally well (the fit and its mirror image
    through the points) the one nearer the prediction is taken, and a residual above the sphere
    check's limit is left to the innovation gate.
    """
    good, bad = [], []
    usable = [(b, p) for b, p in rec.probes if len(p) >= 3]
    bad += [f"ball {b}: {len(p)} probe points" for b, p in rec.probes if len(p) < 3]
    sigma = max(sigma_cmm, 1e-6)
    fits = fit_spheres_checked([p for _, p in usable], tooling.radius, sigma)
    kept = []
    for (ball, pts), fit in zip(usable, fits):
        # A residual above the sphere check's limit alone does not reject the ball: as in the batch
        # solve, the innovation gate (with the kinematic prediction's redundancy) judges the pose.
        if not fit.ok and not (prediction is not None and fit.status.startswith("residual")):
            bad.append(f"ball {ball}: {fit.status}")
            continue
        kept.append((ball, pts, fit))
    chosen, ambiguous = {}, []
    if prediction is not None:
        # the fit, its mirror image and a fit started at the prediction; balls with equal point counts at once
        by_count: dict[int, list] = {}
        for ball, pts, fit in kept:
            if ball in prediction:
                by_count.setdefault(len(pts), []).append((ball, pts, fit))
        for group in by_count.values():
            pts = np.array([p for _, p, _ in group])
            first = np.array([f.centre for _, _, f in group])
            pred = np.array([prediction[b] for b, _, _ in group])
            refits = fit_spheres_batch(np.concatenate([pts, pts]), tooling.radius,
                                       guess=np.concatenate([mirror_through_points(pts, first), pred]))
            cands = [first, refits[:len(group)], refits[len(group):]]
            near = best_of_candidates(pts, tooling.radius, cands, sigma, pred)
            # the mirror image, where it fits nearly as well (within the 1e-6 chi-square limit of
            # one residual): the innovation gate may take it for the balls in ``flip``
            other = fit_spheres_batch(pts, tooling.radius, guess=mirror_through_points(pts, near))
            ssr = [np.sum((np.linalg.norm(pts - c[:, None], axis=2) - tooling.radius) ** 2, axis=1)
                   for c in (near, other)]
            alike = (ssr[1] <= ssr[0] + MIRROR_CHI2 * sigma**2) & (np.linalg.norm(other - near, axis=1) > tooling.radius)
            for k, (ball, _, _) in enumerate(group):
                if alike[k]:
                    ambiguous.append(ball)
                chosen[ball] = other[k] if (ball in flip and alike[k]) else near[k]
    for ball, pts, fit in kept:
        centre, cov = fit.centre, fit.covariance
        if ball in chosen and np.linalg.norm(chosen[ball] - centre) > 1e-9:
            d = pts - chosen[ball]
            J = d / np.linalg.norm(d, axis=1, keepdims=True)
            centre, cov = chosen[ball], np.linalg.inv(J.T @ J) * sigma**2
        good.append((ball, centre, cov))
    if rec.probes and len(good) < min_balls:
        return None, f"{len(good)} good ball(s) of {len(rec.probes)}; a pose needs {min_balls}" + (
            f" ({'; '.join(bad)})" if bad else "")
    _good_centres.ambiguous = ambiguous  # balls whose mirror image fits as well (read by the caller)
    return good, None


def records_dataset(meta: Dataset, records: list[PoseData], model=None) -> Dataset:
    """A dataset (robot, tool and noise of ``meta``) holding the poses ``records``."""
    probes = [(r.pose, b, x) for r in records for b, pts in r.probes for x in pts]
    centres = [(r.pose, b, c) for r in records for b, c in r.centres]
    poses = [(r.pose, r.T) for r in records if r.T is not None]
    distances = [(r.pose, b, v) for r in records for b, v in r.distances]
    q = np.array([r.q for r in records]).reshape(len(records), -1)

    def points(rows):
        return PointObservations([p for p, _, _ in rows], [b for _, b, _ in rows],
                                 np.array([x for _, _, x in rows]).reshape(-1, 3)) if rows else None

    return Dataset(robot=meta.robot, tooling=meta.tooling, noise=meta.noise, provenance=dict(meta.provenance),
                   pose_ids=[r.pose for r in records],
                   joints_deg=model.joints_to_file_units(q) if model is not None else np.degrees(q),
                   probes=points(probes), centres=points(centres),
                   poses=PoseObservations([p for p, _ in poses], np.array([T[:3, 3] for _, T in poses]),
                                          matrix_to_quaternion(np.array([T[:3, :3] for _, T in poses])))
                   if poses else None,
                   distances=DistanceObservations([p for p, _, _ in distances], [b for _, b, _ in distances],
                                                  [v for _, _, v in distances]) if distances else None,
                   path=meta.path, chain=meta.chain)


class NoiseTracker:
    """The measurement noise factor, estimated from the innovations seen so far.

    With innovation covariance ``S = A + f R`` (A: the parameters' share, R: the declared
    measurement noise with the joints' folded in, f: the current factor), a pose's innovation
    ``d2 = v' S^-1 v`` has expectation ``tr(S^-1 A) + f_true tr(S^-1 R)``, so each pose gives an
    estimate of ``f_true``. Poses whose innovation is mostly measurement noise (redundancy
    ``tr(S^-1 f R)`` at least half their size; early on the weak prior dominates) are pooled by
    their weighted median, robust to the poses with gross errors. The current pose takes part
    (rejected ones too), so a wrong start cannot lock itself in. The factor is at least 1: below
    it (a pessimistic declared noise, or an innovation the linearisation overrates early on)
    the gate would only get stricter. Gates and updates use ``f R``.
    """

    def __init__(self):
        self.values: list[tuple[float, float]] = []  # (estimate of f, weight)

    def factor(self, extra=()) -> float:
        vals = self.values + list(extra)
        if not vals:
            return 1.0
        v, w = np.array(vals).T
        order = np.argsort(v)
        cum = np.cumsum(w[order])
        return float(max(v[order][np.searchsorted(cum, 0.5 * cum[-1])], 1.0))

    def observe(self, v, A, R) -> float:
        """Record innovation ``v`` (A, R as above); returns the factor to gate and update it with."""
        f = self.factor()
        Si = np.linalg.inv(A + f * R)
        d2, a, b = float(v @ Si @ v), float(np.trace(Si @ A)), float(np.trace(Si @ R))
        if f * b >= 0.5 * len(v):
            self.values.append((max((d2 - a) / b, 0.0), f * b))
        return self.factor()

    @staticmethod
    def implausible(v, S) -> str | None:
        """The gate: a rejection reason when ``v' S^-1 v`` is beyond the chi-square limit."""
        d2 = float(v @ np.linalg.solve(S, v))
        if d2 > chi2_quantile(1 - INNOVATION_FALSE_ALARM, len(v)):
            return f"innovation implausible (chi-square {d2:.3g} for {len(v)} measurements)"
        return None


class _Engine:
    def __init__(self, ds: Dataset, model: RobotModel, options: CalibrationOptions = CalibrationOptions(),
                 names=None):
        self.ds = ds
        self.model = model
        self.options = options
        self.params = model.parameters() if names is None else ParameterSet(model, tuple(names))
        self.held = model.nominal.copy()
        self.sigmas: Sigmas = _sigmas(ds, model, options)
        self.prior_sigma = weak_prior(self.params)
        self.n_accepted = 0
        self.noise = NoiseTracker()
        self.records: list[PoseData] = []  # the accepted poses (as taken: a bad probe point left out)
        self.seen: dict[int, PoseData] = {}  # every pose fed with measurements, for the final smoothing
        self._final = None

    def estimate(self):
        """``(theta (P,), covariance (P, P))`` in internal units."""
        raise NotImplementedError

    def _current(self) -> np.ndarray:
        raise NotImplementedError

    def _prediction(self, rec: PoseData, theta) -> dict:
        balls = [b for b, _ in rec.probes]
        if not balls:
            return {}
        offsets = np.array([self.ds.tooling.balls[b] for b in balls])
        e, _, _ = fx.pose_ball_centres_error(theta, rec.q, offsets, np.zeros_like(offsets), self.params.index,
                                             self.held, self.model.chain)
        return dict(zip(balls, e))

    def _measurement(self, rec: PoseData, flip=()):
        """``(evaluate, None)`` or ``(None, reason)``; ``evaluate(theta)`` gives the stacked residual
        ``h(theta) - z``, its Jacobian and the declared noise R with the joints' noise folded in."""
        sig = self.sigmas
        centre_parts, T_meas = [], rec.T
        if rec.probes:
            good, reason = _good_centres(rec, self.ds.tooling, self.ds.noise.cmm_sigma,
                                         prediction=self._prediction(rec, self._current()), flip=flip)
            if good is None:
                return None, reason
            centre_parts += [(self.ds.tooling.balls[b], c, cov) for b, c, cov in good]
        centre_parts += [(self.ds.tooling.balls[b], xyz, np.eye(3) * sig.centre**2) for b, xyz in rec.centres]
        if not centre_parts and T_meas is None and not rec.distances:
            return None, "no measurements"
        Rj = np.diag(np.broadcast_to(np.asarray(sig.joint, dtype=float) ** 2, (len(rec.q),)))
        offsets = np.array([p[0] for p in centre_parts]).reshape(-1, 3)
        zs = np.array([p[1] for p in centre_parts]).reshape(-1, 3)
        R_blocks = [p[2] for p in centre_parts]
        if T_meas is not None:
            R_blocks.append(np.diag([sig.pose_rotation**2] * 3 + [sig.pose_position**2] * 3))
        d_offsets = np.array([self.ds.tooling.balls[b] for b, _ in rec.distances]).reshape(-1, 3)
        d_lengths = np.array([v for _, v in rec.distances], dtype=float)
        if len(d_lengths):
            R_blocks.append(np.eye(len(d_lengths)) * sig.distance**2)
        m = sum(len(b) for b in R_blocks)
        R0 = np.zeros((m, m))
        k = 0
        for block in R_blocks:
            R0[k:k + len(block), k:k + len(block)] = block
            k += len(block)

        def evaluate(theta):
            e, Jt, Jq = [], [], []
            if len(offsets):
                ee, jt, jq = fx.pose_ball_centres_error(theta, rec.q, offsets, zs, self.params.index, self.held,
                                                        self.model.chain)
                e.append(ee.ravel())
                Jt.append(jt.reshape(-1, jt.shape[-1]))
                Jq.append(jq.reshape(-1, jq.shape[-1]))
            if T_meas is not None:
                ee, jt, jq = fx.pose_error(theta, rec.q[None], T_meas[None], self.params.index, self.held,
                                           self.model.chain)
                e.append(ee[0])
                Jt.append(jt[0])
                Jq.append(jq[0])
            if len(d_lengths):
                qs = np.broadcast_to(rec.q, (len(d_lengths), len(rec.q)))
                ee, jt, jq = fx.distance_error(theta, qs, d_offsets, d_lengths, self.params.index, self.held,
                                               self.model.chain)
                e.append(ee[:, 0])
                Jt.append(jt[:, 0])
                Jq.append(jq[:, 0])
            Jq = np.vstack(Jq)
            return np.concatenate(e), np.vstack(Jt), R0 + Jq @ Rj @ Jq.T  # joint noise folded in

        evaluate.parts = centre_parts
        evaluate.ambiguous = list(getattr(_good_centres, "ambiguous", [])) if rec.probes else []
        return evaluate, None

    def _screen(self, rec: PoseData, theta, cov):
        """The pose's measurement if it passes the checks and the innovation gate at the current
        ``theta`` and its covariance ``cov``; else, as the batch solve excludes single probe
        points, the variant without the one probe point that makes it pass with the smallest
        innovation. Returns ``(evaluate, record used, noise factor, None)`` or ``(None, rec, f, reason)``."""

        if rec.measured():
            self.seen[rec.pose] = rec
            self._final = None

        def statistic(r, flip=()):
            evaluate, why = self._measurement(r, flip)
            if evaluate is None:
                return None, why, None
            e, H, R = evaluate(theta)
            return evaluate, None, (-e, H @ cov @ H.T, R)

        evaluate, reason, vAR = statistic(rec)
        f = self.noise.observe(*vAR) if vAR is not None else self.noise.factor()
        if evaluate is not None:
            reason = NoiseTracker.implausible(vAR[0], vAR[1] + f * vAR[2])
            if reason is None:
                return evaluate, rec, f, None
        # Where the prediction is still poor (early poses), a ball's mirror image may be the
        # consistent one: try them; then single probe points left out. The passing variant with
        # the smallest innovation is taken.
        from itertools import combinations

        def best_of(variants):
            best = None
            for variant, flip in variants:
                ev, _, vAR_k = statistic(variant, flip)
                if ev is None:
                    continue
                v, A, R = vAR_k
                d2 = float(v @ np.linalg.solve(A + f * R, v))
                if NoiseTracker.implausible(v, A + f * R) is None and (best is None or d2 < best[0]):
                    best = (d2, ev, variant)
            return best

        def without_one(rec):
            for j, (ball, pts) in enumerate(rec.probes):
                for k in range(len(pts) if len(pts) >= 4 else 0):
                    variant = PoseData(rec.pose, rec.q, list(rec.probes), list(rec.centres), rec.T, list(rec.distances))
                    variant.probes[j] = (ball, np.delete(pts, k, axis=0))
                    yield variant, ()

        amb = evaluate.ambiguous if evaluate is not None else []
        flips = ((rec, flip) for n in range(1, len(amb) + 1) for flip in combinations(amb, n))
        best = best_of(flips) or best_of(without_one(rec))
        if best is not None:
            return best[1], best[2], f, None
        return None, rec, f, reason

    def _accepted(self, rec: PoseData) -> UpdateReport:
        self.records.append(rec)
        self.n_accepted += 1
        self._final = None
        return UpdateReport(rec.pose, True)

    def _smooth(self):
        """The final smoothing: one batch solve over every pose fed (weak prior, noise estimated and
        gross errors excluded as in ``calibrate``), so that the end depends neither on the order
        the poses came in nor on what the running estimate refused on the way (a pose refused
        against an early, poor estimate is judged again, as the batch judges it). Returns
        ``(theta, covariance)`` in internal units, or None while the poses cannot determine the
        parameters without the prior (the running estimate stands then)."""
        from dataclasses import replace

        from fgcal.estimation.calibrate import calibrate

        ident = self.model.identifiable_names()
        names = list(self.params.names)
        options = replace(self.options, prior="weak", extra=tuple(n for n in names if n not in ident),
                          exclude=tuple(n for n in ident if n not in names))
        try:
            r = calibrate(records_dataset(self.ds, list(self.seen.values()), self.model), self.model, options)
        except FgcalError as exc:  # too few poses for the batch solve yet: the running estimate stands
            log.info("final smoothing skipped: %s", exc)
            return None
        if r.names != names:
            raise FgcalError(f"final smoothing: the batch solve holds {', '.join(h['name'] for h in r.held)}")
        scale = np.where(self.params.is_angle, np.radians(1.0), 1.0)
        return self.params.from_file_units(r.estimate), r.covariance * np.outer(scale, scale)


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
        self._factors: list[float] = []  # the noise factor each accepted pose was added with

    def _current(self) -> np.ndarray:
        return self.isam.calculateEstimateVector(self.t_key) if self._started else self.params.nominal()

    def update(self, rec: PoseData) -> UpdateReport:
        i = rec.pose
        # The innovation against the current estimate, at the noise estimated so far.
        cov = self.isam.marginalCovariance(self.t_key) if self._started else np.diag(self.prior_sigma**2)
        evaluate, used, f, reason = self._screen(rec, self._current(), cov)
        if evaluate is None:
            return UpdateReport(i, False, reason)
        return self._add(used, evaluate.parts, f)

    def _add(self, rec: PoseData, parts, f: float) -> UpdateReport:
        """Add an accepted pose's factors, its noise scaled by the factor ``f``."""
        sig = self.sigmas
        i = rec.pose
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        if not self._started:
            graph.add(fx.parameter_prior(self.t_key, self.params.nominal(), self.prior_sigma))
            values.insert(self.t_key, self.params.nominal())
        joint_vars = bool(np.all(np.asarray(sig.joint) > 0))
        qargs = ({"q_key": fx.joint_key(i)} if joint_vars else {"q_fixed": rec.q}) | {"chain": self.model.chain}
        if joint_vars:
            graph.add(fx.joint_prior(fx.joint_key(i), rec.q, sig.joint * np.sqrt(f)))
            values.insert(fx.joint_key(i), rec.q.copy())
        # Each ball enters through its (fitted) centre with the fit's full covariance: to first
        # order the same information as its probe points around a centre variable, without the
        # stiff kinematic factor that would need relinearising at every step.
        if parts:
            cov = np.zeros((3 * len(parts), 3 * len(parts)))
            for k, (_, _, c) in enumerate(parts):
                cov[3 * k:3 * k + 3, 3 * k:3 * k + 3] = c * f
            graph.add(fx.ball_centres_factor(self.params.index, self.held, [o for o, _, _ in parts],
                                             [c for _, c, _ in parts], cov, t_key=self.t_key, **qargs))
        if rec.T is not None:
            graph.add(fx.pose_factor(self.params.index, self.held, rec.T, sig.pose_rotation * np.sqrt(f),
                                     sig.pose_position * np.sqrt(f), t_key=self.t_key, **qargs))
        for ball, length in rec.distances:
            graph.add(fx.distance_factor(self.params.index, self.held, self.ds.tooling.balls[ball], length,
                                         sig.distance * np.sqrt(f), t_key=self.t_key, **qargs))
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
        self._factors.append(f)
        return self._accepted(rec)

    def state(self) -> dict:
        """What :meth:`restore` needs: the accepted poses, the noise factor each was added with,
        and the innovations seen (the tree itself is rebuilt by adding the poses again)."""
        from fgcal.online.run import _record_to_json

        return {"records": [_record_to_json(r) for r in self.records], "factors": self._factors,
                "noise": self.noise.values, "seen": [_record_to_json(r) for r in self.seen.values()]}

    def restore(self, state: dict, n_accepted: int) -> None:
        from fgcal.online.run import _record_from_json

        for d, f in zip(state["records"], state["factors"]):
            rec = _record_from_json(d)
            evaluate, reason = self._measurement(rec)
            if evaluate is None:
                raise FgcalError(f"restoring pose {rec.pose}: {reason}")
            self._add(rec, evaluate.parts, f)
        self.noise.values = [tuple(v) for v in state.get("noise", [])]
        self.seen = {r.pose: r for r in map(_record_from_json, state.get("seen", []))}
        self.n_accepted = n_accepted

    def finish(self) -> None:
        """The final smoothing (see :meth:`_Engine._smooth`); the incremental state stays as it was."""
        if self.seen and self._final is None:
            self._final = self._smooth()

    def estimate(self):
        if self._final is not None:
            return self._final
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

    def _current(self) -> np.ndarray:
        return self.kf.x

    def update(self, rec: PoseData) -> UpdateReport:
        x0 = self.kf.x.copy()
        P0 = self.kf.P + self.kf.Q  # random-walk prediction
        evaluate, used, f, reason = self._screen(rec, x0, P0)  # f: the measurement noise estimated so far
        if evaluate is None:
            return UpdateReport(rec.pose, False, reason)
        e0, H0, R0 = evaluate(x0)
        if self.kind == "ekf":
            x = x0.copy()
            sigma0 = np.sqrt(np.diag(P0))
            for _ in range(self.max_iterations):
                e, H, R = evaluate(x)
                innovation = -e - H @ (x0 - x)
                S = H @ P0 @ H.T + f * R
                K = np.linalg.solve(S, H @ P0).T
                x_new = x0 + K @ innovation
                # Relinearise while the step is a noticeable fraction of the prior's spread: the
                # error of a linearisation that far off is second order, ~1e-2 of a sigma.
                if np.max(np.abs(x_new - x) / sigma0) < 0.1:
                    break
                x = x_new
            reason = NoiseTracker.implausible(innovation, S)
            if reason:
                return UpdateReport(rec.pose, False, reason)
            # Commit through filterpy's update, linearised at the iterated point.
            self.kf.x, self.kf.P = x0, P0
            self.kf.update(np.zeros(len(e)), HJacobian=lambda _x: H, Hx=lambda _x: e + H @ (_x - x), R=f * R)
        else:
            from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

            R = R0
            n = len(x0)
            if self._ukf is None:  # one filter, reused: each pose brings its own hx, R and size
                points = MerweScaledSigmaPoints(n, alpha=0.1, beta=2.0, kappa=3.0 - n)
                self._ukf = UnscentedKalmanFilter(dim_x=n, dim_z=len(e0), dt=1.0, fx=lambda s, dt: s,
                                                  hx=None, points=points)
            ukf = self._ukf
            ukf.x, ukf.P, ukf.Q = x0.copy(), P0.copy(), np.zeros((n, n))
            ukf.predict()
            ukf.update(np.zeros(len(e0)), R=f * R, hx=lambda s: evaluate(s)[0])
            self.kf.x, self.kf.P = ukf.x.copy(), 0.5 * (ukf.P + ukf.P.T)
        return self._accepted(used)

    def finish(self) -> None:
        """The final smoothing (see :meth:`_Engine._smooth`) when the parameters do not drift: the
        filter's state becomes the smoothed one, whatever the order the poses came in."""
        if self.seen and self._final is None and not np.any(self.kf.Q):
            self._final = self._smooth()
            if self._final is not None:
                self.kf.x, self.kf.P = self._final[0].copy(), self._final[1].copy()

    def estimate(self):
        return self.kf.x.copy(), self.kf.P.copy()

    def state(self) -> dict:
        from fgcal.online.run import _record_to_json

        return {"x": self.kf.x.tolist(), "P": self.kf.P.tolist(), "noise": self.noise.values,
                "records": [_record_to_json(r) for r in self.records],
                "seen": [_record_to_json(r) for r in self.seen.values()]}

    def restore(self, state: dict, n_accepted: int) -> None:
        from fgcal.online.run import _record_from_json

        self.kf.x = np.array(state["x"], dtype=float)
        self.kf.P = np.array(state["P"], dtype=float)
        self.noise.values = [tuple(v) for v in state.get("noise", [])]
        self.records = [_record_from_json(r) for r in state.get("records", [])]
        self.seen = {r.pose: r for r in map(_record_from_json, state.get("seen", []))}
        self.n_accepted = n_accepted


def make_engine(kind: str, ds: Dataset, model: RobotModel, options=CalibrationOptions(), **kw):
    if kind == "isam2":
        return ISAM2Engine(ds, model, options, **kw)
    if kind in ("ekf", "ukf"):
        return KalmanEngine(ds, model, options, kind=kind, **kw)
    raise FgcalError(f"unknown engine {kind!r} (isam2, ekf, ukf)")

