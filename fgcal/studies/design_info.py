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
* the joint readings as priors on the pose's joint variables (when they carry noise).

Each pose's local variables (its joints, its ball centres) are eliminated as the estimator
eliminates them (a per-pose Schur complement, here by QR for accuracy), leaving that pose's
information about the parameters; plans add these up. No I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factors.errors import ball_centre_error, probe_error

from fgcal.estimation.calibrate import CalibrationOptions, _sigmas
from fgcal.measurements.dataset import Dataset, Noise
from fgcal.measurements.types import kinematic_levels
from fgcal.errors import FgcalError
from fgcal.estimation.graph import Sigmas
from fgcal.robots.model import ParameterSet, RobotModel, Tooling
from fgcal.studies.simulate import UP, ball_access

__all__ = ["DESIGNED_LEVELS", "Layout", "sigmas_of", "cap_directions", "layout_from_access", "information"]

DESIGNED_LEVELS = ("probes", "centres", "poses", "distances")  # all of fgcal.measurements.dataset.LEVELS


@dataclass
class Layout:
    """What is measured at each of N poses.

    Attributes
    ----------
    levels : tuple of str
        Measurement levels, a subset of :data:`DESIGNED_LEVELS`.
    balls : ndarray of bool, shape (N, B)
        Balls (tooling order) measured at each pose, for the ``probes`` and ``centres`` levels.
    probes_per_ball : int
    """

    levels: tuple
    balls: np.ndarray
    probes_per_ball: int = 4

    def usable(self) -> np.ndarray:
        """(N,) bool: the pose gives at least one measurement."""
        if "poses" in self.levels:
            return np.ones(len(self.balls), dtype=bool)
        return self.balls.any(axis=1)


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
    accessible of those :func:`fgcal.studies.simulate.ball_access` allows (as the simulator picks them).

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


def _eliminate(J_theta, J_local) -> np.ndarray:
    """Per-pose information about theta (n, P, P) with the local variables eliminated (QR)."""
    if J_local.shape[2] == 0:
        return np.einsum("nmp,nmq->npq", J_theta, J_theta)
    Q, _ = np.linalg.qr(J_local)
    Jp = J_theta - Q @ (np.swapaxes(Q, 1, 2) @ J_theta)
    return np.einsum("nmp,nmq->npq", Jp, Jp)


def _group_information(model, params, x, q, balls, layout: Layout, sig: Sigmas) -> np.ndarray:
    """Information (n, P, P) of n poses that each measure the balls ``balls`` (n, k) (indices)."""
    n, nj = q.shape
    k = balls.shape[1]
    idx = params.index
    theta = x[idx]
    P = len(idx)
    offsets = model.tooling.offsets() if model.tooling is not None else np.zeros((0, 3))
    sigma_q = np.broadcast_to(np.asarray(sig.joint, dtype=float), (nj,))
    with_joints = bool(np.all(sigma_q > 0))
    probes = "probes" in layout.levels and k > 0
    n_local = (nj if with_joints else 0) + (3 * k if probes else 0)
    blocks_t, blocks_l = [], []

    def add(rows_t, rows_q=None, rows_c=None):
        """Whitened rows (n, r, P), their joint (n, r, nj) and centre (n, r, 3k) columns."""
        r = rows_t.shape[1]
        local = np.zeros((n, r, n_local))
        if with_joints and rows_q is not None:
            local[:, :, :nj] = rows_q
        if rows_c is not None:
            local[:, :, n_local - 3 * k:] = rows_c
        blocks_t.append(rows_t)
        blocks_l.append(local)

    T = model.forward(x, q)
    for kind in kinematic_levels(layout.levels):  # each measurement type's own error and noise
        if kind.per_ball and not k:
            continue
        T_m = np.repeat(T, k, axis=0) if kind.per_ball else T
        q_m = np.repeat(q, k, axis=0) if kind.per_ball else q
        off = offsets[balls].reshape(-1, 3) if kind.per_ball else np.zeros((n, 3))
        _, Jt, Jq = kind.error(theta, q_m, kind.design_data(T_m, off), idx, x, model.chain)
        w = 1.0 / kind.sigma(sig)
        add((Jt * w[None, :, None]).reshape(n, -1, P), (Jq * w[None, :, None]).reshape(n, -1, nj))
    if probes:  # probe points on spheres around ball-centre variables tied to the kinematics
        off = offsets[balls].reshape(-1, 3)
        centre, Jt, Jq = ball_centre_error(theta, np.repeat(q, k, axis=0), off, np.zeros_like(off), idx, x,
                                           model.chain)
        Jt, Jq = Jt.reshape(n, 3 * k, P), Jq.reshape(n, 3 * k, nj)
        add(Jt / sig.kinematic, Jq / sig.kinematic, -np.eye(3 * k)[None].repeat(n, 0) / sig.kinematic)
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
        add(np.zeros((n, k * ppb, P)), None, rows_c.reshape(n, k * ppb, 3 * k))
    if with_joints:
        # the readings as priors on the joint variables (factors.errors.joint_error: Jacobian I)
        add(np.zeros((n, nj, P)), np.broadcast_to(np.diag(1.0 / sigma_q), (n, nj, nj)))
    if not blocks_t:
        return np.zeros((n, P, P))
    return _eliminate(np.concatenate(blocks_t, axis=1), np.concatenate(blocks_l, axis=1))


def information(model: RobotModel, q, layout: Layout, noise: Noise, params: ParameterSet | None = None,
                slots=None, sigmas: Sigmas | None = None) -> np.ndarray:
    """Per-pose information about the parameters, ``(N, P, P)`` (internal units: mm, rad).

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
    """
    params = params or model.parameters()
    x = model.nominal if slots is None else np.asarray(slots, dtype=float)
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if "probes" in layout.levels and (model.tooling is None or model.tooling.radius <= 0):
        raise FgcalError(f"robot model {model.name}: probe points need balls of positive radius; its tool has "
                         "reflectors (radius 0): design for ball centres (position only) or poses instead")
    sig = sigmas or sigmas_of(noise, model)
    out = np.zeros((len(q), len(params.index), len(params.index)))
    usable = layout.usable()
    counts = layout.balls.sum(axis=1) if layout.balls.size else np.zeros(len(q), dtype=int)
    for k in np.unique(counts[usable]):
        rows = np.nonzero(usable & (counts == k))[0]
        balls = np.array([np.nonzero(layout.balls[i])[0] for i in rows], dtype=int).reshape(len(rows), k)
        out[rows] = _group_information(model, params, x, q[rows], balls, layout, sig)
    return out
