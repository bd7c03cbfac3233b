"""Starting points from data: base and tool transforms fitted to measured poses.

When the measuring instrument's frame and the tool are unknown (a laser tracker somewhere in the
room, a probe on the flange), the nominal model cannot place the tool at all. With flange poses
``F_i`` from the nominal links and measured poses ``M_i``, ``M_i = B F_i X`` is the hand-eye
problem: the base rotation maps the flange's relative rotations onto the measured ones (a rigid
fit of their rotation axes), the tool rotation is then their mean, the translations follow by
linear least squares, and a final nonlinear least-squares pass polishes all twelve. No I/O here.
"""
from __future__ import annotations

import numpy as np

from .kinematics import forward
from .model import EULER_FIELDS, RobotModel, slot
from .posefit import nearest_rotation
from .transforms import so3_log, to_euler_zyx_trans

__all__ = ["fit_base_and_tool"]


def _exp(w):
    angle = np.linalg.norm(w)
    if angle < 1e-15:
        return np.eye(3)
    k = w / angle
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def fit_base_and_tool(model: RobotModel, q, T_measured, slots=None, orientation_scale: float = 100.0):
    """Slot vector (37,) with base and tool fitted to measured tool poses.

    Parameters
    ----------
    q : array_like, shape (N, 6)
        Joint readings (rad), N >= 3 with varied orientations.
    T_measured : array_like, shape (N, 4, 4)
        Measured tool poses in the instrument's frame (mm).
    slots : array_like, shape (37,), optional
        Link geometry to use (the model's nominal by default); its base and tool are replaced.
    orientation_scale : float
        Lever arm (mm) weighing rotation errors against position errors in the final polish.

    Returns
    -------
    slots : ndarray, shape (37,)
    rms : float
        RMS distance (mm) between measured and fitted tool origins.
    """
    x = np.array(model.nominal if slots is None else slots, dtype=float)
    base = [slot(f"base.{f}") for f in EULER_FIELDS]
    tool = [slot(f"tool.{f}") for f in EULER_FIELDS]
    x[base] = 0.0
    x[tool] = 0.0
    F = forward(x, q)
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
    x[tool] = to_euler_zyx_trans(A_t)
    fitted = forward(x, q)
    rms = float(np.sqrt(np.mean(np.sum((fitted[:, :3, 3] - M[:, :3, 3]) ** 2, axis=1))))
    return x, rms
