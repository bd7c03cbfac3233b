"""Following a drifting robot: an iterated EKF over the geometry and the joint-error block.

The state is the robot's geometric parameters followed by the coefficients of a joint-error block
(:mod:`fgcal.estimation.joint_errors`: compliances and map harmonics), each a random walk whose
per-pose step has the standard deviation of :class:`DriftLevels`. Each pose is first *predicted*
with the state after the poses before it (the one-step-ahead prediction a user running the robot
gets), then the state is updated with it. The corrected joints are ``q + G(q) phi``, so the
measurement's Jacobian in the block is ``J_q G``.

:func:`choose_drift` picks the drift level and the measurement-noise factor that maximise the
one-step-ahead (predictive) log-likelihood of a training stretch of poses; nothing after it is
looked at. No I/O here (:mod:`fgcal.online.drift_result` holds the result and its file).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from fgcal.errors import FgcalError
from fgcal.estimation.build import _sigmas
from fgcal.estimation.joint_errors import JointErrorBlock, JointErrorSpec
from fgcal.estimation.options import WEAK_PRIOR, CalibrationOptions
from fgcal.measurements.dataset import Dataset
from fgcal.measurements.pose import POSE
from fgcal.measurements.spherefit import chi2_quantile
from fgcal.online.measurement import NoiseTracker
from fgcal.online.records import PoseData, pose_records
from fgcal.robots.gravity import model_inertials
from fgcal.robots.model import ParameterSet, RobotModel

__all__ = ["DRIFT_SCALES", "NOISE_FACTORS", "DriftFilter", "DriftLevels", "DriftStep", "choose_drift", "follow_drift"]

log = logging.getLogger(__name__)

GATE_FALSE_ALARM = 1e-6  # a pose's innovation beyond this chi-square tail is not taken (it is still predicted)
MAX_ITERATIONS = 10
COMPONENTS = ("pose_rotation", "pose_position", "centre")  # noise components, each with its own factor


@dataclass(frozen=True)
class DriftLevels:
    """Random-walk standard deviations per pose of the state's entries.

    Attributes
    ----------
    length_mm, angle_deg : float
        Geometric lengths (mm) and angles (deg).
    map_urad : float
        Each map coefficient (µrad).
    compliance_urad_per_nm : float
        Each compliance (µrad/Nm).
    """

    length_mm: float = 0.0
    angle_deg: float = 0.0
    map_urad: float = 0.0
    compliance_urad_per_nm: float = 0.0

    def __post_init__(self):
        for k, v in vars(self).items():
            if not np.isfinite(v) or v < 0:
                raise FgcalError(f"drift {k}: {v!r} is not a finite non-negative number")

    def scaled(self, factor: float) -> DriftLevels:
        return DriftLevels(*(factor * v for v in vars(self).values()))

    def step_sigma(self, is_angle, block_names) -> np.ndarray:
        """The per-pose step (S,) internal units for geometric entries flagged ``is_angle`` (P,)
        followed by the block's ``block_names``."""
        geo = np.where(np.asarray(is_angle, dtype=bool), np.radians(self.angle_deg), self.length_mm)
        blk = [self.compliance_urad_per_nm * 1e-6 if n.endswith(".compliance") else self.map_urad * 1e-6
               for n in block_names]
        return np.concatenate([geo, np.array(blk, dtype=float)])

    def to_dict(self) -> dict:
        return {k: float(v) for k, v in vars(self).items()}

    @classmethod
    def from_dict(cls, d: dict) -> DriftLevels:
        return cls(**{k: float(d.get(k, 0.0)) for k in ("length_mm", "angle_deg", "map_urad",
                                                          "compliance_urad_per_nm")})


@dataclass(frozen=True)
class DriftStep:
    """One pose: its one-step-ahead prediction (before it is taken), then whether it was taken.

    Attributes
    ----------
    pose : int
    error_mm : float
        Predicted minus measured position of the tool (mm), from the state before the pose.
    sigma_mm : float
        That prediction's standard deviation from the state's covariance (root of the trace, mm).
    loglik : float
        The pose's predictive log-likelihood (nats) at the innovation's covariance.
    nis : float
        Normalised innovation squared (chi-square with ``rows`` degrees of freedom when consistent).
    rows : int
    taken : bool
        False when the innovation failed the gate (the state then only drifts).
    """

    pose: int
    error_mm: float
    sigma_mm: float
    loglik: float
    nis: float
    rows: int
    taken: bool


class DriftFilter:
    """An iterated EKF over ``[geometry (P,), joint-error block (K,)]`` with a random-walk drift.

    Parameters
    ----------
    ds : Dataset
        Robot, tool and declared noise (its poses are fed with :meth:`step`); tool poses
        (``poses``) or ball centres (``centres``).
    model : RobotModel
    spec : JointErrorSpec or None
        The joint-error block (None: geometry alone).
    levels : DriftLevels
    design_cache : dict, optional
        Shared by filters of the same dataset and block (the joint-error design per reading).
    noise_factor : float or None
        The declared measurement noise (variances) is multiplied by it; None (default): one factor
        per noise component (tool rotation, tool position, ball centres) estimated from the
        innovations as they come (:class:`fgcal.online.measurement.NoiseTracker`: the weighted
        median of the poses' estimates, at least 1).
    """

    def __init__(self, ds: Dataset, model: RobotModel, spec: JointErrorSpec | None, levels: DriftLevels,
                 noise_factor: float | None = None, options: CalibrationOptions = CalibrationOptions(),
                 design_cache: dict | None = None):
        if noise_factor is not None and (not np.isfinite(noise_factor) or noise_factor <= 0):
            raise FgcalError(f"noise factor {noise_factor!r}: must be a positive number")
        self.ds, self.model, self.levels = ds, model, levels
        self.noise_factor = None if noise_factor is None else float(noise_factor)
        self.trackers = {c: NoiseTracker() for c in COMPONENTS}
        self.params = model.parameters()
        self.index = self.params.index
        self.held = model.nominal.copy()
        self.block = None if spec is None or not spec.names(model.n_joints) else JointErrorBlock.build(
            spec, model.n_joints, model_inertials(model), chain=model.chain)
        block_names = [] if self.block is None else list(self.block.names)
        self.names = list(self.params.names) + block_names
        self.n_geometric = len(self.params)
        prior = np.concatenate([WEAK_PRIOR.sigmas(self.params.names),
                                [] if self.block is None else self.block.prior_sigma])
        self.x = np.concatenate([self.params.nominal(), np.zeros(len(block_names))])
        self.P = np.diag(prior**2)
        self.q_var = levels.step_sigma(self.params.is_angle, block_names) ** 2
        sig = _sigmas(ds, model, options)
        self.balls = ds.tooling.balls
        self.R_pose = np.diag(POSE.sigma(sig) ** 2)
        self.sigma_centre = float(sig.centre)
        self.Rj = np.diag(np.broadcast_to(np.asarray(sig.joint, dtype=float) ** 2, (model.n_joints,)))
        self.steps: list[DriftStep] = []
        self.design_cache: dict = {} if design_cache is None else design_cache  # reading -> G (same block)

    # ---------------------------------------------------------------- measurement
    def _design(self, q) -> np.ndarray:
        """``G`` (n, K) at the reading ``q``; compliance torques at the nominal geometry (so that
        it depends on the reading alone and is kept: the iterations and the runs of
        :func:`choose_drift` share it)."""
        if self.block is None:
            return np.zeros((len(q), 0))
        key = q.tobytes()
        G = self.design_cache.get(key)
        if G is None:
            G = self.design_cache[key] = self.block.design(q[None], self.model.nominal)[0]
        return G

    def _rows(self, rec: PoseData, x):
        """``(e (M,), H (M, S), R0 (M, M), component of each row (M,), position rows)`` at ``x``."""
        theta, phi = x[:self.n_geometric], x[self.n_geometric:]
        G = self._design(rec.q)
        qc = rec.q + G @ phi
        es, jts, jqs, rs, comp = [], [], [], [], []
        pos: list[int] = []
        if rec.T is not None:
            e, jt, jq = POSE.error(theta, qc[None], (rec.T[None],), self.index, self.held, self.model.chain)
            es.append(e[0])
            jts.append(jt[0])
            jqs.append(jq[0])
            rs.append(np.diag(self.R_pose))
            comp += [0, 0, 0, 1, 1, 1]
            pos = [3, 4, 5]
        if rec.centres:
            import factors as fx

            offsets = np.array([self.balls[b] for b, _ in rec.centres])
            zs = np.array([c for _, c in rec.centres])
            e, jt, jq = fx.pose_ball_centres_error(theta, qc, offsets, zs, self.index, self.held, self.model.chain)
            if not pos:
                pos = [len(comp), len(comp) + 1, len(comp) + 2]  # the first ball
            es.append(e.ravel())
            jts.append(jt.reshape(-1, jt.shape[-1]))
            jqs.append(jq.reshape(-1, jq.shape[-1]))
            rs.append(np.full(e.size, self.sigma_centre**2))
            comp += [2] * e.size
        if not es:
            raise FgcalError(f"pose {rec.pose}: drift following takes tool poses or ball centres; this pose has "
                             "neither (probe points: fit them first with fgcal measure)")
        e, Jt, Jq = np.concatenate(es), np.vstack(jts), np.vstack(jqs)
        H = np.hstack([Jt, Jq @ G])
        R0 = np.diag(np.concatenate(rs)) + Jq @ self.Rj @ Jq.T
        return e, H, R0, np.array(comp), pos

    def factors(self) -> dict[str, float]:
        """The noise factor of each component now (variances)."""
        if self.noise_factor is not None:
            return {c: self.noise_factor for c in COMPONENTS}
        return {c: t.factor() for c, t in self.trackers.items()}

    def _scaled(self, R0, comp) -> np.ndarray:
        f = np.array([self.factors()[COMPONENTS[c]] for c in comp])
        s = np.sqrt(f)
        return R0 * np.outer(s, s)

    # ---------------------------------------------------------------- the filter
    def step(self, rec: PoseData) -> DriftStep:
        """Predict ``rec`` from the state so far (one step ahead), then take it (iterated update)."""
        x0 = self.x
        P0 = self.P + np.diag(self.q_var)  # the random walk to this pose
        e, H, R0, comp, pos = self._rows(rec, x0)
        v = -e
        A = H @ P0 @ H.T
        if self.noise_factor is None:  # each component's factor learns from this pose's innovation too
            for c, name in enumerate(COMPONENTS):
                rows = np.nonzero(comp == c)[0]
                if len(rows):
                    self.trackers[name].observe(v[rows], A[np.ix_(rows, rows)], R0[np.ix_(rows, rows)])
        R = self._scaled(R0, comp)
        S = A + R
        _, logdet = np.linalg.slogdet(S)
        nis = float(v @ np.linalg.solve(S, v))
        loglik = -0.5 * (nis + logdet + len(v) * np.log(2 * np.pi))
        Hp = H[pos]
        sigma_mm = float(np.sqrt(max(np.trace(Hp @ P0 @ Hp.T), 0.0)))
        error_mm = float(np.linalg.norm(e[pos]))
        taken = nis <= chi2_quantile(1 - GATE_FALSE_ALARM, len(v))
        if taken:
            self.x, self.P = self._update(rec, x0, P0, e, H, R, comp)
        else:
            self.P = P0
            log.info("pose %d: innovation implausible (chi-square %.3g for %d rows): predicted, not taken",
                     rec.pose, nis, len(v))
        out = DriftStep(rec.pose, error_mm, sigma_mm, float(loglik), nis, len(v), bool(taken))
        self.steps.append(out)
        return out

    def _update(self, rec, x0, P0, e, H, R, comp):
        x = x0
        for _ in range(MAX_ITERATIONS):
            innovation = -e - H @ (x0 - x)
            PHt = P0 @ H.T
            S = H @ PHt + R
            K = np.linalg.solve(S, PHt.T).T
            x_new = x0 + K @ innovation
            done = np.max(np.abs(x_new - x) / np.sqrt(np.diag(P0))) < 1e-3
            x = x_new
            if done:
                break
            e, H, R0, _, _ = self._rows(rec, x)
            R = self._scaled(R0, comp)
        PHt = P0 @ H.T
        S = H @ PHt + R
        K = np.linalg.solve(S, PHt.T).T
        P = P0 - K @ S @ K.T
        return x, 0.5 * (P + P.T)

    def estimate(self) -> tuple[list[str], np.ndarray, np.ndarray]:
        """``(names, values (S,), sigmas (S,))`` in file units (mm, deg, µrad, µrad/Nm)."""
        geo = ParameterSet(self.model, tuple(self.params.names))
        scale = np.concatenate([np.where(geo.is_angle, np.degrees(1.0), 1.0),
                                np.full(len(self.names) - self.n_geometric, 1e6)])
        return list(self.names), self.x * scale, np.sqrt(np.maximum(np.diag(self.P), 0.0)) * scale


def _records(ds: Dataset, model: RobotModel, order=None) -> list[PoseData]:
    levels = [lv for lv in ("poses", "centres") if lv in ds.levels()]
    if not levels:
        raise FgcalError(f"{ds.path or 'dataset'}: drift following takes tool poses (poses.csv) or ball centres "
                         f"(centres.csv); this dataset has {', '.join(ds.levels()) or 'no measurements'}")
    recs = pose_records(ds, levels, model=model)
    if order is not None:
        by_id = {r.pose: r for r in recs}
        missing = [int(p) for p in order if int(p) not in by_id]
        if missing:
            raise FgcalError(f"{ds.path or 'dataset'}: pose {missing[0]} is not in the dataset")
        recs = [by_id[int(p)] for p in order]
    return [r for r in recs if r.measured()]


def follow_drift(ds: Dataset, model: RobotModel, spec: JointErrorSpec | None, levels: DriftLevels,
                 noise_factor: float | None = None, order=None, stop_after: int | None = None,
                 design_cache: dict | None = None) -> DriftFilter:
    """Run a :class:`DriftFilter` over the dataset's poses in ``order`` (pose ids; default file
    order, which is time order for a recorded session); ``stop_after``: only the first poses."""
    f = DriftFilter(ds, model, spec, levels, noise_factor, design_cache=design_cache)
    recs = _records(ds, model, order)
    for rec in recs[:stop_after]:
        f.step(rec)
    return f


DRIFT_SCALES = (0.0, 0.3, 1.0, 3.0, 10.0)  # multiples of the base drift tried (geometry and block apart)
NOISE_FACTORS = (3.0, 10.0, 30.0, 100.0, 300.0)  # declared-noise variance factors tried
GROWTH = 3.0  # a grid whose best value is its largest grows by this factor ...
MAX_GROWTH = 4  # ... at most this many times


def _split(base: DriftLevels, geometry: float, block: float) -> DriftLevels:
    """``base`` with its geometric steps scaled by ``geometry`` and the block's by ``block``."""
    return DriftLevels(geometry * base.length_mm, geometry * base.angle_deg, block * base.map_urad,
                       block * base.compliance_urad_per_nm)


def choose_drift(ds: Dataset, model: RobotModel, spec: JointErrorSpec | None, train: int, base: DriftLevels,
                 factors=DRIFT_SCALES, noise_factors=NOISE_FACTORS, order=None, burn_in: float = 0.25):
    """The drift (``base`` with its geometry and its block scaled apart by ``factors``) and the
    noise factor that maximise the one-step-ahead log-likelihood of the first ``train`` poses
    (those after the first ``burn_in`` share of them, where the weak prior still dominates the
    prediction, are scored); the poses after them are never run.

    A coordinate search, each step a grid (grown by :data:`GROWTH` past its largest value, at most
    :data:`MAX_GROWTH` times, while the best is there; a warning when it stops there): the noise
    factor at no drift (the noise a dataset declares is often its instrument's alone, far below
    what a model of the robot fits to), the geometry's and the block's drift on one grid (each
    then grown past its end where the best is there), then the noise factor again.

    Returns
    -------
    levels : DriftLevels
    noise_factor : float
    table : list of dict
        ``{"geometry", "block", "noise_factor", "loglik", "mean_mm"}`` per run (training poses only).
    """
    if train < 4:
        raise FgcalError(f"choosing the drift needs at least 4 training poses, not {train}")
    start = int(burn_in * train)
    table: list[dict] = []
    done: dict = {}
    cache: dict = {}
    has_block = spec is not None and bool(spec.names(model.n_joints))

    def score(g, b, nf):
        key = (float(g), float(b), float(nf))
        if key not in done:
            f = follow_drift(ds, model, spec, _split(base, g, b), nf, order=order, stop_after=train,
                             design_cache=cache)
            scored = f.steps[start:]
            done[key] = {"geometry": key[0], "block": key[1], "noise_factor": key[2],
                         "loglik": float(sum(s.loglik for s in scored)),
                         "mean_mm": float(np.mean([s.error_mm for s in scored]))}
            table.append(done[key])
            log.info("drift x%g (geometry), x%g (block), noise factor %g: training log-likelihood %.1f, "
                     "one-step-ahead mean %.4f mm", g, b, nf, done[key]["loglik"], done[key]["mean_mm"])
        return done[key]["loglik"]

    def best(grid, at):
        """The grid's best value, the grid grown by GROWTH past its largest end while the best is there."""
        grid = sorted(grid)
        top = max(grid, key=at)
        for _ in range(MAX_GROWTH):
            if top != grid[-1] or top <= 0:
                break
            grid.append(grid[-1] * GROWTH)
            top = max(grid, key=at)
        if top == grid[-1] and len(grid) > 1:
            log.warning("the drift's choice stopped at the largest value tried (%g): the optimum may lie beyond it", top)
        return top

    g = b = min(factors)
    nf = best(noise_factors, lambda v: score(g, b, v))
    # the geometry's and the block's drift on one grid: each alone absorbs some of the other's
    # drift, and a search along one at a time stops at the first it tried
    pairs = [(gv, bv) for gv in factors for bv in (factors if has_block else (b,))]
    g, b = max(pairs, key=lambda p: score(p[0], p[1], nf))
    g = best(factors, lambda v: score(v, b, nf))  # grown past the grid's end where the best is there
    if has_block:
        b = best(factors, lambda v: score(g, v, nf))
    nf = best(noise_factors, lambda v: score(g, b, v))
    return _split(base, g, b), nf, table
