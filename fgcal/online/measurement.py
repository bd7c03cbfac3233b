"""One pose's measurement as the online engines use it (one small function per measurement type
builds its rows), the innovation gate and the noise factor estimated from the innovations."""
from __future__ import annotations

import heapq
from dataclasses import dataclass, field

import numpy as np

from fgcal.measurements.distance import DISTANCE
from fgcal.measurements.pose import POSE
from fgcal.measurements.spherefit import chi2_quantile
from fgcal.measurements.types import BY_LEVEL
from fgcal.online.centres import INNOVATION_FALSE_ALARM
from fgcal.online.records import PoseData

__all__ = ["NoiseTracker", "PoseMeasurement", "UpdateReport"]

REDUNDANCY = 0.5  # a pose's innovation informs the noise factor when this share of it is measurement noise


@dataclass
class UpdateReport:
    """What an engine did with a pose; ``journal`` holds what a replay of it needs (JSON types)."""

    pose: int
    accepted: bool
    reason: str = "ok"
    journal: dict = field(default_factory=dict)


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
        # The weighted median in logarithmic time per pose: the estimates below it in a max-heap,
        # the median and those above in a min-heap, split so that the weight below is under half.
        self._low: list[tuple[float, float]] = []  # (-value, weight)
        self._high: list[tuple[float, float]] = []  # (value, weight)
        self._w_low = 0.0
        self._w_total = 0.0
        self.last: tuple[float, float] | None = None  # what the last :meth:`observe` added
        for v, w in values:
            self.add(v, w)

    def add(self, v: float, w: float) -> None:
        """Pool one estimate ``v`` of the factor with weight ``w``."""
        v, w = float(v), float(w)
        self.values.append((v, w))
        if self._high and v >= self._high[0][0]:
            heapq.heappush(self._high, (v, w))
        else:
            heapq.heappush(self._low, (-v, w))
            self._w_low += w
        self._w_total += w
        half = 0.5 * self._w_total
        # The median is the smallest estimate at which the cumulative weight reaches half.
        while self._low and self._w_low >= half:
            nv, nw = heapq.heappop(self._low)
            self._w_low -= nw
            heapq.heappush(self._high, (-nv, nw))
        while self._high and self._w_low + self._high[0][1] < half:
            hv, hw = heapq.heappop(self._high)
            self._w_low += hw
            heapq.heappush(self._low, (-hv, hw))

    def factor(self) -> float:
        """The weighted median of the estimates so far, at least 1 (1 before any)."""
        if not self._high:
            return 1.0
        return max(self._high[0][0], 1.0)

    def observe(self, v, A, R) -> float:
        """Record innovation ``v`` (A, R as above); returns the factor to gate and update it with."""
        f = self.factor()
        m = len(v)
        X = np.linalg.solve(A + f * R, np.hstack([v[:, None], A, R]))  # S^-1 [v, A, R]: one factorisation
        d2, a, b = float(v @ X[:, 0]), float(np.trace(X[:, 1:m + 1])), float(np.trace(X[:, m + 1:]))
        self.last = None
        if f * b >= REDUNDANCY * len(v):
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

    def __init__(self, engine, rec: PoseData, parts, ambiguous=(), taken=None, setup=None):
        sig = engine.sigmas
        self.engine, self.rec, self.parts, self.ambiguous = engine, rec, parts, list(ambiguous)
        self.setup = setup  # a SetupProposal (fgcal.online.setup_blocks): contacts to set-up blocks
        self.taken = taken or {}
        balls = engine.ds.tooling.balls
        self.offsets = np.array([p[0] for p in parts]).reshape(-1, 3)
        self.zs = np.array([p[1] for p in parts]).reshape(-1, 3)
        self.d_offsets = np.array([balls[b] for b, _ in rec.distances]).reshape(-1, 3)
        self.d_lengths = np.array([v for _, v in rec.distances], dtype=float)
        self.generic = _generic_terms(engine, rec) if rec.generic else []  # [(kind, data payload, n)]
        blocks = [p[2] for p in parts]
        if rec.T is not None:
            blocks.append(np.diag(POSE.sigma(sig) ** 2))
        if len(self.d_lengths):
            blocks.append(np.diag(np.tile(DISTANCE.sigma(sig) ** 2, len(self.d_lengths))))
        for kind, _, n in self.generic:
            blocks.append(np.diag(np.tile(np.asarray(kind.sigma(sig), dtype=float) ** 2, n)))
        if setup is not None and setup.n_rows:
            blocks.append(np.diag(setup.sigmas(engine) ** 2))
        m = sum(len(b) for b in blocks)
        self.n_rows = m
        self.R0 = np.zeros((m, m))
        k = 0
        for block in blocks:
            self.R0[k:k + len(block), k:k + len(block)] = block
            k += len(block)
        self.rj = _joint_variances(engine, len(rec.q))  # (n,) rad^2
        self._last = None  # (theta's bytes, value) of the last call
        self._centres_only = bool(len(self.offsets)) and rec.T is None and not len(self.d_lengths) \
            and not self.generic and setup is None
        # The gate's linearisation (:meth:`fgcal.online.base._Engine._screen`): the state ``x`` and
        # covariance ``C`` with the set-up blocks the pose starts, ``C H'`` and ``H C H'``.
        self.gate: tuple | None = None

    def __call__(self, theta):
        key = np.asarray(theta, dtype=float).tobytes()
        if self._last is not None and self._last[0] == key:  # the gate's and the update's first look
            return self._last[1]
        self._last = (key, self._evaluate(theta))
        return self._last[1]

    def bend(self, dx, H, R) -> float:
        """A bound on how far the state's step ``dx`` (P,) moves the measurement from its
        linearisation ``H`` (M, P), whitened by ``R`` (M, M): to second order, a point's second
        derivatives are its first ones turned by a rotation's axis, so the error is at most the
        angles' steps summed (rad) times the point's first-order move bound (mm). Ball centres
        only (inf for other rows, or with set-up entries in the state: relinearised by the step)."""
        engine = self.engine
        if not self._centres_only or len(dx) != len(engine.params):
            return np.inf
        step = np.abs(dx)
        turn = float(step @ engine.is_angle)
        if not turn:
            return 0.0
        columns = np.sqrt(np.add.reduce((H * H).reshape(-1, 3, H.shape[1]), axis=1))  # (B, P): each column's length per ball
        move = columns @ step  # (B,) mm
        return turn * float(np.sqrt(move @ move)) / float(np.sqrt(max(np.linalg.eigvalsh(R)[0], 1e-300)))

    def augment(self, x, P):
        """The state ``(x, P)`` with the set-up blocks this pose starts appended (see
        :meth:`fgcal.online.setup_blocks.SetupProposal.augment`)."""
        return (x, P) if self.setup is None else self.setup.augment(x, P)

    def _evaluate(self, x):
        """At the state ``x``: the robot's parameters (P,), then the set-up blocks' free entries."""
        x = np.asarray(x, dtype=float)
        n_p = len(self.engine.params)
        theta = x[:n_p]
        if self._centres_only and len(x) == n_p:  # ball centres alone (the common pose): the same values, directly
            e, Jt, Jq = _centre_rows(self.engine, theta, self.rec.q, self.offsets, self.zs)
            return e, Jt, self.R0 + (Jq * self.rj) @ Jq.T
        rows = []
        if len(self.offsets):
            rows.append(_centre_rows(self.engine, theta, self.rec.q, self.offsets, self.zs))
        if self.rec.T is not None:
            rows.append(_pose_rows(self.engine, theta, self.rec.q, self.rec.T))
        if len(self.d_lengths):
            rows.append(_distance_rows(self.engine, theta, self.rec.q, self.d_offsets, self.d_lengths))
        for kind, data, n in self.generic:
            rows.append(_generic_rows(self.engine, kind, theta, self.rec.q, data, n))
        if len(x) > n_p:  # set-up entries in the state: the robot's rows do not depend on them
            rows = [(e, np.hstack([Jt, np.zeros((len(Jt), len(x) - n_p))]), Jq) for e, Jt, Jq in rows]
        others = []  # rows of other poses (pending plane contacts) or of none (known distances)
        if self.setup is not None:
            for e, J, Jq, group in self.setup.rows(self.engine, x):
                if group is not None and group.current:
                    rows.append((e, J, Jq))
                else:
                    others.append((e, J, Jq))
        if not rows and not others:
            return np.zeros(0), np.zeros((0, len(x))), np.zeros((0, 0))
        n_joints = len(self.rec.q)
        own = (np.concatenate(c) for c in zip(*rows)) if rows else \
            (np.zeros(0), np.zeros((0, len(x))), np.zeros((0, n_joints)))
        e, Jt, Jq = own
        m0 = len(e)
        Jq_all = np.zeros((m0 + sum(len(o[0]) for o in others), n_joints * (1 + len(others))))
        Jq_all[:m0, :n_joints] = Jq
        k = m0
        for j, (e_o, _, Jq_o) in enumerate(others, start=1):  # each pose's joints apart
            if Jq_o is not None:
                Jq_all[k:k + len(e_o), j * n_joints:(j + 1) * n_joints] = Jq_o
            k += len(e_o)
        if others:
            e = np.concatenate([e] + [o[0] for o in others])
            Jt = np.vstack([Jt] + [o[1] for o in others])
        rj = np.tile(self.rj, 1 + len(others))  # the joints' variances, each pose's joints apart
        return e, Jt, self.R0 + (Jq_all * rj) @ Jq_all.T  # joint noise folded in (diagonal: no product with it)


def _joint_variances(engine, n: int) -> np.ndarray:
    """The joint readings' variances (n,) at the engine's declared noise, formed once per noise
    (its :class:`~fgcal.estimation.graph.Sigmas` are replaced, never changed); not to be written to."""
    sig = engine.sigmas
    kept = getattr(engine, "_joint_variances", None)
    if kept is None or kept[0] is not sig or len(kept[1]) != n:
        kept = engine._joint_variances = (sig, np.broadcast_to(np.asarray(sig.joint, dtype=float) ** 2, (n,)).copy())
    return kept[1]


def _generic_terms(engine, rec: PoseData) -> list:
    """The pose's measurements of the types taken through the protocol (:func:`fgcal.online.records.generic_types`):
    ``(kind, data payload, n)`` per level in the order the pose has them, the payload from the type's
    ``terms`` of its ``observations``."""
    out = []
    for level in dict.fromkeys(lv for lv, _, _ in rec.generic):
        kind = BY_LEVEL[level]
        mine = [(b, v) for lv, b, v in rec.generic if lv == level]
        obs = kind.observations(np.full(len(mine), rec.pose, dtype=int), np.array([b for b, _ in mine]),
                                np.array([v for _, v in mine], dtype=float).reshape(len(mine), -1))
        out.append((kind, kind.terms(obs, engine.ds.tooling, {rec.pose: 0}).data, len(mine)))
    return out


def _generic_rows(engine, kind, theta, q, data, n):
    """A registered type's rows (``width`` per measurement) from its ``error``, J_theta, J_q."""
    qs = np.broadcast_to(q, (n, len(q)))
    e, jt, jq = kind.error(theta, qs, data, engine.index, engine.held, engine.model.chain)
    return (np.asarray(e).reshape(-1), np.asarray(jt).reshape(-1, np.shape(jt)[-1]),
            np.asarray(jq).reshape(-1, np.shape(jq)[-1]))


def _centre_rows(engine, theta, q, offsets, centres):
    """Ball centres: rows ``FK(theta, q) offset - centre`` (3 per ball), J_theta, J_q."""
    h, jt, jq = engine._ball_kinematics(theta, q, offsets)
    return (h - centres).ravel(), jt.reshape(-1, jt.shape[-1]), jq.reshape(-1, jq.shape[-1])


def _pose_rows(engine, theta, q, T):
    """A measured tool pose (:mod:`fgcal.measurements.pose`): 6 rows (rotation log, rad; position, mm), J_theta, J_q."""
    e, jt, jq = POSE.error(theta, q[None], (T[None],), engine.index, engine.held, engine.model.chain)
    return e[0], jt[0], jq[0]


def _distance_rows(engine, theta, q, offsets, lengths):
    """Ballbar lengths (:mod:`fgcal.measurements.distance`): one row per ball (mm), J_theta, J_q."""
    qs = np.broadcast_to(q, (len(lengths), len(q)))
    e, jt, jq = DISTANCE.error(theta, qs, (offsets, lengths), engine.index, engine.held, engine.model.chain)
    return e[:, 0], jt[:, 0], jq[:, 0]
