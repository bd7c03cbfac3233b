"""Inverse kinematics: closed form for the PUMA 560 structure, numerical for any model.

The closed form holds for the nominal structure of the PUMA 560 in this convention
(alpha = 90, 0, -90, 90, -90 deg; a_1 = a_4 = a_5 = d_2 = d_5 = 0; all beta 0; spherical
wrist); base, tool, joint offsets and the lengths a_2, a_3, d_3, d_4 may take any values.
The eight branches are the products of shoulder (lefty/righty), elbow (up/down) and wrist
(flip/no flip). For a calibrated model (betas, small twists) use :func:`solve_numeric`,
seeded by the closed form of the nominal model. Units: mm, rad. No I/O here.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from fgcal.errors import FgcalError
from fgcal.robots.model import RobotModel, slot
from fgcal.robots.transforms import check_transform, euler_zyx_trans, pose_difference, rot, so3_left_jacobian_inverse

__all__ = ["BRANCHES", "Branch", "IKError", "solve_numeric", "solve_puma", "solve_puma_batch", "wrap_into_limits"]


class IKError(FgcalError):
    """No joint solution (out of reach, beyond the limits, or a model the solver cannot handle)."""


@dataclass(frozen=True)
class Branch:
    """A PUMA arm configuration: ``righty`` shoulder, ``elbow_up``, wrist ``flip`` (q5 < 0)."""

    righty: bool
    elbow_up: bool
    flip: bool

    def __str__(self):
        return f"{'righty' if self.righty else 'lefty'}/{'up' if self.elbow_up else 'down'}/{'flip' if self.flip else 'noflip'}"


BRANCHES = tuple(Branch(*b) for b in itertools.product((True, False), repeat=3))

_PUMA_ALPHA = np.radians([90.0, 0.0, -90.0, 90.0, -90.0])


def _check_puma_structure(x) -> None:
    alphas = np.array([x[slot(f"j{n}.alpha")] for n in range(1, 6)])
    zero = [x[slot(s)] for s in ("j1.a", "j4.a", "j5.a", "j2.d", "j5.d")] + [x[slot(f"j{n}.beta")] for n in range(1, 6)]
    if not (np.allclose(alphas, _PUMA_ALPHA, atol=1e-12) and np.allclose(zero, 0.0, atol=1e-12)):
        raise IKError("closed-form IK needs the PUMA 560 structure (twists 90/0/-90/90/-90 deg, spherical wrist, "
                      "no beta); use the numerical solver for this model")


def wrap_into_limits(q, limits) -> np.ndarray:
    """Shift each angle by multiples of 2 pi into ``limits`` (6, 2), nearest to 0 when several fit.

    Angles that fit nowhere are left as they are (outside the limits).
    """
    q = np.array(q, dtype=float)
    two_pi = 2 * np.pi
    for j in range(q.shape[-1]):
        lo, hi = limits[j]
        qj = q[..., j]
        base = (qj + np.pi) % two_pi - np.pi  # in [-pi, pi)
        best = base.copy()
        best_cost = np.full(base.shape, np.inf)
        for k in range(-3, 4):
            cand = base + k * two_pi
            ok = (cand >= lo - 1e-12) & (cand <= hi + 1e-12)
            cost = np.where(ok, np.abs(cand), np.inf)
            take = cost < best_cost
            best = np.where(take, cand, best)
            best_cost = np.where(take, cost, best_cost)
        q[..., j] = np.where(np.isfinite(best_cost), best, qj)
    return q


def solve_puma_batch(model: RobotModel, T_target, branch: Branch, slots=None):
    """Closed-form IK for many targets ``T_target`` (N, 4, 4) in one arm configuration.

    Returns
    -------
    q : ndarray, shape (N, 6)
        Joint readings (rad), wrapped into the joint limits where possible; NaN where unreachable.
    reachable : ndarray of bool, shape (N,)
    """
    x = model.nominal if slots is None else np.asarray(slots, dtype=float)
    _check_puma_structure(x)
    T_target = check_transform(T_target, "T_target").reshape(-1, 4, 4)
    A_b = euler_zyx_trans(*x[slot("base.phi"):slot("base.pz") + 1])
    A_t = euler_zyx_trans(*x[slot("tool.phi"):slot("tool.pz") + 1])
    W = np.linalg.inv(A_b) @ T_target @ np.linalg.inv(A_t)  # = A_1 ... A_5 Rz(q6)
    a2, a3 = x[slot("j2.a")], x[slot("j3.a")]
    d3, d4 = x[slot("j3.d")], x[slot("j4.d")]
    offsets = np.array([x[slot(f"j{n}.theta")] for n in range(1, 6)] + [0.0])
    px, py, pz = W[:, 0, 3], W[:, 1, 3], W[:, 2, 3]

    # Wrist centre in the base frame: (c1 X + s1 d3, s1 X - c1 d3, Y) with
    # X = a2 c2 + a3 c23 - d4 s23 and Y = a2 s2 + a3 s23 + d4 c23.
    # Shoulder: (px, py) = Rz(t1) (X, -d3) with X = +-sqrt(r^2 - d3^2).
    r2 = px * px + py * py
    reachable = r2 >= d3 * d3
    X = np.sqrt(np.maximum(r2 - d3 * d3, 0.0)) * (1.0 if branch.righty else -1.0)
    t1 = np.arctan2(py, px) - np.arctan2(-d3, X)
    Y = pz
    # Elbow: X^2 + Y^2 = a2^2 + a3^2 + d4^2 + 2 a2 (a3 c3 - d4 s3).
    K = (X * X + Y * Y - a2 * a2 - a3 * a3 - d4 * d4) / (2.0 * a2)
    rho = np.hypot(a3, d4)
    reachable &= np.abs(K) <= rho * (1 + 1e-12)
    gamma = np.arccos(np.clip(K / rho, -1.0, 1.0))
    t3 = -np.arctan2(d4, a3) + (gamma if branch.elbow_up else -gamma)
    # (X, Y) = Rot(t2) (u, v):
    u = a2 + a3 * np.cos(t3) - d4 * np.sin(t3)
    v = a3 * np.sin(t3) + d4 * np.cos(t3)
    t2 = np.arctan2(Y, X) - np.arctan2(v, u)
    # Wrist: R3^T R_W = Rz(t4) Ry(-t5) Rz(t6).
    R3 = rot(2, t1) @ rot(0, np.pi / 2) @ rot(2, t2 + t3) @ rot(0, -np.pi / 2)
    M = np.swapaxes(R3, -1, -2) @ W[:, :3, :3]
    sb = np.hypot(M[:, 0, 2], M[:, 1, 2])
    if not branch.flip:  # no flip: q5 = -b >= 0
        sb = -sb
    b = np.arctan2(sb, M[:, 2, 2])
    singular = np.abs(sb) < 1e-12
    safe = np.where(singular, 1.0, sb)
    # At the wrist singularity (q5 = 0) only t4 + t6 is defined: put it all on t6.
    t4 = np.where(singular, 0.0, np.arctan2(M[:, 1, 2] / safe, M[:, 0, 2] / safe))
    t6 = np.where(singular, np.arctan2(M[:, 1, 0], M[:, 0, 0]), np.arctan2(M[:, 2, 1] / safe, -M[:, 2, 0] / safe))
    theta = np.stack([t1, t2, t3, t4, -b, t6], axis=1)
    q = wrap_into_limits(theta - offsets, model.joint_limits)
    q[~reachable] = np.nan
    return q, reachable


def solve_puma(model: RobotModel, T_target, branch: Branch, slots=None) -> np.ndarray:
    """Closed-form joint readings (6,) rad that put the tool at ``T_target`` (4, 4) mm.

    Parameters
    ----------
    model : RobotModel
    T_target : array_like, shape (4, 4)
        Desired tool pose in the world frame.
    branch : Branch
    slots : array_like, shape (37,), optional
        Geometry to invert (PUMA structure); the model's nominal by default.

    Returns
    -------
    ndarray, shape (6,)
        Joint readings wrapped into the joint limits where possible (they may still lie outside:
        check with ``model.in_limits``).

    Raises
    ------
    IKError
        If the target is out of reach for this branch or the geometry is not PUMA-like.
    """
    q, reachable = solve_puma_batch(model, check_transform(T_target, "T_target")[None], branch, slots)
    if not reachable[0]:
        raise IKError(f"target out of reach in the {branch} configuration")
    return q[0]


def solve_numeric(model: RobotModel, T_target, q_seed, slots=None, orientation_scale: float = 100.0,
                  tol_mm: float = 1e-9) -> np.ndarray:
    """Joint readings (n,) (rad, mm) that bring any model's tool to ``T_target``, from ``q_seed``.

    Bounded least squares on the pose error (position in mm, orientation in rad times
    ``orientation_scale`` mm) with the analytic joint Jacobian, within the joint limits.

    Raises
    ------
    IKError
        If the pose error at the solution exceeds ``1e-6`` mm (or rad x scale).
    """
    x = model.nominal if slots is None else np.asarray(slots, dtype=float)
    T_target = check_transform(T_target, "T_target")
    w = np.array([1, 1, 1, orientation_scale, orientation_scale, orientation_scale], dtype=float)
    lo, hi = model.joint_limits[:, 0], model.joint_limits[:, 1]
    seed = np.clip(np.asarray(q_seed, dtype=float), lo, hi)

    def residual(q):
        d, delta = pose_difference(model.forward(x, q)[0], T_target)
        return np.concatenate([d, delta]) * w

    def jac(q):
        # residual = [p - p_t; log(R R_t^T)]: d log = J_l^-1(log) w_world
        J = model.chain.jacobians(x, q).pose_joints[0].copy()
        _, delta = pose_difference(model.forward(x, q)[0], T_target)
        J[3:] = so3_left_jacobian_inverse(delta) @ J[3:]
        return J * w[:, None]

    from scipy.optimize import least_squares

    sol = least_squares(residual, seed, jac=jac, bounds=(lo, hi), xtol=1e-15, ftol=1e-15, gtol=1e-15,
                        max_nfev=200, method="trf")
    q, r = sol.x, sol.fun
    err = float(np.linalg.norm(r))
    # The bounded solver creeps the last digits on a redundant arm (7 joints, 6 equations): finish
    # with minimum-norm Gauss-Newton steps while they stay inside the limits.
    for _ in range(20):
        if err <= tol_mm or err > 1.0:
            break
        step = -np.linalg.lstsq(jac(q), r, rcond=None)[0]
        q_new = q + step
        if np.any(q_new < lo) or np.any(q_new > hi):
            break
        r_new = residual(q_new)
        if np.linalg.norm(r_new) >= err:
            break
        q, r, err = q_new, r_new, float(np.linalg.norm(r_new))
    sol.x = q
    if err > 1e-6:
        at_limit = [model.joint_names[j] for j in range(model.n_joints) if min(sol.x[j] - lo[j], hi[j] - sol.x[j]) < 1e-6]
        why = f"; {', '.join(at_limit)} at the joint limit" if at_limit else ""
        raise IKError(f"numerical IK did not reach the target (pose error {err:.3g} mm{why})")
    return sol.x
