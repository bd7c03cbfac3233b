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

__all__ = ["PoseData", "pose_records", "prefit", "records_dataset", "weak_prior", "UpdateReport", "NoiseTracker",
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
    # probe index -> (its points, plain SphereFit, its mirror image (3,)), from :func:`prefit`
    fits: dict | None = field(default=None, repr=False, compare=False)

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
    """What an engine did with a pose; ``journal`` holds what a replay of it needs (JSON types)."""

    pose: int
    accepted: bool
    reason: str = "ok"
    journal: dict = field(default_factory=dict)


def _good_centres(rec: PoseData, tooling, sigma_cmm: float, min_balls: int = 3, prediction=None, flip=(),
                  search: bool = False):
    """Fitted centres of a pose's probed balls: ``(good, ambiguous, None)`` or ``(None, [], reason)``.

    ``good``: ``(ball, xyz, cov)`` per usable ball. ``prediction`` (ball -> xyz, mm): where the
    current estimate puts each ball. As in the batch solve, of the centres that fit a cap of
    points equally well (the fit and its mirror image through the points) the one nearer the
    prediction is taken, and a residual above the sphere check's limit is left to the innovation
    gate. A ball whose plain fit passes its check and lies near its prediction (within a quarter
    of the radius, and nearer it than a quarter of the way to its mirror image) is taken as fitted:
    the search among mirror images, which costs most of a pose's time, runs for the other balls,
    or for all with ``search`` (the innovation gate's second look). ``ambiguous``: the balls
    searched whose mirror image fits as well (the gate may take it for the balls in ``flip``).
    """
    good, bad = [], []
    usable = [(b, p) for b, p in rec.probes if len(p) >= 3]
    bad += [f"ball {b}: {len(p)} probe points" for b, p in rec.probes if len(p) < 3]
    sigma = max(sigma_cmm, 1e-6)
    prefit([rec], tooling, sigma_cmm)
    fits = [rec.fits[j][1:] for j, (_, p) in enumerate(rec.probes) if len(p) >= 3]
    kept = []
    for (ball, pts), (fit, mirror) in zip(usable, fits):
        # A residual above the sphere check's limit alone does not reject the ball: as in the batch
        # solve, the innovation gate (with the kinematic prediction's redundancy) judges the pose.
        if not fit.ok and not (prediction is not None and fit.status.startswith("residual")):
            bad.append(f"ball {ball}: {fit.status}")
            continue
        kept.append((ball, pts, fit, mirror))
    chosen, ambiguous = {}, []
    if prediction is not None:
        kept_pred = [k for k in kept if k[0] in prediction]
        if not search and kept_pred:
            kept_pred = [k for k, plain in zip(kept_pred, _plain_fit_will_do(kept_pred, prediction, tooling.radius))
                         if not plain]
        chosen, ambiguous = _search_mirrors([k[:3] for k in kept_pred], prediction, tooling.radius, sigma, flip)
    for ball, pts, fit, _ in kept:
        centre, cov = fit.centre, fit.covariance
        if ball in chosen and np.linalg.norm(chosen[ball] - centre) > 1e-9:
            d = pts - chosen[ball]
            J = d / np.linalg.norm(d, axis=1, keepdims=True)
            centre, cov = chosen[ball], np.linalg.inv(J.T @ J) * sigma**2
        good.append((ball, centre, cov))
    if rec.probes and len(good) < min_balls:
        return None, [], f"{len(good)} good ball(s) of {len(rec.probes)}; a pose needs {min_balls}" + (
            f" ({'; '.join(bad)})" if bad else "")
    return good, ambiguous, None


def _plain_fit_will_do(kept, prediction, radius) -> np.ndarray:
    """For each ``(ball, points, fit, mirror)``: its fit passed its check and lies near the
    prediction (a quarter of the radius, and a quarter of the way to its mirror image): any other
    start would end in the same minimum."""
    ok = np.array([fit.ok for _, _, fit, _ in kept])
    centre = np.array([fit.centre for _, _, fit, _ in kept])
    pred = np.array([prediction[b] for b, _, _, _ in kept])
    d_pred = np.linalg.norm(centre - pred, axis=1)
    d_mirror = np.linalg.norm(centre - np.array([m for _, _, _, m in kept]), axis=1)
    return ok & (d_pred < 0.25 * radius) & (d_pred < 0.25 * d_mirror)


def prefit(records, tooling, sigma_cmm: float) -> None:
    """The plain sphere fit of every probed ball (3 points or more) of ``records`` and its mirror
    image through the points, kept on each record (``fits``): all at once, vectorised (each
    ball's fit is the one a fit of its pose alone gives). Records that have them are left alone."""
    def stale(r, j, p):
        return r.fits is None or j not in r.fits or r.fits[j][0] is not p

    todo = [(r, j, p) for r in records for j, (_, p) in enumerate(r.probes) if len(p) >= 3 and stale(r, j, p)]
    for r in records:
        if r.fits is None:
            r.fits = {}
    if not todo:
        return
    fits = fit_spheres_checked([p for _, _, p in todo], tooling.radius, max(sigma_cmm, 1e-6))
    counts = np.array([len(p) for _, _, p in todo])
    mirrors = np.empty((len(todo), 3))
    for n in np.unique(counts):
        idx = np.nonzero(counts == n)[0]
        mirrors[idx] = mirror_through_points(np.array([todo[i][2] for i in idx]),
                                             np.array([fits[i].centre for i in idx]))
    for (r, j, p), fit, mirror in zip(todo, fits, mirrors):
        r.fits[j] = (p, fit, mirror)  # the points themselves: a record whose points are replaced is fitted again


def _search_mirrors(kept, prediction, radius, sigma, flip):
    """Of each ball's fit, its mirror image and a fit started at the prediction, the one the batch
    takes; balls with equal point counts at once. Returns ``(ball -> centre, ambiguous balls)``."""
    chosen, ambiguous = {}, []
    by_count: dict[int, list] = {}
    for ball, pts, fit in kept:
        by_count.setdefault(len(pts), []).append((ball, pts, fit))
    for group in by_count.values():
        pts = np.array([p for _, p, _ in group])
        first = np.array([f.centre for _, _, f in group])
        pred = np.array([prediction[b] for b, _, _ in group])
        refits = fit_spheres_batch(np.concatenate([pts, pts]), radius,
                                   guess=np.concatenate([mirror_through_points(pts, first), pred]))
        cands = [first, refits[:len(group)], refits[len(group):]]
        near = best_of_candidates(pts, radius, cands, sigma, pred)
        # the mirror image, where it fits nearly as well (within the 1e-6 chi-square limit of
        # one residual): the innovation gate may take it for the balls in ``flip``
        other = fit_spheres_batch(pts, radius, guess=mirror_through_points(pts, near))
        ssr = [np.sum((np.linalg.norm(pts - c[:, None], axis=2) - radius) ** 2, axis=1) for c in (near, other)]
        alike = (ssr[1] <= ssr[0] + MIRROR_CHI2 * sigma**2) & (np.linalg.norm(other - near, axis=1) > radius)
        for k, (ball, _, _) in enumerate(group):
            if alike[k]:
                ambiguous.append(ball)
            chosen[ball] = other[k] if (ball in flip and alike[k]) else near[k]
    return chosen, ambiguous


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

    def __init__(self, values=()):
        self.values: list[tuple[float, float]] = []  # (estimate of f, weight), in the order seen
        self._v = np.empty(0)  # the estimates sorted, and their weights: the median in linear time
        self._w = np.empty(0)
        self.last: tuple[float, float] | None = None  # what the last :meth:`observe` added
        for v, w in values:
            self.add(v, w)

    def add(self, v: float, w: float) -> None:
        """Pool one estimate ``v`` of the factor with weight ``w``."""
        self.values.append((float(v), float(w)))
        k = int(np.searchsorted(self._v, v, side="right"))
        self._v = np.insert(self._v, k, v)
        self._w = np.insert(self._w, k, w)

    def factor(self) -> float:
        """The weighted median of the estimates so far, at least 1 (1 before any)."""
        if not len(self._v):
            return 1.0
        cum = np.cumsum(self._w)
        return float(max(self._v[np.searchsorted(cum, 0.5 * cum[-1])], 1.0))

    def observe(self, v, A, R) -> float:
        """Record innovation ``v`` (A, R as above); returns the factor to gate and update it with."""
        f = self.factor()
        Si = np.linalg.inv(A + f * R)
        d2, a, b = float(v @ Si @ v), float(np.trace(Si @ A)), float(np.trace(Si @ R))
        self.last = None
        if f * b >= 0.5 * len(v):
            self.add(max((d2 - a) / b, 0.0), f * b)
            self.last = self.values[-1]
        return self.factor()

    @staticmethod
    def implausible(v, S) -> str | None:
        """The gate: a rejection reason when ``v' S^-1 v`` is beyond the chi-square limit."""
        d2 = float(v @ np.linalg.solve(S, v))
        if d2 > chi2_quantile(1 - INNOVATION_FALSE_ALARM, len(v)):
            return f"innovation implausible (chi-square {d2:.3g} for {len(v)} measurements)"
        return None


class PoseMeasurement:
    """One pose's measurement as the engines use it: ``m(theta)`` gives the stacked residual
    ``h(theta) - z`` (M,), its Jacobian (M, P) and the declared noise R (M, M) with the joints'
    noise folded in. One function per measurement type builds its rows (:func:`_centre_rows`,
    :func:`_pose_rows`, :func:`_distance_rows`).

    Attributes
    ----------
    parts : list of (offset (3,), centre (3,), covariance (3, 3))
        The ball centres taken (fitted or measured), tool-frame offsets and world centres in mm.
    ambiguous : list of str
        Balls whose mirror image fits as well (see :func:`_good_centres`).
    taken : dict
        How the pose was taken when not as it came: ``flip`` (balls), ``drop`` ([ball index,
        point index]), ``search`` (the mirror search ran for every ball); what a replay needs.
    """

    def __init__(self, engine, rec: PoseData, parts, ambiguous=(), taken=None):
        sig = engine.sigmas
        self.engine, self.rec, self.parts, self.ambiguous = engine, rec, parts, list(ambiguous)
        self.taken = taken or {}
        balls = engine.ds.tooling.balls
        self.offsets = np.array([p[0] for p in parts]).reshape(-1, 3)
        self.zs = np.array([p[1] for p in parts]).reshape(-1, 3)
        self.d_offsets = np.array([balls[b] for b, _ in rec.distances]).reshape(-1, 3)
        self.d_lengths = np.array([v for _, v in rec.distances], dtype=float)
        blocks = [p[2] for p in parts]
        if rec.T is not None:
            blocks.append(np.diag([sig.pose_rotation**2] * 3 + [sig.pose_position**2] * 3))
        if len(self.d_lengths):
            blocks.append(np.eye(len(self.d_lengths)) * sig.distance**2)
        m = sum(len(b) for b in blocks)
        self.R0 = np.zeros((m, m))
        k = 0
        for block in blocks:
            self.R0[k:k + len(block), k:k + len(block)] = block
            k += len(block)
        self.Rj = np.diag(np.broadcast_to(np.asarray(sig.joint, dtype=float) ** 2, (len(rec.q),)))

    def __call__(self, theta):
        rows = []
        if len(self.offsets):
            rows.append(_centre_rows(self.engine, theta, self.rec.q, self.offsets, self.zs))
        if self.rec.T is not None:
            rows.append(_pose_rows(self.engine, theta, self.rec.q, self.rec.T))
        if len(self.d_lengths):
            rows.append(_distance_rows(self.engine, theta, self.rec.q, self.d_offsets, self.d_lengths))
        e, Jt, Jq = (np.concatenate(x) for x in zip(*rows))
        return e, Jt, self.R0 + Jq @ self.Rj @ Jq.T  # joint noise folded in


def _centre_rows(engine, theta, q, offsets, centres):
    """Ball centres: rows ``FK(theta, q) offset - centre`` (3 per ball), J_theta, J_q."""
    h, jt, jq = engine._ball_kinematics(theta, q, offsets)
    return (h - centres).ravel(), jt.reshape(-1, jt.shape[-1]), jq.reshape(-1, jq.shape[-1])


def _pose_rows(engine, theta, q, T):
    """A measured tool pose: 6 rows (rotation log, rad; position, mm), J_theta, J_q."""
    e, jt, jq = fx.pose_error(theta, q[None], T[None], engine.index, engine.held, engine.model.chain)
    return e[0], jt[0], jq[0]


def _distance_rows(engine, theta, q, offsets, lengths):
    """Ballbar lengths: one row per ball (mm), J_theta, J_q."""
    qs = np.broadcast_to(q, (len(lengths), len(q)))
    e, jt, jq = fx.distance_error(theta, qs, offsets, lengths, engine.index, engine.held, engine.model.chain)
    return e[:, 0], jt[:, 0], jq[:, 0]


def _variant(rec: PoseData, taken: dict) -> PoseData:
    """The pose as taken (``taken["drop"]``: one probe point left out)."""
    if not taken.get("drop"):
        return rec
    j, k = taken["drop"]
    out = PoseData(rec.pose, rec.q, list(rec.probes), list(rec.centres), rec.T, list(rec.distances),
                   None if rec.fits is None else dict(rec.fits))
    ball, pts = rec.probes[j]
    out.probes[j] = (ball, np.delete(pts, k, axis=0))
    return out


class _Engine:
    def __init__(self, ds: Dataset, model: RobotModel, options: CalibrationOptions = CalibrationOptions(),
                 names=None):
        self.ds = ds
        self.model = model
        self.options = options
        self.params = model.parameters() if names is None else ParameterSet(model, tuple(names))
        self.index = self.params.index  # slot of each parameter (P,) (a property that builds it anew)
        self.held = model.nominal.copy()
        self.sigmas: Sigmas = _sigmas(ds, model, options)
        self.prior_sigma = weak_prior(self.params)
        self.n_accepted = 0
        self.noise = NoiseTracker()
        self.records: list[PoseData] = []  # the accepted poses (as taken: a bad probe point left out)
        self.seen: dict[int, PoseData] = {}  # every pose fed with measurements, for the final smoothing
        self._final = None
        self._kinematics: dict = {}

    def estimate(self):
        """``(theta (P,), covariance (P, P))`` in internal units."""
        raise NotImplementedError

    def _current(self) -> np.ndarray:
        raise NotImplementedError

    def _ball_kinematics(self, theta, q, offsets):
        """``(FK(theta, q) offsets (B, 3), J_theta (B, 3, P), J_q (B, 3, n))``, kept for the last few
        arguments: the prediction, the innovation and the filter's first linearisation share one."""
        key = (np.asarray(theta, dtype=float).tobytes(), q.tobytes(), offsets.tobytes())
        hit = self._kinematics.get(key)
        if hit is None:
            if len(self._kinematics) >= 8:
                self._kinematics.clear()
            hit = self._kinematics[key] = fx.pose_ball_centres_error(
                theta, q, offsets, np.zeros_like(offsets), self.index, self.held, self.model.chain)
        return hit

    def _prediction(self, rec: PoseData, theta) -> dict:
        balls = [b for b, _ in rec.probes]
        if not balls:
            return {}
        h, _, _ = self._ball_kinematics(theta, rec.q, np.array([self.ds.tooling.balls[b] for b in balls]))
        return dict(zip(balls, h))

    def _measurement(self, rec: PoseData, flip=(), search: bool = False):
        """``(PoseMeasurement, None)`` or ``(None, reason)``, at the current estimate's prediction."""
        sig = self.sigmas
        parts, ambiguous = [], []
        if rec.probes:
            good, ambiguous, reason = _good_centres(rec, self.ds.tooling, self.ds.noise.cmm_sigma,
                                                    prediction=self._prediction(rec, self._current()), flip=flip,
                                                    search=search)
            if good is None:
                return None, reason
            parts += [(self.ds.tooling.balls[b], c, cov) for b, c, cov in good]
        parts += [(self.ds.tooling.balls[b], xyz, np.eye(3) * sig.centre**2) for b, xyz in rec.centres]
        if not parts and rec.T is None and not rec.distances:
            return None, "no measurements"
        taken = {k: v for k, v in (("flip", list(flip)), ("search", search)) if v}
        return PoseMeasurement(self, rec, parts, ambiguous, taken), None

    def _screen(self, rec: PoseData, theta, cov):
        """The pose's measurement if it passes the checks and the innovation gate at the current
        ``theta`` and its covariance ``cov``; else the variant (mirror images of ambiguous balls,
        then, as the batch solve excludes single probe points, one probe point left out) that
        passes with the smallest innovation. Returns ``(measurement, record used, noise factor,
        None)`` or ``(None, rec, f, reason)``."""
        if rec.measured():
            self.seen[rec.pose] = rec
            self._final = None

        def statistic(r, flip=(), search=False):
            m, why = self._measurement(r, flip, search)
            if m is None:
                return None, why, None
            e, H, R = m(theta)
            return m, None, (-e, H @ cov @ H.T, R)

        m, reason, vAR = statistic(rec)
        f = self.noise.observe(*vAR) if vAR is not None else self.noise.factor()
        if m is not None:
            reason = NoiseTracker.implausible(vAR[0], vAR[1] + f * vAR[2])
            if reason is None:
                return m, rec, f, None
        # Where the prediction is still poor (early poses), a ball's mirror image may be the
        # consistent one: search them all, and try them; then single probe points left out. The
        # passing variant with the smallest innovation is taken.
        from itertools import combinations

        def best_of(variants):
            best = None
            for variant, flip, drop in variants:
                m_k, _, vAR_k = statistic(variant, flip, search=True)
                if m_k is None:
                    continue
                v, A, R = vAR_k
                d2 = float(v @ np.linalg.solve(A + f * R, v))
                if NoiseTracker.implausible(v, A + f * R) is None and (best is None or d2 < best[0]):
                    if drop is not None:
                        m_k.taken["drop"] = list(drop)
                    best = (d2, m_k, variant)
            return best

        def without_one(rec):
            for j, (ball, pts) in enumerate(rec.probes):
                for k in range(len(pts) if len(pts) >= 4 else 0):
                    yield _variant(rec, {"drop": (j, k)}), (), (j, k)

        searched = self._measurement(rec, search=True)[0] if rec.probes else m
        amb = searched.ambiguous if searched is not None else []
        flips = ((rec, flip, None) for n in range(len(amb) + 1) for flip in combinations(amb, n))
        best = best_of(flips) or best_of(without_one(rec))
        if best is not None:
            return best[1], best[2], f, None
        return None, rec, f, reason

    def _report(self, rec: PoseData, reason=None, m: PoseMeasurement | None = None, f: float = 1.0) -> UpdateReport:
        """The pose's report (accepted when ``reason`` is None), with what a replay needs: the
        noise estimate the pose added, and for an accepted pose its noise factor and how it was taken."""
        journal = {} if self.noise.last is None else {"noise": list(self.noise.last)}
        if reason is not None:
            return UpdateReport(rec.pose, False, reason, journal)
        self.records.append(rec)
        self.n_accepted += 1
        self._final = None
        journal["f"] = f
        if m is not None:
            journal.update(m.taken)
        return UpdateReport(rec.pose, True, "ok", journal)

    def _replayed(self, rec: PoseData, entry: dict, measure: bool = True):
        """Book-keeping of a journalled pose (noise, poses seen); for an accepted one, the record as
        taken and (``measure``) its measurement at the current estimate; ``(None, None)`` for a
        refused one."""
        self.noise.last = None
        if entry.get("noise"):
            self.noise.add(*entry["noise"])
        if rec.measured():
            self.seen[rec.pose] = rec
        self._final = None
        if not entry["accepted"]:
            return None, None
        used = _variant(rec, entry)
        if not measure:
            return used, None
        m, reason = self._measurement(used, entry.get("flip", ()), entry.get("search", False))
        if m is None:
            raise FgcalError(f"restoring pose {rec.pose}: {reason}")
        return used, m

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
    """Incremental smoothing over the same factors as the batch graph, in segments of ``window`` poses."""

    snapshots = False  # the tree cannot be stored: a resume replays the journal

    def __init__(self, ds, model, options=CalibrationOptions(), names=None, theta_threshold=(0.05, 1e-4),
                 factorization="CHOLESKY", window: int = 50):
        """``window``: poses (their joint variables and factors) in one tree. When it is full the
        tree is replaced by a new one whose only factor is the parameters' marginal, a Gaussian at
        the current estimate: each pose's information stays, its linearisation is frozen (as a
        marginalised leaf's would be), and each update's cost and the memory stay bounded (measured
        at 1000 poses: the running estimate within 0.01 sigma of an unsegmented tree's)."""
        import gtsam

        super().__init__(ds, model, options, names)
        self.window = window
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
        thresholds.insert(("q", np.full(model.n_joints, 1e-5)))
        p.setRelinearizeThreshold(thresholds)
        p.relinearizeSkip = 1
        self._isam_params = p
        self.t_key = fx.theta_key()
        self._tree(None)
        self._started = False

    def _tree(self, prior) -> None:
        """A new, empty tree; ``prior``: the factor its first update adds on the parameters."""
        import gtsam

        self.isam = gtsam.ISAM2(self._isam_params)
        self._prior = prior
        self._in_tree = 0  # poses in this tree
        self._linpoint = None
        self._keep = []  # the factors' closures reference their arguments: keep them alive
        self._est = None  # (theta, covariance) of the tree as it is

    def _current(self) -> np.ndarray:
        return self.estimate()[0]

    def update(self, rec: PoseData) -> UpdateReport:
        # The innovation against the current estimate, at the noise estimated so far.
        theta, cov = self._running()
        m, used, f, reason = self._screen(rec, theta, cov)
        if m is None:
            return self._report(rec, reason)
        self._add(used, m.parts, f)
        return self._report(used, None, m, f)

    def _add(self, rec: PoseData, parts, f: float) -> None:
        """Add an accepted pose's factors, its noise scaled by the factor ``f``."""
        import gtsam

        sig = self.sigmas
        i = rec.pose
        if self._in_tree >= self.window:  # the tree is full: its marginal starts the next one
            theta, cov = self._running()
            self._tree(gtsam.PriorFactorVector(self.t_key, theta, gtsam.noiseModel.Gaussian.Covariance(cov)))
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        if self._in_tree == 0:
            start = self.params.nominal() if self._prior is None else self._prior.prior()
            graph.add(self._prior or fx.parameter_prior(self.t_key, start, self.prior_sigma))
            values.insert(self.t_key, start)
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
        self._in_tree += 1
        self._est = None
        self._started = True

    def restore(self, state, journal) -> None:
        """Rebuild the tree from the journalled poses ``journal`` ((record, entry) pairs, in order):
        each accepted pose is added again as it was taken, without its screening (``state`` unused)."""
        for rec, entry in journal:
            used, m = self._replayed(rec, entry)
            if m is not None:
                self._add(used, m.parts, entry["f"])
                self._report(used, None, m, entry["f"])

    def finish(self) -> None:
        """The final smoothing (see :meth:`_Engine._smooth`); the incremental state stays as it was."""
        if self.seen and self._final is None:
            self._final = self._smooth()

    def _running(self):
        """The tree's ``(theta, covariance)`` (kept until the next pose is added)."""
        if not self._started:
            return self.params.nominal(), np.diag(self.prior_sigma**2)
        if self._est is None:
            self._est = (self.isam.calculateEstimateVector(self.t_key), self.isam.marginalCovariance(self.t_key))
        return self._est

    def estimate(self):
        if self._final is not None:
            return self._final
        theta, cov = self._running()
        return theta.copy(), cov.copy()


@dataclass
class FilterState:
    """A filter's state: the parameters ``x`` (P,), their covariance ``P`` (P, P) and the
    random-walk process noise ``Q`` (P, P) added before each pose (internal units)."""

    x: np.ndarray
    P: np.ndarray
    Q: np.ndarray


class KalmanEngine(_Engine):
    """A Kalman filter over the parameter vector: iterated EKF (``ekf``, its update in numpy in
    filterpy's Joseph form: filterpy's import alone costs more than a thousand updates) or
    filterpy's unscented filter (``ukf``)."""

    snapshots = True  # the state is small: a resume restores the last snapshot and replays after it

    def __init__(self, ds, model, options=CalibrationOptions(), names=None, kind="ekf", drift=None,
                 max_iterations=20):
        super().__init__(ds, model, options, names)
        if kind not in ("ekf", "ukf"):
            raise FgcalError(f"unknown filter {kind!r} (ekf, ukf)")
        self.kind = kind
        P = len(self.params)
        self.kf = FilterState(self.params.nominal().copy(), np.diag(self.prior_sigma**2),
                              np.zeros((P, P)) if drift is None else np.diag(np.asarray(drift, dtype=float) ** 2))
        self.max_iterations = max_iterations
        self._ukf = None

    def _current(self) -> np.ndarray:
        return self.kf.x

    def update(self, rec: PoseData) -> UpdateReport:
        x0 = self.kf.x.copy()
        P0 = self.kf.P + self.kf.Q  # random-walk prediction
        m, used, f, reason = self._screen(rec, x0, P0)  # f: the measurement noise estimated so far
        if m is None:
            return self._report(rec, reason)
        if self.kind == "ekf":
            reason = self._iterated_update(m, x0, P0, f)
            if reason:
                return self._report(rec, reason)
        else:
            self._unscented_update(m, x0, P0, f)
        return self._report(used, None, m, f)

    def _iterated_update(self, m: PoseMeasurement, x0, P0, f: float) -> str | None:
        """The iterated EKF's update of ``(x0, P0)`` by ``m`` at noise factor ``f``; a reason when
        the innovation at the iterated point is implausible (the state is then untouched)."""
        x = x0.copy()
        sigma0 = np.sqrt(np.diag(P0))
        for _ in range(self.max_iterations):
            e, H, R = m(x)
            innovation = -e - H @ (x0 - x)
            PHt = P0 @ H.T
            S = H @ PHt + f * R
            K = np.linalg.solve(S, PHt.T).T
            x_new = x0 + K @ innovation
            # Relinearise while the step is a noticeable fraction of the prior's spread: the
            # error of a linearisation that far off is second order, ~1e-2 of a sigma.
            if np.max(np.abs(x_new - x) / sigma0) < 0.1:
                break
            x = x_new
        reason = NoiseTracker.implausible(innovation, S)
        if reason:
            return reason
        # Joseph form, linearised at the iterated point: symmetric and positive whatever the rounding
        I_KH = np.eye(len(x0)) - K @ H
        self.kf.x = x0 + K @ innovation
        self.kf.P = I_KH @ P0 @ I_KH.T + K @ (f * R) @ K.T
        return None

    def _unscented_update(self, m: PoseMeasurement, x0, P0, f: float) -> None:
        from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

        e0, _, R = m(x0)
        n = len(x0)
        if self._ukf is None:  # one filter, reused: each pose brings its own hx, R and size
            points = MerweScaledSigmaPoints(n, alpha=0.1, beta=2.0, kappa=3.0 - n)
            self._ukf = UnscentedKalmanFilter(dim_x=n, dim_z=len(e0), dt=1.0, fx=lambda s, dt: s,
                                              hx=None, points=points)
        ukf = self._ukf
        ukf.x, ukf.P, ukf.Q = x0.copy(), P0.copy(), np.zeros((n, n))
        ukf.predict()
        ukf.update(np.zeros(len(e0)), R=f * R, hx=lambda s: m(s)[0])
        self.kf.x, self.kf.P = ukf.x.copy(), 0.5 * (ukf.P + ukf.P.T)

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
        """The filter's state (a snapshot: its size does not grow with the poses)."""
        return {"x": self.kf.x.tolist(), "P": self.kf.P.tolist()}

    def restore(self, state: dict, journal) -> None:
        """The state of a snapshot taken after the journalled poses ``journal`` ((record, entry)
        pairs, in order), whose book-keeping (noise, poses seen and taken) is rebuilt from them."""
        for rec, entry in journal:
            used, _ = self._replayed(rec, entry, measure=False)
            if used is not None:
                self._report(used, None, None, entry["f"])
        self.kf.x = np.array(state["x"], dtype=float)
        self.kf.P = np.array(state["P"], dtype=float)


def make_engine(kind: str, ds: Dataset, model: RobotModel, options=CalibrationOptions(), **kw):
    if kind == "isam2":
        return ISAM2Engine(ds, model, options, **kw)
    if kind in ("ekf", "ukf"):
        return KalmanEngine(ds, model, options, kind=kind, **kw)
    raise FgcalError(f"unknown engine {kind!r} (isam2, ekf, ukf)")

