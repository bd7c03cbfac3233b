"""What one pose's measurements tell about the parameters: the design's information model.

The information is built from the estimator's own measurement definitions (the error functions
of :mod:`factors.errors` and the graph's noise, :class:`fgcal.estimation.graph.Sigmas`), evaluated at the
predicted measurements of the model, never from a second copy of the measurement model:

* ``probes``: per measured ball, ``probes_per_ball`` points on its accessible cap
  (:func:`factors.errors.probe_error` about a ball-centre variable) and the centre at the forward
  kinematics (:func:`factors.errors.ball_centre_error`, the graph's tight "kinematic" factor);
* ``centres``: a measured ball centre or tracker reflector (position only),
  :func:`factors.errors.ball_centre_error`;
* ``poses``: a measured tool pose, :func:`factors.errors.pose_error`;
* contacts and other types with set-up blocks (``uses_setup``): the ball at its fixture point or
  on its plane, the type's ``setup_error`` at its ``design_data``, in the parameters and the
  free set-up entries, which close the information (a plan marginalises them);
* the joint readings as priors on the pose's joint variables (when they carry noise).

Each pose's local variables (its joints, its ball centres) are eliminated as the estimator
eliminates them (a per-pose Schur complement, here by QR for accuracy), leaving that pose's
information about the parameters; plans add these up.

When the data's error is not what the estimator weighs it by (the robot's unmodelled errors,
seen as a random joint-space error that the joint readings do not show), the covariance of the
estimate is the sandwich ``M^-1 B M^-1``: ``M`` the information at the estimator's weights and
``B`` (:func:`information_and_middle`) the same rows' second moment under the actual error.
No I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from factors.errors import ball_centre_error, probe_error
from fgcal.errors import FgcalError
from fgcal.estimation.build import _sigmas
from fgcal.estimation.graph import Sigmas
from fgcal.estimation.options import CalibrationOptions
from fgcal.measurements.dataset import Dataset, Noise
from fgcal.measurements.setup import SetupLayout
from fgcal.measurements.types import kinematic_levels
from fgcal.robots.model import ParameterSet, RobotModel, Tooling
from fgcal.studies.plans import UP, ball_access

__all__ = [
    "Layout",
    "cap_directions",
    "information",
    "information_and_middle",
    "joint_sensitivity",
    "layout_from_access",
    "sigmas_of",
]



@dataclass
class Layout:
    """What is measured at each of N poses.

    Attributes
    ----------
    levels : tuple of str
        Measurement levels: ``probes`` and any registered measurement type's.
    balls : ndarray of bool, shape (N, B)
        Balls (tooling order) measured at each pose, for the ``probes`` and ``centres`` levels.
    probes_per_ball : int
    contacts : dict of str to ndarray of str, shape (N, B)
        For measurement types with set-up blocks (``uses_setup``): the fixture each ball touches
        at each pose ("" for none), per level.
    setup : fgcal.measurements.setup.SetupLayout, optional
        The set-up blocks of those contacts, at the values designed for (their start). Their free
        entries follow the parameters in the information: they are estimated with the robot, and
        a plan's criterion marginalises them.
    """

    levels: tuple
    balls: np.ndarray
    probes_per_ball: int = 4
    contacts: dict = field(default_factory=dict)
    setup: SetupLayout | None = None

    def usable(self) -> np.ndarray:
        """(N,) bool: the pose gives at least one measurement."""
        if "poses" in self.levels:
            return np.ones(len(self.balls), dtype=bool)
        return np.asarray(self.balls.any(axis=1) | self.touching().any(axis=1))

    def touching(self) -> np.ndarray:
        """(N, levels with set-up blocks) int: each pose's contacts per such level."""
        return np.column_stack([np.sum(f != "", axis=1) for f in self.contacts.values()] or
                               [np.zeros(len(self.balls), dtype=int)])

    @property
    def n_setup(self) -> int:
        """Free set-up entries after the parameters in the information (0 without set-up blocks)."""
        return 0 if self.setup is None else self.setup.n_free


def sigmas_of(noise: Noise, model: RobotModel) -> Sigmas:
    """The graph's noise for each factor kind, exactly as the estimator sets it from ``noise``."""
    stub = Dataset(robot="", tooling=model.tooling or Tooling(0.0, {}), noise=noise, provenance={},
                   pose_ids=np.zeros(0, dtype=int), joints_deg=np.zeros((0, model.n_joints)))
    return _sigmas(stub, model, CalibrationOptions())


def cap_directions(axis, n_points: int, polar_deg: float = 60.0) -> np.ndarray:
    """``n_points`` unit vectors (n_points, 3): the pole ``axis``, then a ring ``polar_deg`` away."""
    a = np.asarray(axis, dtype=float)
    norm = np.linalg.norm(a)
    a = UP if not np.isfinite(norm) or norm < 1e-12 else a / norm
    h = np.array([1.0, 0, 0]) if abs(a[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = np.cross(a, h)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    p = np.radians(polar_deg)
    ring = [np.cos(p) * a + np.sin(p) * (np.cos(t) * e1 + np.sin(t) * e2)
            for t in 2 * np.pi * np.arange(n_points - 1) / max(n_points - 1, 1)]
    return np.array([a, *ring])[:n_points]


def layout_from_access(model: RobotModel, q, levels, n_balls: int = 3, slots=None, probes_per_ball: int = 4,
                       margin_mm: float = 0.0, margin_deg: float = 0.0) -> Layout:
    """The balls an instrument measures at joint sets ``q`` (N, n) rad: the ``n_balls`` most
    accessible of those :func:`fgcal.studies.plans.ball_access` allows (as the simulator picks them).

    Poses with fewer than ``n_balls`` accessible balls measure none (they are not usable for the
    ball levels). A model without a measuring volume is taken to see every ball (a tracker).
    """
    tooling = model.tooling
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if tooling is None or not tooling.balls:
        return Layout(tuple(levels), np.zeros((len(q), 0), dtype=bool), probes_per_ball)
    x = model.nominal if slots is None else np.asarray(slots, dtype=float)
    ok, upness, _ = ball_access(model.forward(x, q), tooling, model.volume, margin_mm, margin_deg)
    if model.volume is None:
        ok = np.ones_like(ok)
    n_balls = min(n_balls, ok.shape[1])
    rank = np.argsort(np.argsort(-np.where(ok, upness, -np.inf), axis=1, kind="stable"), axis=1)
    chosen = ok & (rank < n_balls) & (ok.sum(axis=1, keepdims=True) >= n_balls)
    return Layout(tuple(levels), chosen, probes_per_ball)


def _eliminate(J_theta, J_local, J_q=None, ratio=None, sigma_u=None):
    """Per-pose information about theta (n, P, P) with the local variables eliminated (QR).

    With ``ratio`` (m,), each row's actual over weighted variance, also the middle of the sandwich
    (n, P, P); ``J_q`` (n, m, nj) and ``sigma_u`` (nj,) rad add a joint-space error the rows see
    but the estimator does not model.
    """
    Jp = J_theta
    if J_local.shape[2]:
        Q, _ = np.linalg.qr(J_local)
        Jp = J_theta - Q @ (np.swapaxes(Q, 1, 2) @ J_theta)
    info = np.einsum("nmp,nmq->npq", Jp, Jp)
    if ratio is None:
        return info
    middle = np.einsum("nmp,m,nmq->npq", Jp, ratio, Jp)
    if sigma_u is not None and np.any(sigma_u > 0):
        G = np.einsum("nmp,nmj->npj", Jp, J_q) * sigma_u[None, None, :]
        middle = middle + G @ np.swapaxes(G, 1, 2)
    return info, middle


def _group_information(model, params, x, q, balls, layout: Layout, sig: Sigmas, actual: Sigmas | None = None,
                       sigma_u=None, touch=None):
    """Information (n, P + S, P + S) of n poses that each measure the balls ``balls`` (n, k)
    (indices) and touch, per level with set-up blocks, ``touch[level]``: balls (n, c) and fixture
    names (n, c); S the layout's free set-up entries. With ``actual`` (the data's noise) also the
    sandwich's middle (see :func:`_eliminate`)."""
    n, nj = q.shape
    k = balls.shape[1]
    idx = params.index
    theta = x[idx]
    P = len(idx) + layout.n_setup
    touch = touch or {}
    offsets = model.tooling.offsets() if model.tooling is not None else np.zeros((0, 3))
    sigma_q = np.broadcast_to(np.asarray(sig.joint, dtype=float), (nj,))
    with_joints = bool(np.all(sigma_q > 0))
    probes = "probes" in layout.levels and k > 0
    n_local = (nj if with_joints else 0) + (3 * k if probes else 0)
    blocks_t, blocks_l, blocks_q, ratios = [], [], [], []
    act = actual or sig

    def add(rows_t, rows_q=None, rows_c=None, ratio=1.0, seen=True):
        """Whitened rows (n, r, P), their joint (n, r, nj) and centre (n, r, 3k) columns; ``ratio``
        the rows' actual over weighted variance; ``seen``: a joint-space error moves them."""
        r = rows_t.shape[1]
        if rows_t.shape[2] < P:  # no set-up columns
            rows_t = np.concatenate([rows_t, np.zeros((n, r, P - rows_t.shape[2]))], axis=2)
        local = np.zeros((n, r, n_local))
        if with_joints and rows_q is not None:
            local[:, :, :nj] = rows_q
        if rows_c is not None:
            local[:, :, n_local - 3 * k:] = rows_c
        blocks_t.append(rows_t)
        blocks_l.append(local)
        blocks_q.append(rows_q if seen and rows_q is not None else np.zeros((n, r, nj)))
        ratios.append(np.broadcast_to(np.asarray(ratio, dtype=float), (r,)))

    T = model.forward(x, q)
    for kind in kinematic_levels(layout.levels):  # each measurement type's own error and noise
        if getattr(kind, "uses_setup", False):  # contacts: rows in the parameters and the set-up blocks
            if kind.level in touch and touch[kind.level][0].shape[1]:
                balls, fixtures = touch[kind.level]
                J_t, J_q, w, c = _setup_rows(kind, model, theta, idx, x, q, balls, fixtures, layout, sig)
                add(J_t, J_q, ratio=np.tile((kind.sigma(act) * w) ** 2, c))
            continue
        if kind.per_ball and not k:
            continue
        T_m = np.repeat(T, k, axis=0) if kind.per_ball else T
        q_m = np.repeat(q, k, axis=0) if kind.per_ball else q
        off = offsets[balls].reshape(-1, 3) if kind.per_ball else np.zeros((n, 3))
        _, Jt, Jq = kind.error(theta, q_m, kind.design_data(T_m, off), idx, x, model.chain)
        w = 1.0 / kind.sigma(sig)
        ratio = np.tile((kind.sigma(act) * w) ** 2, k if kind.per_ball else 1)
        add((Jt * w[None, :, None]).reshape(n, -1, len(idx)), (Jq * w[None, :, None]).reshape(n, -1, nj), ratio=ratio)
    if probes:  # probe points on spheres around ball-centre variables tied to the kinematics
        off = offsets[balls].reshape(-1, 3)
        centre, Jt, Jq = ball_centre_error(theta, np.repeat(q, k, axis=0), off, np.zeros_like(off), idx, x,
                                           model.chain)
        Jt, Jq = Jt.reshape(n, 3 * k, len(idx)), Jq.reshape(n, 3 * k, nj)
        add(Jt / sig.kinematic, Jq / sig.kinematic, -np.eye(3 * k)[None].repeat(n, 0) / sig.kinematic,
            ratio=(act.kinematic / sig.kinematic) ** 2)
        ppb = layout.probes_per_ball
        pts, cs = [], []
        for i in range(n):
            for j, b in enumerate(balls[i]):
                c = centre[i * k + j]
                dirs = cap_directions(T[i, :3, :3] @ offsets[b] + np.linalg.norm(offsets[b]) * UP, ppb)
                pts.append(c + model.tooling.radius * dirs)
                cs.append(np.repeat(c[None], ppb, axis=0))
        _, Jc = probe_error(np.vstack(cs), np.vstack(pts), model.tooling.radius)
        Jc = Jc.reshape(n, k, ppb, 3) / sig.probe
        rows_c = np.zeros((n, k, ppb, 3 * k))
        for j in range(k):
            rows_c[:, j, :, 3 * j:3 * j + 3] = Jc[:, j]
        add(np.zeros((n, k * ppb, P)), None, rows_c.reshape(n, k * ppb, 3 * k), ratio=(act.probe / sig.probe) ** 2)
    if with_joints:
        # the readings as priors on the joint variables (factors.errors.joint_error: Jacobian I)
        actual_q = np.broadcast_to(np.asarray(act.joint, dtype=float), (nj,))
        add(np.zeros((n, nj, P)), np.broadcast_to(np.diag(1.0 / sigma_q), (n, nj, nj)),
            ratio=(actual_q / sigma_q) ** 2, seen=False)
    middle = actual is not None or sigma_u is not None
    if not blocks_t:
        return (np.zeros((n, P, P)), np.zeros((n, P, P))) if middle else np.zeros((n, P, P))
    J_t, J_l = np.concatenate(blocks_t, axis=1), np.concatenate(blocks_l, axis=1)
    if not middle:
        return _eliminate(J_t, J_l)
    su = None if sigma_u is None else np.broadcast_to(np.asarray(sigma_u, dtype=float), (nj,))
    return _eliminate(J_t, J_l, np.concatenate(blocks_q, axis=1), np.concatenate(ratios), su)


def _setup_rows(kind, model, theta, idx, x, q, balls, fixtures, layout: Layout, sig: Sigmas):
    """Whitened rows of contacts with set-up blocks at n poses, ``c`` each (balls and fixture
    names (n, c)): ``(J (n, c w, P + S), J_q (n, c w, nj), w (w,) the rows' weights, c)``, from
    the type's own :meth:`~fgcal.measurements.contact.SetupMeasurement.setup_error` at its
    :meth:`design_data`."""
    n, c = balls.shape
    offsets = model.tooling.offsets()
    setup = layout.setup
    assert setup is not None and model.tooling is not None  # contacts: the layout has the blocks
    radius = model.tooling.radius
    *payload, s = kind.design_data(None, offsets[balls].reshape(-1, 3), fixtures.reshape(-1), setup, radius)
    _, J_t, J_q, J_s, cols = kind.setup_error(theta, np.repeat(q, c, axis=0), tuple(payload), s, idx, x, model.chain)
    m, width, P = len(J_t), J_t.shape[1], len(idx)
    J = np.zeros((m, width, P + setup.n_free))
    J[:, :, :P] = J_t
    where = setup.column()[cols]  # (m, 3) column among the free entries, -1 for fixed ones
    for j in range(cols.shape[1]):
        free = where[:, j] >= 0
        J[free, :, P + where[free, j]] += J_s[free, :, j]
    w = 1.0 / kind.sigma(sig)
    return ((J * w[None, :, None]).reshape(n, c * width, -1), (J_q * w[None, :, None]).reshape(n, c * width, -1),
            w, c)


def information(model: RobotModel, q, layout: Layout, noise: Noise, params: ParameterSet | None = None,
                slots=None, sigmas: Sigmas | None = None) -> np.ndarray:
    """Per-pose information about the parameters, ``(N, P, P)`` (internal units: mm, rad); with
    set-up blocks (``layout.setup``) about the parameters and the free set-up entries after them,
    ``(N, P + S, P + S)`` (their priors and known distances are not in it:
    :meth:`~fgcal.measurements.setup.SetupLayout.prior_information`).

    Parameters
    ----------
    q : array_like, shape (N, n)
        Joint readings (rad, mm for prismatic joints).
    layout : Layout
        What is measured at each pose; unusable poses get zero information.
    noise : Noise
        The dataset's noise; turned into the graph's sigmas as the estimator does.
    params : ParameterSet, optional
        The estimated parameters (the model's identifiable ones by default).
    slots : array_like, optional
        Where to linearise (the nominal by default).
    sigmas : Sigmas, optional
        The estimator's noise, replacing ``noise``'s.
    """
    return _per_pose(model, q, layout, noise, params, slots, sigmas)


def information_and_middle(model: RobotModel, q, layout: Layout, noise: Noise, params: ParameterSet | None = None,
                           slots=None, sigmas: Sigmas | None = None, actual: Sigmas | None = None, joint_error=0.0):
    """Per-pose information ``M_i`` at the estimator's weights and the middle ``B_i`` of the
    sandwich ``Cov = (sum M_i)^-1 (sum B_i) (sum M_i)^-1``, both (N, P, P).

    ``actual`` is the data's noise per factor kind (the estimator's by default) and
    ``joint_error`` (rad, scalar or per joint) a random joint-space error at each pose that the
    readings do not show and the estimator does not model (the robot's unmodelled errors).
    Other arguments as :func:`information`.
    """
    return _per_pose(model, q, layout, noise, params, slots, sigmas, actual or sigmas or sigmas_of(noise, model),
                     joint_error)


def _per_pose(model, q, layout, noise, params, slots, sigmas, actual=None, joint_error=None):
    params = params or model.parameters()
    x = model.nominal if slots is None else np.asarray(slots, dtype=float)
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if "probes" in layout.levels and (model.tooling is None or model.tooling.radius <= 0):
        raise FgcalError(f"robot model {model.name}: probe points need balls of positive radius; its tool has "
                         "reflectors (radius 0): design for ball centres (position only) or poses instead")
    sig = sigmas or sigmas_of(noise, model)
    P = len(params.index) + layout.n_setup
    out = np.zeros((len(q), P, P))
    mid = np.zeros((len(q), P, P)) if actual is not None else None
    usable = layout.usable()
    counts = layout.balls.sum(axis=1) if layout.balls.size else np.zeros(len(q), dtype=int)
    # Poses are evaluated in groups with the same number of balls and of contacts per level.
    signature = np.column_stack([counts, layout.touching()])
    for sig_row in np.unique(signature[usable], axis=0):
        rows = np.nonzero(usable & np.all(signature == sig_row, axis=1))[0]
        k = int(sig_row[0])
        balls = np.array([np.nonzero(layout.balls[i])[0] for i in rows], dtype=int).reshape(len(rows), k)
        touch = {}
        for level, fixtures in layout.contacts.items():
            b = np.array([np.nonzero(fixtures[i] != "")[0] for i in rows], dtype=int).reshape(len(rows), -1)
            touch[level] = (b, fixtures[rows[:, None], b])
        got = _group_information(model, params, x, q[rows], balls, layout, sig, actual, joint_error, touch)
        if mid is None:
            out[rows] = got
        else:
            out[rows], mid[rows] = got
    return out if mid is None else (out, mid)


def joint_sensitivity(model: RobotModel, q, layout: Layout, sigmas: Sigmas, slots=None) -> dict:
    """How much a joint-space error shows in each variance component of the kinematic levels.

    Returns ``{component: (s, rows)}`` (names of :func:`fgcal.estimation.noise.component_table`):
    ``s`` the sum over the component's rows at poses ``q`` of the squared whitened (by
    ``sigmas``) joint Jacobian, per rad^2 of joint error, and ``rows`` their number; a joint error
    of ``sigma_u`` rad adds ``sigma_u^2 s / rows`` to the component's variance factor.
    """
    from fgcal.estimation.noise import component_table

    x = model.nominal if slots is None else np.asarray(slots, dtype=float)
    q = np.atleast_2d(np.asarray(q, dtype=float))
    offsets = model.tooling.offsets() if model.tooling is not None else np.zeros((0, 3))
    idx = model.parameters().index
    T = model.forward(x, q)
    out = {}
    for kind in kinematic_levels(layout.levels):
        setup = getattr(kind, "uses_setup", False)
        if kind.per_ball:
            pose, ball = np.nonzero(layout.contacts[kind.level] != "") if setup else np.nonzero(layout.balls)
            if not len(pose):
                continue
            T_m, q_m, off = T[pose], q[pose], offsets[ball]
        else:
            T_m, q_m, off = T, q, np.zeros((len(q), 3))
        # a contact's payload needs its fixture and the set-up blocks
        radius = model.tooling.radius if model.tooling is not None else 0.0
        more = (layout.contacts[kind.level][pose, ball], layout.setup, radius) if setup else ()
        _, _, Jq = kind.error(x[idx], q_m, kind.design_data(T_m, off, *more), idx, x, model.chain)
        w2 = np.einsum("mrj,mrj->r", Jq, Jq) / kind.sigma(sigmas) ** 2  # per component column
        for name, (level, cols, *_rest) in component_table().items():
            if level == kind.level:
                out[name] = (float(w2[cols].sum()), int(len(q_m) * len(w2[cols])))
    return out
