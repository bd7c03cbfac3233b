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

from fgcal.measurements.camera import pose_entries, project
from fgcal.robots.transforms import rot

__all__ = ["PNP_MIN_POINTS", "hand_eye", "pnp", "pnp_each", "pnp_images", "undistort"]

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
    """The rotation nearest ``M`` (3, 3) or each of a stack (N, 3, 3)."""
    U, _, Vt = np.linalg.svd(M)
    R = U @ Vt
    flip = np.linalg.det(R) < 0
    if np.any(flip):
        R = np.where(flip[..., None, None], (U * [1.0, 1.0, -1.0]) @ Vt, R)
    return R


def _dlt_rows(P, n) -> np.ndarray:
    """The DLT's two rows a point (N, 2m, 3k): ``[P, 0, -u P]`` and ``[0, P, -v P]`` for
    homogeneous points ``P`` (N, m, k) and normalised image points ``n`` (N, m, 2)."""
    N, m, k = P.shape
    A = np.zeros((N, m, 2, 3 * k))
    A[:, :, 0, :k], A[:, :, 1, k:2 * k] = P, P
    A[:, :, 0, 2 * k:], A[:, :, 1, 2 * k:] = -n[..., :1] * P, -n[..., 1:] * P
    return A.reshape(N, 2 * m, 3 * k)


def _ones(X) -> np.ndarray:
    return np.ones(X.shape[:-1] + (1,))


def _pnp_planar(X, n) -> np.ndarray:
    """Start poses (N, 4, 4) of planar targets ``X`` (N, m, 3) by homographies (DLT)."""
    A = _dlt_rows(np.concatenate([X[..., :2], _ones(X)], axis=-1), n)
    H = np.linalg.svd(A, full_matrices=False)[2][:, -1].reshape(-1, 3, 3)
    H = H * (2.0 / (np.linalg.norm(H[:, :, 0], axis=1) + np.linalg.norm(H[:, :, 1], axis=1)))[:, None, None]
    H = np.where(H[:, 2:3, 2:3] < 0, -H, H)  # the target in front of the camera (its origin at positive depth)
    T = np.broadcast_to(np.eye(4), H.shape[:1] + (4, 4)).copy()
    T[:, :3, :3] = _nearest_rotation(np.stack([H[:, :, 0], H[:, :, 1], np.cross(H[:, :, 0], H[:, :, 1])], axis=2))
    T[:, :3, 3] = H[:, :, 2]
    return T


def _pnp_dlt(X, n) -> np.ndarray:
    """Start poses (N, 4, 4) of non-planar targets ``X`` (N, m, 3) by 3D DLTs."""
    A = _dlt_rows(np.concatenate([X, _ones(X)], axis=-1), n)
    P = np.linalg.svd(A, full_matrices=False)[2][:, -1].reshape(-1, 3, 4)
    P = P / np.cbrt(np.linalg.det(P[:, :, :3]))[:, None, None]
    T = np.broadcast_to(np.eye(4), P.shape[:1] + (4, 4)).copy()
    T[:, :3, :3], T[:, :3, 3] = _nearest_rotation(P[:, :, :3]), P[:, :, 3]
    return T


def _zyx(a) -> tuple[np.ndarray, np.ndarray]:
    """``R = Rz(phi) Ry(theta) Rx(psi)`` (N, 3, 3) of angles ``a`` (N, 3) rad, and ``dR`` (N, 3, 3, 3)
    by phi, theta, psi."""
    R3 = [rot(axis, a[:, 2 - axis]) for axis in range(3)]  # Rx, Ry, Rz
    D3 = []
    for axis, Ra in enumerate(R3):  # d/da of a rotation about one axis: its plane's entries turned by 90 deg
        i, j = [(1, 2), (2, 0), (0, 1)][axis]
        D = np.zeros_like(Ra)
        D[:, i, i], D[:, j, j], D[:, i, j], D[:, j, i] = -Ra[:, j, i], -Ra[:, j, i], -Ra[:, i, i], Ra[:, i, i]
        D3.append(D)
    Rx, Ry, Rz = R3
    dR = np.stack([D3[2] @ Ry @ Rx, Rz @ D3[1] @ Rx, Rz @ Ry @ D3[0]], axis=1)
    return Rz @ Ry @ Rx, dR


def _steps(J, r) -> np.ndarray:
    """Least-squares steps (N, 6) of the stacked systems ``J`` (N, R, 6), ``r`` (N, R) (QR; an image
    whose system is singular by lstsq, the minimum-norm step)."""
    try:
        Q, U = np.linalg.qr(J)
        return np.linalg.solve(U, np.einsum("nri,nr->ni", Q, r)[..., None])[..., 0]
    except np.linalg.LinAlgError:
        return np.array([np.linalg.lstsq(j, b, rcond=None)[0] for j, b in zip(J, r, strict=True)])


def pnp_images(X, uv, k, iterations: int = 15) -> tuple[np.ndarray, np.ndarray]:
    """:func:`pnp` of N images of m corners each at once: ``X`` (N, m, 3) mm, ``uv`` (N, m, 2) px,
    intrinsics ``k`` (9,); returns ``T_ct`` (N, 4, 4) and the RMS reprojection errors (N,) px.

    Raises
    ------
    ValueError
        With fewer than four points (six for a non-planar target).
    """
    X = np.asarray(X, dtype=float)
    uv = np.asarray(uv, dtype=float)
    N, m = X.shape[:2]
    planar = np.all(np.abs(X[..., 2]) < 1e-9, axis=1)
    if m < (PNP_MIN_POINTS if planar.all() else 6):
        raise ValueError(f"PnP needs at least {PNP_MIN_POINTS if planar.all() else 6} points, got {m}")
    n = undistort(uv.reshape(-1, 2), k).reshape(N, m, 2)
    T = np.empty((N, 4, 4))
    for sel, start in ((planar, _pnp_planar), (~planar, _pnp_dlt)):
        if sel.any():
            T[sel] = start(X[sel], n[sel])
    e = pose_entries(T)
    active = np.ones(N, dtype=bool)
    for _ in range(iterations):  # Gauss-Newton on the pixels, analytic Jacobian in the pose entries
        i = np.flatnonzero(active)
        if not len(i):
            break
        R, dR = _zyx(e[i, 3:])
        uv_e, J_X, _ = project((X[i] @ np.swapaxes(R, 1, 2) + e[i, None, :3]).reshape(-1, 3), k)
        D = np.concatenate([np.broadcast_to(np.eye(3), (len(i), m, 3, 3)),
                            np.einsum("naij,nmj->nmia", dR, X[i])], axis=3)
        J = (J_X.reshape(len(i), m, 2, 3) @ D).reshape(len(i), 2 * m, 6)
        step = _steps(J, (uv[i] - uv_e.reshape(len(i), m, 2)).reshape(len(i), -1))
        e[i] += step
        active[i[np.max(np.abs(step), axis=1) < 1e-10]] = False
    T = np.broadcast_to(np.eye(4), (N, 4, 4)).copy()
    T[:, :3, :3], T[:, :3, 3] = _zyx(e[:, 3:])[0], e[:, :3]
    uv_e = project((X @ np.swapaxes(T[:, :3, :3], 1, 2) + T[:, None, :3, 3]).reshape(-1, 3), k)[0]
    return T, np.sqrt(np.mean(np.sum((uv_e.reshape(N, m, 2) - uv) ** 2, axis=2), axis=1))


def pnp(X, uv, k, iterations: int = 15) -> tuple[np.ndarray, float]:
    """The target frame in the camera frame, ``T_ct`` (4, 4), from target points ``X`` (m, 3) mm and
    their pixels ``uv`` (m, 2) with intrinsics ``k`` (9,); and the RMS reprojection error (px).

    Raises
    ------
    ValueError
        With fewer than four points (six for a non-planar target) or a degenerate configuration.
    """
    T, rms = pnp_images(np.asarray(X, dtype=float)[None], np.asarray(uv, dtype=float)[None], k, iterations)
    return T[0], float(rms[0])


def pnp_each(images: list, k, memo: dict) -> list:
    """:func:`pnp` of each image ``(X (m, 3), uv (m, 2))`` with intrinsics ``k`` (9,): ``(T_ct, rms)``
    or None where it fails. Images of equal corner counts are solved together
    (:func:`pnp_images`); ``memo`` keeps each image's by its values (solved once however often asked)."""
    k = np.asarray(k, dtype=float)
    keys = [(np.asarray(X, dtype=float).tobytes(), np.asarray(uv, dtype=float).tobytes(), k.tobytes())
            for X, uv in images]
    todo: dict = {}
    for key, (X, uv) in zip(keys, images, strict=True):
        if key not in memo:
            todo.setdefault(len(X), {})[key] = (X, uv)
    for group in todo.values():
        try:
            T, rms = pnp_images(np.array([X for X, _ in group.values()]), np.array([u for _, u in group.values()]), k)
            memo.update({key: (T[j], float(rms[j])) for j, key in enumerate(group)})
        except (ValueError, np.linalg.LinAlgError):  # one at a time: only the images that fail fail
            for key, (X, uv) in group.items():
                try:
                    memo[key] = pnp(X, uv, k)
                except (ValueError, np.linalg.LinAlgError):
                    memo[key] = None
    return [memo[key] for key in keys]


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
