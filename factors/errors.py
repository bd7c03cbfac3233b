"""Pure error functions of fgcal's measurement model, vectorised over M measurements.

Each returns the *unwhitened* error and its Jacobians with respect to its variables. The
kinematic parameters are a vector ``theta`` (P,) in internal units (mm, rad), placed into the
37-slot chain by ``index`` (P,) over ``held`` (S,), the values of the slots not estimated. Each kinematic error
takes the robot's ``chain`` (:class:`fgcal.robots.kinematics.Chain`; the all-revolute chain of
``held``'s size by default). Joint variables ``q`` are the readings (rad, or mm for prismatic
joints); points are mm (world).
"""
from __future__ import annotations

import numpy as np

from fgcal.robots.kinematics import jacobians, projected_point_jacobians
from fgcal.robots.transforms import so3_left_jacobian_inverse, so3_log

__all__ = [
    "ball_centre_along",
    "ball_centre_error",
    "distance_error",
    "joint_error",
    "pose_ball_centres_error",
    "pose_error",
    "probe_error",
    "slots_of",
]


def slots_of(theta, index, held) -> np.ndarray:
    """The slot vector with ``theta`` at ``index`` and ``held`` elsewhere."""
    x = np.array(held, dtype=float)
    x[np.asarray(index, dtype=int)] = theta
    return x


def probe_error(centre, point, radius):
    """A probe point lies on the sphere of ``radius`` around the ball centre.

    Parameters
    ----------
    centre, point : array_like, shape (M, 3)
    radius : float

    Returns
    -------
    e : ndarray, shape (M, 1)
        ``|point - centre| - radius`` (mm).
    J_centre : ndarray, shape (M, 1, 3)
    """
    diff = (np.asarray(point, dtype=float) - np.asarray(centre, dtype=float)).reshape(-1, 3)
    dist = np.sqrt(np.einsum("mi,mi->m", diff, diff))  # not np.linalg.norm: ~20 us less a call (GTSAM's per-pose factors)
    return (dist - radius)[:, None], (-diff / dist[:, None])[:, None, :]


def ball_centre_error(theta, q, offset, centre, index, held, chain=None):
    """A ball centre is at the forward kinematics times the ball's tool-frame offset.

    Parameters
    ----------
    theta : array_like, shape (P,)
    q : array_like, shape (M, n)
        Joint readings (rad, mm) of each measurement's pose.
    offset : array_like, shape (M, 3)
        The ball's centre in the tool frame (mm).
    centre : array_like, shape (M, 3)
        The ball-centre variable, or a measured centre (mm, world).
    index, held : see :func:`slots_of`.
    chain : fgcal.robots.kinematics.Chain, optional
        The robot's chain; the all-revolute chain of ``held``'s size by default.

    Returns
    -------
    e : ndarray, shape (M, 3)
        ``FK(theta, q) offset - centre`` (mm).
    J_theta : ndarray, shape (M, 3, P)
    J_q : ndarray, shape (M, 3, n)
    (the Jacobian with respect to ``centre`` is ``-I``)
    """
    x = slots_of(theta, index, held)
    q = np.atleast_2d(q)
    jac = jacobians(x, q, offsets=np.asarray(offset, dtype=float).reshape(-1, 1, 3), chain=chain)
    e = jac.points[:, 0] - np.atleast_2d(centre)
    return e, jac.point_slots[:, 0][:, :, index], jac.point_joints[:, 0]


def ball_centre_along(theta, q, offset, direction, index, held, chain=None):
    """A ball centre by the forward kinematics, and the Jacobians of its distance along a world
    direction (one row a measurement, as a plane contact's ``n . centre``) without the full
    ``(M, 3, P)`` ones of :func:`ball_centre_error`.

    Parameters
    ----------
    q : array_like, shape (M, n)
    offset : array_like, shape (M, 3)
        The ball's centre in the tool frame (mm).
    direction : array_like, shape (M, 3)
        The world direction ``u`` of each measurement (unit vectors).
    index, held, chain : see :func:`ball_centre_error`.

    Returns
    -------
    centre : ndarray, shape (M, 3)
        ``FK(theta, q) offset`` (mm, world).
    J_theta : ndarray, shape (M, 1, P)
        ``u . d centre / d theta``.
    J_q : ndarray, shape (M, 1, n)
        ``u . d centre / d q``.
    """
    x = slots_of(theta, index, held)
    q = np.atleast_2d(np.asarray(q, dtype=float))
    offset = np.asarray(offset, dtype=float).reshape(-1, 3)
    direction = np.asarray(direction, dtype=float).reshape(-1, 3)
    centre, along_slots, along_joints = projected_point_jacobians(x, q, offset, direction, chain=chain)
    return centre, along_slots[:, None, np.asarray(index, dtype=int)], along_joints[:, None, :]


def pose_ball_centres_error(theta, q, offsets, centres, index, held, chain=None):
    """:func:`ball_centre_error` for B balls of one pose, with one kinematics evaluation.

    Parameters
    ----------
    q : array_like, shape (n,)
    offsets, centres : array_like, shape (B, 3)

    Returns
    -------
    e : ndarray, shape (B, 3); J_theta : (B, 3, P); J_q : (B, 3, n)
    """
    x = slots_of(theta, index, held)
    jac = jacobians(x, np.asarray(q, dtype=float).reshape(1, -1), offsets=np.asarray(offsets, dtype=float).reshape(-1, 3),
                    chain=chain)
    e = jac.points[0] - np.asarray(centres, dtype=float).reshape(-1, 3)
    return e, jac.point_slots[0][:, :, index], jac.point_joints[0]


def pose_error(theta, q, T_measured, index, held, chain=None):
    """A measured tool pose against the forward kinematics.

    Returns
    -------
    e : ndarray, shape (M, 6)
        ``[log(R_fk R_meas^T) (rad, world); p_fk - p_meas (mm)]``.
    J_theta : ndarray, shape (M, 6, P)
    J_q : ndarray, shape (M, 6, n)
    """
    x = slots_of(theta, index, held)
    q = np.atleast_2d(q)
    T_measured = np.asarray(T_measured, dtype=float).reshape(-1, 4, 4)
    jac = jacobians(x, q, chain=chain)
    w = so3_log(jac.T[:, :3, :3] @ np.swapaxes(T_measured[:, :3, :3], -1, -2))
    e = np.concatenate([w, jac.T[:, :3, 3] - T_measured[:, :3, 3]], axis=1)
    Jl = so3_left_jacobian_inverse(w)

    def rows(J):  # J: (M, 6, n) with rows [dp; omega]
        return np.concatenate([Jl @ J[:, 3:], J[:, :3]], axis=1)

    return e, rows(jac.pose_slots[:, :, index]), rows(jac.pose_joints)


def distance_error(theta, q, offset, length, index, held, chain=None):
    """A ballbar: the tool ball at ``FK(theta, q) offset`` is ``length`` from the world origin (the pivot).

    Parameters
    ----------
    theta, q, index, held, chain : see :func:`ball_centre_error`.
    offset : array_like, shape (M, 3)
        The ball's centre in the tool frame (mm).
    length : array_like, shape (M,)
        Measured centre-to-centre length (mm).

    Returns
    -------
    e : ndarray, shape (M, 1)
        ``|FK(theta, q) offset| - length`` (mm).
    J_theta : ndarray, shape (M, 1, P)
    J_q : ndarray, shape (M, 1, n)
    """
    length = np.asarray(length, dtype=float).reshape(-1)
    p, J_t, J_q = ball_centre_error(theta, q, offset, np.zeros((len(length), 3)), index, held, chain)
    dist = np.linalg.norm(p, axis=1)
    u = (p / np.maximum(dist, 1e-300)[:, None])[:, None, :]  # (M, 1, 3): d|p|/dp
    return (dist - length)[:, None], u @ J_t, u @ J_q


def joint_error(q, reading):
    """A joint variable against the controller's reading: ``q - reading`` (M, n), Jacobian ``I``."""
    return np.atleast_2d(q) - np.atleast_2d(reading)
