"""Starting points from data: base and tool transforms fitted to measured poses or points.

When the measuring instrument's frame and the tool are unknown (a laser tracker somewhere in the
room, a probe on the flange), the nominal model cannot place the tool at all. With flange poses
``F_i`` from the nominal links and measured poses ``M_i``, ``M_i = B F_i X`` is the hand-eye
problem: the base rotation maps the flange's relative rotations onto the measured ones (a rigid
fit of their rotation axes), the tool rotation is then their mean, the translations follow by
linear least squares, and a final nonlinear least-squares pass polishes all twelve. With measured
points only (a tracker reflector), ``P_i = B F_i p`` is solved the same way for the base and the
point's offset ``p`` on the flange, alternating a rigid fit of the base with a linear fit of ``p``.
No I/O here.
"""
from __future__ import annotations

import numpy as np

from fgcal.measurements.posefit import nearest_rotation
from fgcal.robots.model import EULER_FIELDS, RobotModel
from fgcal.robots.transforms import so3_log, to_euler_zyx_trans

__all__ = ["fit_base_and_point", "fit_base_and_tool"]


def _exp(w):
    angle = np.linalg.norm(w)
    if angle < 1e-15:
        return np.eye(3)
    k = w / angle
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def _flange_poses(model: RobotModel, q, slots):
    """``(slots with base and tool zeroed, base indices, tool indices, flange poses (N, 4, 4))``."""
    x = np.array(model.nominal if slots is None else slots, dtype=float)
    base = [model.slot(f"base.{f}") for f in EULER_FIELDS]
    tool = [model.slot(f"tool.{f}") for f in EULER_FIELDS]
    x[base] = 0.0
    x[tool] = 0.0
    # The flange: the chain without the tool (nor a constant tool offset).
    return x, base, tool, model.forward(x, q) @ np.linalg.inv(model.tool_offset_matrix)


def fit_base_and_tool(model: RobotModel, q, T_measured, slots=None, orientation_scale: float = 100.0):
    """Slot vector (S,) with base and tool fitted to measured tool poses.

    Parameters
    ----------
    q : array_like, shape (N, n)
        Joint readings (rad, mm), N >= 3 with varied orientations.
    T_measured : array_like, shape (N, 4, 4)
        Measured tool poses in the instrument's frame (mm).
    slots : array_like, shape (S,), optional
        Link geometry to use (the model's nominal by default); its base and tool are replaced.
    orientation_scale : float
        Lever arm (mm) weighing rotation errors against position errors in the final polish.

    Returns
    -------
    slots : ndarray, shape (S,)
    rms : float
        RMS distance (mm) between measured and fitted tool origins.
    """
    x, base, tool, F = _flange_poses(model, q, slots)
    post = model.tool_offset_matrix
    M = np.asarray(T_measured, dtype=float)
    n = len(F)
    # Base rotation from relative rotations: axis(M_i M_0^T) = R_b axis(F_i F_0^T).
    ref = 0
    a_f = so3_log(F[:, :3, :3] @ F[ref, :3, :3].T)
    a_m = so3_log(M[:, :3, :3] @ M[ref, :3, :3].T)
    H = a_f.T @ a_m
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R_b = Vt.T @ D @ U.T
    R_t = nearest_rotation(np.einsum("nji,jk,nkl->il", F[:, :3, :3], R_b.T, M[:, :3, :3]))
    # Translations: M_p - R_b F_p = R_b F_R p_t + t_b (linear in p_t, t_b).
    A = np.zeros((3 * n, 6))
    A[:, :3] = np.einsum("ij,njk->nik", R_b, F[:, :3, :3]).reshape(-1, 3)
    A[:, 3:] = np.tile(np.eye(3), (n, 1))
    b = (M[:, :3, 3] - F[:, :3, 3] @ R_b.T).ravel()
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    p_t, t_b = sol[:3], sol[3:]

    def unpack(v):
        Rb = _exp(v[0:3]) @ R_b
        Rt = R_t @ _exp(v[6:9])
        return Rb, v[3:6] + t_b, Rt, v[9:12] + p_t

    def residual(v):
        Rb, tb, Rt, pt = unpack(v)
        pos = (F[:, :3, 3] + np.einsum("nij,j->ni", F[:, :3, :3], pt)) @ Rb.T + tb - M[:, :3, 3]
        Rfit = np.einsum("ij,njk,kl->nil", Rb, F[:, :3, :3], Rt)
        ang = so3_log(Rfit @ np.swapaxes(M[:, :3, :3], 1, 2)) * orientation_scale
        return np.concatenate([pos.ravel(), ang.ravel()])

    from scipy.optimize import least_squares

    polished = least_squares(residual, np.zeros(12), x_scale=np.r_[[1e-3] * 3, [1.0] * 3, [1e-3] * 3, [1.0] * 3])
    Rb, tb, Rt, pt = unpack(polished.x)
    A_b = np.eye(4)
    A_b[:3, :3], A_b[:3, 3] = Rb, tb
    A_t = np.eye(4)
    A_t[:3, :3], A_t[:3, 3] = Rt, pt
    x[base] = to_euler_zyx_trans(A_b)
    x[tool] = to_euler_zyx_trans(A_t @ np.linalg.inv(post))
    fitted = model.forward(x, q)
    rms = float(np.sqrt(np.mean(np.sum((fitted[:, :3, 3] - M[:, :3, 3]) ** 2, axis=1))))
    return x, rms


def _rigid_fit(A, B):
    """Rotation and translation ``(R, t)`` minimising ``sum |R a_i + t - b_i|^2`` (Kabsch)."""
    ca, cb = A.mean(axis=0), B.mean(axis=0)
    U, _, Vt = np.linalg.svd((A - ca).T @ (B - cb))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, cb - R @ ca


def fit_base_and_point(model: RobotModel, q, points, slots=None, iterations: int = 100):
    """Slot vector (S,) with the base and the measured point's offset on the flange fitted to points.

    The tool frame is put at the point with the flange's orientation (a point has none of its own).

    Parameters
    ----------
    q : array_like, shape (N, n_joints)
        Joint readings (rad), N >= 3 with the flange's orientation varied.
    points : array_like, shape (N, 3)
        Measured positions of the point in the instrument's frame (mm).
    slots : array_like, shape (S,), optional
        Link geometry to use (the model's nominal by default); its base and tool are replaced.

    Returns
    -------
    slots : ndarray, shape (S,)
    rms : float
        RMS distance (mm) between measured and fitted points.
    """
    x, base, tool, F = _flange_poses(model, q, slots)
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    Fr, Fp = F[:, :3, :3], F[:, :3, 3]
    p = np.zeros(3)
    for _ in range(iterations):
        R_b, t_b = _rigid_fit(Fp + Fr @ p, P)
        # R_b^T (P - t_b) - F_p = F_R p: linear in p.
        b = ((P - t_b) @ R_b - Fp).ravel()
        p_new, *_ = np.linalg.lstsq(Fr.reshape(-1, 3), b, rcond=None)
        done = np.linalg.norm(p_new - p) < 1e-9
        p = p_new
        if done:
            break
    R_b, t_b = _rigid_fit(Fp + Fr @ p, P)

    def residual(v):
        return ((Fp + Fr @ (p + v[6:9])) @ (_exp(v[0:3]) @ R_b).T + t_b + v[3:6] - P).ravel()

    from scipy.optimize import least_squares

    v = least_squares(residual, np.zeros(9), x_scale=np.r_[[1e-3] * 3, [1.0] * 6]).x
    A_b = np.eye(4)
    A_b[:3, :3], A_b[:3, 3] = _exp(v[0:3]) @ R_b, t_b + v[3:6]
    x[base] = to_euler_zyx_trans(A_b)
    x[tool[3:]] = p + v[6:9]
    fitted = (model.forward(x, q) @ np.linalg.inv(model.tool_offset_matrix))[:, :3, 3]
    rms = float(np.sqrt(np.mean(np.sum((fitted - P) ** 2, axis=1))))
    return x, rms
