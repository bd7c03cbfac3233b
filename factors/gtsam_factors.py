"""GTSAM factors built on :mod:`factors.errors`: small builders returning ``gtsam`` factors.

Variables in a ``gtsam.Values``: the parameter vector under :func:`theta_key` (a Vector of P),
each pose's joints under :func:`joint_key` (Vector n, rad or mm), each ball centre under
:func:`centre_key` (Vector 3, mm). A variable that is known (exact joint readings, a measured
centre) is passed as a constant instead of a key.

Keep a reference to every factor's arguments: the error closures capture them.
"""
from __future__ import annotations

import gtsam
import numpy as np

from fgcal.robots.kinematics import jacobians

from .errors import ball_centre_error, distance_error, pose_ball_centres_error, pose_error, probe_error, slots_of

__all__ = [
    "PoseKinematics",
    "ball_centre_factor",
    "ball_centres_factor",
    "centre_key",
    "distance_factor",
    "joint_key",
    "joint_prior",
    "noise_model",
    "parameter_prior",
    "pose_centres_factor",
    "pose_factor",
    "pose_probes_factor",
    "probe_factor",
    "probes_factor",
    "theta_key",
]


def theta_key() -> int:
    return gtsam.symbol("k", 0)


def joint_key(pose_index: int) -> int:
    return gtsam.symbol("q", int(pose_index))


def centre_key(ball_index: int) -> int:
    return gtsam.symbol("c", int(ball_index))


def noise_model(sigmas, robust: str | None = None, k: float = 1.345):
    """A diagonal Gaussian noise model, optionally inside a Huber or Cauchy robust loss.

    ``k`` is the loss's threshold in units of the whitened error (sigmas).
    """
    base = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas, dtype=float))
    if robust is None:
        return base
    if robust == "huber":
        return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(k), base)
    if robust == "cauchy":
        return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(k), base)
    raise ValueError(f"unknown robust loss {robust!r} (huber, cauchy)")


def _vector(values, key):
    return values.atVector(key)


def probe_factor(c_key: int, point, radius: float, sigma: float, robust=None,
                 k: float = 1.345) -> gtsam.CustomFactor:
    """A probe point (3,) mm on the sphere of ``radius`` around the centre variable ``c_key``
    (``robust``, ``k``: see :func:`noise_model`)."""
    point = np.array(point, dtype=float).reshape(1, 3)

    def error(this, values, H):
        e, J = probe_error(_vector(values, c_key)[None], point, radius)
        if H is not None:
            H[0] = J[0]
        return e[0]

    return gtsam.CustomFactor(noise_model([sigma], robust, k), [c_key], error)


def probes_factor(c_key: int, points, radius: float, sigma: float, robust=None) -> gtsam.CustomFactor:
    """All probe points (n, 3) of one ball in one factor (n-dim error): fewer Python callbacks."""
    points = np.array(points, dtype=float).reshape(-1, 3)

    def error(this, values, H):
        c = _vector(values, c_key)
        e, J = probe_error(np.broadcast_to(c, points.shape), points, radius)
        if H is not None:
            H[0] = J[:, 0, :]
        return e[:, 0]

    return gtsam.CustomFactor(noise_model([sigma] * len(points), robust), [c_key], error)


def pose_probes_factor(c_keys, owner, points, radius: float, sigma: float) -> gtsam.CustomFactor:
    """Probe points (n, 3) of several balls (``owner`` (n,): the index in ``c_keys`` of each
    point's centre variable) in one factor (n-dim error, not robust): the same rows as n
    :func:`probe_factor`s in one Python callback."""
    c_keys = [int(k) for k in c_keys]
    points = np.array(points, dtype=float).reshape(-1, 3)
    owner = np.asarray(owner, dtype=int)
    rows = [np.flatnonzero(owner == b) for b in range(len(c_keys))]  # each centre's points, found once

    def error(this, values, H):
        centres = np.array([_vector(values, k) for k in c_keys])
        e, J = probe_error(centres[owner], points, radius)
        if H is not None:
            for b, r in enumerate(rows):
                h = np.zeros((len(points), 3))
                h[r] = J[r, 0, :]
                H[b] = h
        return e[:, 0]

    return gtsam.CustomFactor(noise_model([sigma] * len(points)), c_keys, error)


def ball_centre_factor(index, held, offset, sigma: float, *, t_key: int, q_key: int | None = None,
                       q_fixed=None, c_key: int | None = None, c_measured=None, robust=None,
                       covariance=None, chain=None) -> gtsam.CustomFactor:
    """A ball centre (variable ``c_key`` or ``c_measured``) at FK(theta, q) times ``offset``.

    Joints are the variable ``q_key`` or the constant ``q_fixed`` (n,) rad/mm; ``chain`` the robot's. A full ``covariance``
    (3, 3) mm^2, for example a sphere fit's, replaces the isotropic ``sigma``.
    """
    if (q_key is None) == (q_fixed is None) or (c_key is None) == (c_measured is None):
        raise ValueError("give exactly one of q_key/q_fixed and one of c_key/c_measured")
    offset = np.array(offset, dtype=float).reshape(1, 3)
    index = np.array(index, dtype=int)
    held = np.array(held, dtype=float)
    q_const = None if q_fixed is None else np.array(q_fixed, dtype=float).reshape(1, -1)
    c_const = None if c_measured is None else np.array(c_measured, dtype=float).reshape(1, 3)
    keys = [t_key] + ([q_key] if q_key is not None else []) + ([c_key] if c_key is not None else [])

    def error(this, values, H):
        theta = _vector(values, t_key)
        q = q_const if q_key is None else _vector(values, q_key)[None]
        c = c_const if c_key is None else _vector(values, c_key)[None]
        e, J_t, J_q = ball_centre_error(theta, q, offset, c, index, held, chain)
        if H is not None:
            H[0] = J_t[0]
            i = 1
            if q_key is not None:
                H[i] = J_q[0]
                i += 1
            if c_key is not None:
                H[i] = -np.eye(3)
        return e[0]

    noise = (gtsam.noiseModel.Gaussian.Covariance(np.asarray(covariance, dtype=float)) if covariance is not None
             else noise_model([sigma] * 3, robust))
    return gtsam.CustomFactor(noise, keys, error)


def ball_centres_factor(index, held, offsets, centres, covariance, *, t_key: int, q_key: int | None = None,
                        q_fixed=None, chain=None) -> gtsam.CustomFactor:
    """B measured ball centres (B, 3) of one pose in one factor (3B-dim error, one kinematics call).

    ``covariance`` is (3B, 3B) mm^2 (block diagonal for independent balls).
    """
    if (q_key is None) == (q_fixed is None):
        raise ValueError("give exactly one of q_key and q_fixed")
    offsets = np.array(offsets, dtype=float).reshape(-1, 3)
    centres = np.array(centres, dtype=float).reshape(-1, 3)
    index = np.array(index, dtype=int)
    held = np.array(held, dtype=float)
    q_const = None if q_fixed is None else np.array(q_fixed, dtype=float).reshape(-1)
    keys = [t_key] + ([q_key] if q_key is not None else [])

    def error(this, values, H):
        q = q_const if q_key is None else _vector(values, q_key)
        e, J_t, J_q = pose_ball_centres_error(_vector(values, t_key), q, offsets, centres, index, held, chain)
        if H is not None:
            H[0] = J_t.reshape(-1, J_t.shape[-1])
            if q_key is not None:
                H[1] = J_q.reshape(-1, J_q.shape[-1])
        return e.ravel()

    return gtsam.CustomFactor(gtsam.noiseModel.Gaussian.Covariance(np.asarray(covariance, dtype=float)), keys, error)


class PoseKinematics:
    """The tool points' kinematics at every pose at once, for per-pose factors whose rows an
    optimiser fills for all poses together (:class:`factors.pose_balls.PoseBallRows`): one chain
    evaluation vectorised over the poses instead of one per pose factor (each ~40 numpy calls on 4x4
    arrays).

    Parameters
    ----------
    index, held : see :func:`factors.errors.slots_of`.
    offsets : array_like, shape (N, B, 3)
        Each pose's tool points (mm), padded with anything where a pose has fewer.
    chain : fgcal.robots.kinematics.Chain, optional
    """

    def __init__(self, index, held, offsets, chain=None):
        self.index = np.array(index, dtype=int)
        self.held = np.array(held, dtype=float)
        self.offsets = np.array(offsets, dtype=float)
        self.chain = chain
        self.points = self.J_theta = self.J_q = np.zeros(0)

    def fill(self, theta, q) -> None:
        """Evaluate at ``theta`` (P,) and every pose's joints ``q`` (N, n): ``points`` (N, B, 3),
        ``J_theta`` (N, B, 3, P) and ``J_q`` (N, B, 3, n)."""
        theta = np.array(theta, dtype=float)
        q = np.array(q, dtype=float).reshape(len(self.offsets), -1)
        jac = jacobians(slots_of(theta, self.index, self.held), q, offsets=self.offsets, chain=self.chain)
        assert jac.points is not None and jac.point_slots is not None and jac.point_joints is not None
        self.points, self.J_theta, self.J_q = jac.points, jac.point_slots[..., self.index], jac.point_joints


def pose_centres_factor(index, held, offsets, sigma: float, *, t_key: int, c_keys, q_key: int | None = None,
                        q_fixed=None, chain=None) -> gtsam.CustomFactor:
    """The B ball-centre variables ``c_keys`` of one pose at FK(theta, q) times their ``offsets``
    (B, 3), in one factor (3B-dim error, one kinematics call; not robust): the same rows as B
    :func:`ball_centre_factor`s, a third of the Python callbacks for three balls.
    """
    if (q_key is None) == (q_fixed is None):
        raise ValueError("give exactly one of q_key and q_fixed")
    offsets = np.array(offsets, dtype=float).reshape(-1, 3)
    c_keys = [int(k) for k in c_keys]
    if len(c_keys) != len(offsets):
        raise ValueError(f"{len(c_keys)} centre keys for {len(offsets)} offsets")
    index = np.array(index, dtype=int)
    held = np.array(held, dtype=float)
    q_const = None if q_fixed is None else np.array(q_fixed, dtype=float).reshape(-1)
    keys = [t_key] + ([q_key] if q_key is not None else []) + c_keys
    B = len(offsets)
    H_c = [np.zeros((3 * B, 3)) for _ in range(B)]
    for b, h in enumerate(H_c):
        h[3 * b:3 * b + 3] = -np.eye(3)

    def error(this, values, H):
        q = q_const if q_key is None else _vector(values, q_key)
        centres = np.array([_vector(values, k) for k in c_keys])
        theta = _vector(values, t_key)
        e, J_t, J_q = pose_ball_centres_error(theta, q, offsets, centres, index, held, chain)
        if H is not None:
            H[0] = J_t.reshape(3 * B, -1)
            i = 1
            if q_key is not None:
                H[1] = J_q.reshape(3 * B, -1)
                i = 2
            for b, h in enumerate(H_c):
                H[i + b] = h
        return e.ravel()

    return gtsam.CustomFactor(noise_model([sigma] * (3 * B)), keys, error)


def kinematic_factor(error_fn, noise, index, held, *, t_key: int, q_key: int | None, q_fixed, chain):
    """A factor on (theta, q) whose error is ``error_fn(theta, q (1, n), index, held, chain)`` ->
    ``(e (1, m), J_theta (1, m, P), J_q (1, m, n))``; joints are the variable ``q_key`` or ``q_fixed``."""
    if (q_key is None) == (q_fixed is None):
        raise ValueError("give exactly one of q_key and q_fixed")
    index = np.array(index, dtype=int)
    held = np.array(held, dtype=float)
    q_const = None if q_fixed is None else np.array(q_fixed, dtype=float).reshape(1, -1)
    keys = [t_key] + ([q_key] if q_key is not None else [])

    def error(this, values, H):
        q = q_const if q_key is None else _vector(values, q_key)[None]
        e, J_t, J_q = error_fn(_vector(values, t_key), q, index, held, chain)
        if H is not None:
            H[0] = J_t[0]
            if q_key is not None:
                H[1] = J_q[0]
        return e[0]

    return gtsam.CustomFactor(noise, keys, error)


def pose_factor(index, held, T_measured, sigma_rot: float, sigma_pos: float, *, t_key: int,
                q_key: int | None = None, q_fixed=None, robust=None, chain=None) -> gtsam.CustomFactor:
    """A measured tool pose (4, 4) against FK(theta, q): error ``[rotation (rad); position (mm)]``."""
    T_measured = np.array(T_measured, dtype=float).reshape(1, 4, 4)
    return kinematic_factor(lambda theta, q, i, h, c: pose_error(theta, q, T_measured, i, h, c),
                             noise_model([sigma_rot] * 3 + [sigma_pos] * 3, robust), index, held, t_key=t_key,
                             q_key=q_key, q_fixed=q_fixed, chain=chain)


def distance_factor(index, held, offset, length: float, sigma: float, *, t_key: int, q_key: int | None = None,
                    q_fixed=None, robust=None, chain=None) -> gtsam.CustomFactor:
    """A ballbar length (mm) from the world origin (the pivot) to the tool ball at ``offset`` (3,)."""
    offset = np.array(offset, dtype=float).reshape(1, 3)
    lengths = np.array([float(length)])
    return kinematic_factor(lambda theta, q, i, h, c: distance_error(theta, q, offset, lengths, i, h, c),
                             noise_model([sigma], robust), index, held, t_key=t_key, q_key=q_key, q_fixed=q_fixed,
                             chain=chain)


def joint_prior(q_key: int, reading, sigma: float) -> gtsam.PriorFactorVector:
    """The joint variable ``q_key`` is the controller's reading (n,) give or take ``sigma``."""
    reading = np.array(reading, dtype=float).reshape(-1)
    return gtsam.PriorFactorVector(q_key, reading, noise_model(np.broadcast_to(sigma, reading.shape)))


def parameter_prior(t_key: int, mean, sigmas) -> gtsam.PriorFactorVector:
    """A prior on the parameter vector: ``mean`` (P,) with ``sigmas`` (P,) in internal units."""
    return gtsam.PriorFactorVector(t_key, np.array(mean, dtype=float), noise_model(sigmas))
