"""The start of a camera calibration without a guess: per-image PnP, then a closed-form
robot-world hand-eye solve (DESIGN.md 8.4). Own implementations (no OpenCV).

PnP: the pixels are undistorted to normalised image coordinates with the camera's (start)
intrinsics; a planar target gives a homography (DLT), any other target a 3D DLT (at least six
points); Gauss-Newton on the reprojection error refines the pose. Hand-eye: for images ``i`` with
the tool pose ``A_i`` (or its inverse) and the target seen from the camera ``B_i``, ``A_i X = Y B_i``
is solved for the rotations by the null vector of the stacked Kronecker equations, projected on
SO(3), then for the translations by linear least squares. No I/O here.
"""
from __future__ import annotations

import numpy as np

from fgcal.measurements.camera import mount_transform, pose_entries, pose_matrix, project

__all__ = ["PNP_MIN_POINTS", "hand_eye", "pnp", "undistort"]

PNP_MIN_POINTS = 4


def undistort(uv, k, iterations: int = 20) -> np.ndarray:
    """Normalised coordinates (M, 2) of pixels ``uv`` (M, 2) for intrinsics ``k`` (9,) (fixed-point)."""
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = np.asarray(k, dtype=float)
    xd = (np.asarray(uv, dtype=float)[:, 0] - cx) / fx
    yd = (np.asarray(uv, dtype=float)[:, 1] - cy) / fy
    x, y = xd.copy(), yd.copy()
    for _ in range(iterations):
        r2 = x * x + y * y
        rad = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        x, y = (xd - dx) / rad, (yd - dy) / rad
    return np.column_stack([x, y])


def _nearest_rotation(M) -> np.ndarray:
    U, _, Vt = np.linalg.svd(M)
    R = U @ Vt
    if np.linalg.det(R) < 0:
        R = U @ np.diag([1.0, 1.0, -1.0]) @ Vt
    return R


def _dlt_rows(P, n) -> np.ndarray:
    """The DLT's two rows a point (2m, 2k + k): ``[P, 0, -u P]`` and ``[0, P, -v P]`` for
    homogeneous points ``P`` (m, k) and normalised image points ``n`` (m, 2)."""
    m, k = P.shape
    A = np.zeros((m, 2, 3 * k))
    A[:, 0, :k], A[:, 1, k:2 * k] = P, P
    A[:, 0, 2 * k:], A[:, 1, 2 * k:] = -n[:, :1] * P, -n[:, 1:] * P
    return A.reshape(2 * m, 3 * k)


def _pnp_planar(X, n) -> np.ndarray:
    A = _dlt_rows(np.column_stack([X[:, :2], np.ones(len(X))]), n)
    H = np.linalg.svd(A, full_matrices=False)[2][-1].reshape(3, 3)
    scale = 2.0 / (np.linalg.norm(H[:, 0]) + np.linalg.norm(H[:, 1]))
    H = H * scale
    if H[2, 2] < 0:  # the target in front of the camera (its origin at positive depth)
        H = -H
    R = _nearest_rotation(np.column_stack([H[:, 0], H[:, 1], np.cross(H[:, 0], H[:, 1])]))
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, H[:, 2]
    return T


def _pnp_dlt(X, n) -> np.ndarray:
    A = _dlt_rows(np.column_stack([X, np.ones(len(X))]), n)
    P = np.linalg.svd(A, full_matrices=False)[2][-1].reshape(3, 4)
    scale = 1.0 / np.cbrt(np.linalg.det(P[:, :3]))
    P = P * scale
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = _nearest_rotation(P[:, :3]), P[:, 3]
    return T


def pnp(X, uv, k, iterations: int = 15) -> tuple[np.ndarray, float]:
    """The target frame in the camera frame, ``T_ct`` (4, 4), from target points ``X`` (m, 3) mm and
    their pixels ``uv`` (m, 2) with intrinsics ``k`` (9,); and the RMS reprojection error (px).

    Raises
    ------
    ValueError
        With fewer than four points (six for a non-planar target) or a degenerate configuration.
    """
    X = np.asarray(X, dtype=float)
    uv = np.asarray(uv, dtype=float)
    planar = bool(np.all(np.abs(X[:, 2]) < 1e-9))
    if len(X) < (PNP_MIN_POINTS if planar else 6):
        raise ValueError(f"PnP needs at least {PNP_MIN_POINTS if planar else 6} points, got {len(X)}")
    n = undistort(uv, k)
    T = _pnp_planar(X, n) if planar else _pnp_dlt(X, n)
    e = pose_entries(T)
    for _ in range(iterations):  # Gauss-Newton on the pixels, analytic Jacobian in the pose entries
        R, t, dR = mount_transform(e)
        uv_e, J_X, _ = project(X @ R.T + t, k)
        D = np.concatenate([np.broadcast_to(np.eye(3), (len(X), 3, 3)), np.einsum("aij,mj->mia", dR, X)], axis=2)
        J = (J_X @ D).reshape(-1, 6)
        step = np.linalg.lstsq(J, -(uv_e - uv).ravel(), rcond=None)[0]
        e = e + step
        if np.max(np.abs(step)) < 1e-10:
            break
    rms = float(np.sqrt(np.mean(np.sum((_reproject(e, X, k) - uv) ** 2, axis=1))))
    return pose_matrix(e), rms


def _reproject(e, X, k) -> np.ndarray:
    T = pose_matrix(e)
    return project(X @ T[:3, :3].T + T[:3, 3], k)[0]


def hand_eye(A, B) -> tuple[np.ndarray, np.ndarray]:
    """``X, Y`` (4, 4) with ``A_i X = Y B_i`` for ``A, B`` (N, 4, 4), N >= 3 with rotations about
    different axes (closed form: rotations, then translations by least squares)."""
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    if len(A) < 3:
        raise ValueError(f"hand-eye needs at least three images, got {len(A)}")
    rows = []
    for a, b in zip(A, B, strict=False):  # R_A R_X - R_Y R_B = 0 in vec (column-major) form
        rows.append(np.hstack([np.kron(np.eye(3), a[:3, :3]), -np.kron(b[:3, :3].T, np.eye(3))]))
    v = np.linalg.svd(np.vstack(rows), full_matrices=False)[2][-1]
    Mx, My = v[:9].reshape(3, 3, order="F"), v[9:].reshape(3, 3, order="F")
    if np.linalg.det(Mx) < 0:
        Mx, My = -Mx, -My
    Rx, Ry = _nearest_rotation(Mx), _nearest_rotation(My)
    # R_A t_X - t_Y = R_Y t_B - t_A
    M = np.vstack([np.hstack([a[:3, :3], -np.eye(3)]) for a in A])
    rhs = np.concatenate([Ry @ b[:3, 3] - a[:3, 3] for a, b in zip(A, B, strict=False)])
    t = np.linalg.lstsq(M, rhs, rcond=None)[0]
    X, Y = np.eye(4), np.eye(4)
    X[:3, :3], X[:3, 3] = Rx, t[:3]
    Y[:3, :3], Y[:3, 3] = Ry, t[3:]
    return X, Y
