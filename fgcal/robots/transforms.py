"""Rigid-body transforms: elementary rotations, ZYX Euler + local translation, quaternions.

Angles are radians and lengths millimetres throughout this module; it does no I/O.
Homogeneous transforms are ``(..., 4, 4)`` arrays.
"""
from __future__ import annotations

import numpy as np

__all__ = [
    "check_transform",
    "euler_zyx_trans",
    "matrix_to_quaternion",
    "pose_difference",
    "pose_matrices",
    "quaternion_to_matrix",
    "rot",
    "so3_log",
    "to_euler_zyx_trans",
]


def check_transform(T, name: str = "transform") -> np.ndarray:
    """Convert ``T`` to a float ``(..., 4, 4)`` array or raise ``ValueError`` naming the shape."""
    T = np.asarray(T, dtype=float)
    if T.ndim < 2 or T.shape[-2:] != (4, 4):
        raise ValueError(f"{name} must have shape (..., 4, 4), got {T.shape}")
    return T


def rot(axis: int, angle) -> np.ndarray:
    """Rotation matrices about the x (0), y (1) or z (2) axis.

    Parameters
    ----------
    axis : int
        0, 1 or 2 for x, y, z.
    angle : float or array_like, shape (N,)
        Angle in radians.

    Returns
    -------
    ndarray, shape (3, 3) or (N, 3, 3)
    """
    angle = np.asarray(angle, dtype=float)
    c, s = np.cos(angle), np.sin(angle)
    R = np.zeros(angle.shape + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R[..., axis, axis] = 1.0
    R[..., i, i] = c
    R[..., j, j] = c
    R[..., i, j] = -s
    R[..., j, i] = s
    return R


def euler_zyx_trans(phi, theta, psi, px, py, pz) -> np.ndarray:
    """``Rz(phi) Ry(theta) Rx(psi) Trans(px, py, pz)`` as a (4, 4) matrix (rad, mm).

    The translation is applied in the rotated frame, as in the paper's eqs. (7) and (8).
    """
    R = rot(2, phi) @ rot(1, theta) @ rot(0, psi)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = R @ np.array([px, py, pz], dtype=float)
    return T


def to_euler_zyx_trans(T) -> np.ndarray:
    """Inverse of :func:`euler_zyx_trans`: ``(phi, theta, psi, px, py, pz)`` (rad, mm).

    Raises ``ValueError`` at the Euler singularity (|theta| = 90 deg), where the angles are not
    unique.
    """
    T = check_transform(T)
    R = T[:3, :3]
    sin_theta = -R[2, 0]
    if abs(abs(sin_theta) - 1.0) < 1e-12:
        raise ValueError("ZYX Euler angles are singular at theta = +-90 deg")
    theta = np.arcsin(np.clip(sin_theta, -1.0, 1.0))
    phi = np.arctan2(R[1, 0], R[0, 0])
    psi = np.arctan2(R[2, 1], R[2, 2])
    local = R.T @ T[:3, 3]
    return np.array([phi, theta, psi, *local])


def matrix_to_quaternion(R) -> np.ndarray:
    """Unit quaternions ``(qw, qx, qy, qz)`` with ``qw >= 0`` from rotation matrices (..., 3, 3)."""
    R = np.asarray(R, dtype=float)
    flat = R.reshape(-1, 3, 3)
    out = np.empty((flat.shape[0], 4))
    for k, m in enumerate(flat):
        tr = np.trace(m)
        if tr > 0:
            s = 2.0 * np.sqrt(tr + 1.0)
            q = np.array([0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s])
        else:
            i = int(np.argmax(np.diag(m)))
            j, n = (i + 1) % 3, (i + 2) % 3
            s = 2.0 * np.sqrt(1.0 + m[i, i] - m[j, j] - m[n, n])
            q = np.empty(4)
            q[0] = (m[n, j] - m[j, n]) / s
            q[1 + i] = 0.25 * s
            q[1 + j] = (m[j, i] + m[i, j]) / s
            q[1 + n] = (m[n, i] + m[i, n]) / s
        q = q / np.linalg.norm(q)
        out[k] = q if q[0] >= 0 else -q
    return out.reshape(R.shape[:-2] + (4,))


def quaternion_to_matrix(q) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from quaternions ``(qw, qx, qy, qz)`` (normalised here)."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - w * z)
    R[..., 0, 2] = 2 * (x * z + w * y)
    R[..., 1, 0] = 2 * (x * y + w * z)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - w * x)
    R[..., 2, 0] = 2 * (x * z - w * y)
    R[..., 2, 1] = 2 * (y * z + w * x)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def pose_matrices(xyz, quat) -> np.ndarray:
    """Homogeneous transforms ``(..., 4, 4)`` from positions ``(..., 3)`` and quaternions ``(..., 4)``."""
    xyz = np.asarray(xyz, dtype=float)
    T = np.zeros(xyz.shape[:-1] + (4, 4))
    T[..., :3, :3] = quaternion_to_matrix(quat)
    T[..., :3, 3] = xyz
    T[..., 3, 3] = 1.0
    return T


def so3_log(R) -> np.ndarray:
    """Rotation vectors (..., 3) in radians of rotation matrices (..., 3, 3)."""
    R = np.asarray(R, dtype=float)
    flat = R.reshape(-1, 3, 3)
    cos_angle = np.clip((np.trace(flat, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(cos_angle)
    v = np.stack([flat[:, 2, 1] - flat[:, 1, 2], flat[:, 0, 2] - flat[:, 2, 0],
                  flat[:, 1, 0] - flat[:, 0, 1]], -1)
    sin_angle = np.sin(angle)
    small = sin_angle < 1e-7
    scale = np.where(small, 0.5 + angle**2 / 12.0, angle / (2.0 * np.where(small, 1.0, sin_angle)))
    out = v * scale[:, None]
    # Near pi the antisymmetric part vanishes: take the axis from the symmetric part instead.
    for k in np.nonzero(angle > np.pi - 1e-6)[0]:
        B = (flat[k] + np.eye(3)) / 2.0
        i = int(np.argmax(np.diag(B)))
        axis = B[:, i] / np.linalg.norm(B[:, i])
        if np.dot(axis, v[k]) < 0:
            axis = -axis
        out[k] = axis * angle[k]
    return out.reshape(R.shape[:-2] + (3,))


def pose_difference(T_measured, T_model) -> tuple[np.ndarray, np.ndarray]:
    """The paper's differential displacement and orientation (eq. 17) between two poses.

    Parameters
    ----------
    T_measured, T_model : array_like, shape (..., 4, 4)

    Returns
    -------
    d : ndarray, shape (..., 3)
        Position difference ``p_measured - p_model`` in world coordinates (mm).
    delta : ndarray, shape (..., 3)
        Rotation vector of ``R_measured R_model^T`` in world coordinates (rad).
    """
    A = check_transform(T_measured, "T_measured")
    B = check_transform(T_model, "T_model")
    d = A[..., :3, 3] - B[..., :3, 3]
    delta = so3_log(A[..., :3, :3] @ np.swapaxes(B[..., :3, :3], -1, -2))
    return d, delta


def skew(v) -> np.ndarray:
    """Cross-product matrices (..., 3, 3) of vectors (..., 3)."""
    v = np.asarray(v, dtype=float)
    S = np.zeros(v.shape + (3,))
    S[..., 0, 1], S[..., 0, 2] = -v[..., 2], v[..., 1]
    S[..., 1, 0], S[..., 1, 2] = v[..., 2], -v[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -v[..., 1], v[..., 0]
    return S


def so3_left_jacobian_inverse(w) -> np.ndarray:
    """``J_l^-1(w)`` (..., 3, 3): ``log(exp([d]) exp([w])) = w + J_l^-1(w) d`` to first order."""
    w = np.asarray(w, dtype=float)
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    W = skew(w)
    small = theta < 1e-6
    t = np.where(small, 1.0, theta)
    coef = np.where(small, 1.0 / 12.0, 1.0 / t**2 - (1.0 + np.cos(t)) / (2.0 * t * np.sin(t)))
    return np.eye(3) - 0.5 * W + coef * (W @ W)
