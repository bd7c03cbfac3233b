"""Closed-form inverse kinematics of the Universal Robots structure, in fgcal's convention.

The structure (the nominal geometry of every UR, in any model of one: built-in table, DH file or
URDF with the UR's joints): twists 90, 0, 0, 90, -90 deg; ``a_1 = a_4 = a_5 = 0``; ``d_2 = d_3 = 0``;
all beta 0. Base, tool, joint offsets (theta, the coupling's offsets), d_1, the lengths a_2, a_3
and the wrist offsets d_4, d_5 may take any values. With the tool removed, the chain is::

    W = Tz(d1) Rz(f1) Rx(90) Rz(f2) Tx(a2) Rz(f3) Tx(a3) Rz(f4) Tz(d4) Rx(90) Rz(f5) Tz(d5) Rx(-90) Rz(f6)

(``f_k`` the joint angle: reading plus offsets). Its solution, derived here:

* shoulder: the wrist point ``p`` of W lies ``d4`` along joint 1's rotated z axis
  ``z1 = (sin f1, -cos f1, 0)``: ``p . z1 = d4``, so ``f1 = psi + asin(d4 / r)`` (the *righty* branch)
  or ``psi + pi - asin(d4 / r)`` with ``(r, psi)`` the polar form of ``(p_x, p_y)``;
* wrist: ``cos f5 = z6 . z1`` (*flip*: ``sin f5 < 0``); the components of ``z1`` in W's frame are
  ``(s5 c6, -s5 s6, c5)``, which give ``f6``; then ``f2 + f3 + f4`` from the rotation;
* elbow: the planar 2R arm ``a2, a3`` reaches the point ``p - d5 z5 - d4 z1`` (joint 4's axis)
  in link 1's plane (*elbow_up*: ``sin f3 < 0``).

The eight branches use :class:`fgcal.robots.ik.Branch` with these meanings. At the wrist
singularity (``sin f5 = 0``) only ``f4 + f6`` is defined: f6 is set to 0. Units: mm, rad. No I/O.
"""
from __future__ import annotations

import numpy as np

from fgcal.robots.base_frame import base_transform
from fgcal.robots.ik import Branch, IKError, wrap_into_limits
from fgcal.robots.model import EULER_FIELDS, RobotModel
from fgcal.robots.transforms import check_transform, euler_zyx_trans, rot
from fgcal.robots.ur_kinematics import is_ur, rot_z4, ur_kinematics

__all__ = ["is_ur_structure", "solve_ur_any", "solve_ur_batch", "ur_branch_of", "ur_proxy"]

_UR_ALPHA = np.radians([90.0, 0.0, 0.0, 90.0, -90.0])


def _values(model: RobotModel, x, field: str) -> np.ndarray:
    return np.array([x[model.slot(f"{j}.{field}")] for j in model.link_names])


def is_ur_structure(model: RobotModel, x=None) -> bool:
    """The geometry ``x`` (the nominal by default) has the UR structure of the module docstring."""
    if model.n_joints != 6 or not np.all(model.joint_is_angle) or model.joint_map is not None:
        return False
    x = model.nominal if x is None else np.asarray(x, dtype=float)
    a, d = _values(model, x, "a"), _values(model, x, "d")
    # a URDF's rounded pi/2 (1.57079632679) is 5e-12 off: within the tolerances (rad, mm)
    angles_ok = np.allclose([*_values(model, x, "alpha") - _UR_ALPHA, *_values(model, x, "beta")], 0.0, atol=1e-9)
    return bool(angles_ok and np.allclose([a[0], a[3], a[4], d[1], d[2]], 0.0, atol=1e-6))


def _wrist_frame(model: RobotModel, x, T_target) -> np.ndarray:
    """``W`` (N, 4, 4): the targets with base, joint 1's d and the tool (and tool offset) removed."""
    A_b = euler_zyx_trans(*[x[model.slot(f"base.{f}")] for f in EULER_FIELDS])
    A_t = euler_zyx_trans(*[x[model.slot(f"tool.{f}")] for f in EULER_FIELDS]) @ model.tool_offset_matrix
    W = np.linalg.inv(A_b) @ T_target @ np.linalg.inv(A_t)
    W[:, 2, 3] -= x[model.slot(f"{model.link_names[0]}.d")]
    return W


def solve_ur_batch(model: RobotModel, T_target, branch: Branch, slots=None) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form IK of a UR-structured geometry for many targets in one branch.

    Parameters
    ----------
    model : RobotModel
    T_target : array_like, shape (N, 4, 4)
        Tool poses (mm) in the world frame.
    branch : Branch
        ``righty`` (shoulder), ``elbow_up`` and ``flip`` as in the module docstring.
    slots : array_like, shape (37,), optional
        The geometry (UR structure); the model's nominal by default.

    Returns
    -------
    q : ndarray, shape (N, 6)
        Joint readings (rad), wrapped into the joint limits where possible; NaN where unreachable.
    reachable : ndarray of bool, shape (N,)

    Raises
    ------
    IKError
        If the geometry is not of the UR structure.
    """
    x = model.nominal if slots is None else np.asarray(slots, dtype=float)
    if not is_ur_structure(model, x):
        raise IKError("closed-form IK needs the UR structure (twists 90/0/0/90/-90 deg, a1 = a4 = a5 = 0, "
                      "d2 = d3 = 0, no beta)")
    W = _wrist_frame(model, x, check_transform(T_target, "T_target").reshape(-1, 4, 4))
    a, d = _values(model, x, "a"), _values(model, x, "d")
    a2, a3, d4, d5 = a[1], a[2], d[3], d[4]
    p, R = W[:, :3, 3], W[:, :3, :3]
    r = np.hypot(p[:, 0], p[:, 1])
    reachable = r >= abs(d4) * (1 + 1e-12)
    s = np.arcsin(np.clip(d4 / np.where(r > 0, r, 1.0), -1.0, 1.0))
    f1 = np.arctan2(p[:, 1], p[:, 0]) + (s if branch.righty else np.pi - s)
    z1 = np.stack([np.sin(f1), -np.cos(f1), np.zeros_like(f1)], axis=1)
    c5 = np.clip(np.einsum("ni,ni->n", R[:, :, 2], z1), -1.0, 1.0)
    f5 = np.arccos(c5) * (-1.0 if branch.flip else 1.0)
    s5 = np.sin(f5)
    w = np.einsum("nji,nj->ni", R, z1)  # z1 in W's frame: (s5 c6, -s5 s6, c5)
    singular = np.abs(s5) < 1e-12
    safe = np.where(singular, 1.0, s5)
    f6 = np.where(singular, 0.0, np.arctan2(-w[:, 1] / safe, w[:, 0] / safe))
    R1 = rot(2, f1) @ rot(0, np.pi / 2)
    R4 = R @ rot(2, -f6) @ rot(0, np.pi / 2) @ rot(2, -f5)  # the frame after link 4
    M = np.swapaxes(R1, -1, -2) @ R4 @ rot(0, -np.pi / 2)  # Rz(f2 + f3 + f4)
    f234 = np.arctan2(M[:, 1, 0], M[:, 0, 0])
    p3 = p - d5 * R4[:, :, 2] - d4 * z1  # joint 4's axis point in link 1's plane
    local = np.einsum("nji,nj->ni", R1, p3)
    X, Y = local[:, 0], local[:, 1]
    c3 = (X * X + Y * Y - a2 * a2 - a3 * a3) / (2.0 * a2 * a3)
    reachable &= np.abs(c3) <= 1 + 1e-12
    f3 = np.arccos(np.clip(c3, -1.0, 1.0)) * (-1.0 if branch.elbow_up else 1.0)
    f2 = np.arctan2(Y, X) - np.arctan2(a3 * np.sin(f3), a2 + a3 * np.cos(f3))
    f4 = f234 - f2 - f3
    angles = np.stack([f1, f2, f3, f4, f5, f6], axis=1)
    angles[:, :5] -= _values(model, x, "theta")
    q = wrap_into_limits(model.chain.readings_of(angles), model.joint_limits)
    q[~reachable] = np.nan
    return q, reachable


def ur_branch_of(model: RobotModel, q, slots=None) -> list[Branch]:
    """The branch of each joint set ``q`` (N, 6) rad of a UR-structured geometry (module docstring)."""
    x = model.nominal if slots is None else np.asarray(slots, dtype=float)
    q = model.chain.check_joints(q)
    f = model.chain.joint_values(q)
    f[:, :5] += _values(model, x, "theta")
    W = _wrist_frame(model, x, model.forward(x, q))
    p = W[:, :3, 3]
    psi = np.arctan2(p[:, 1], p[:, 0])
    return [Branch(righty=bool(np.cos(f1 - ps) >= 0), elbow_up=bool(np.sin(f3) < 0), flip=bool(np.sin(f5) < 0))
            for f1, ps, f3, f5 in zip(f[:, 0], psi, f[:, 2], f[:, 4], strict=True)]


def _dh_of(origin) -> tuple[float, float, float, float, float]:
    """``(a, alpha, theta, d, residual)`` of ``origin = Tx(a) Rx(alpha) Rz(theta) Tz(d)`` (mm, rad);
    the residual (mm or rad) is how far ``origin`` is from that form."""
    R, t = origin[:3, :3], origin[:3, 3]
    alpha = float(np.arctan2(-R[1, 2], R[2, 2]))
    M = rot(0, -alpha) @ R
    theta = float(np.arctan2(M[1, 0], M[0, 0]))
    d = float(t @ R[:, 2])
    rebuilt = rot(0, alpha) @ rot(2, theta)
    residual = max(float(np.abs(rebuilt - R).max()), float(np.abs(t - [t[0], 0.0, 0.0] - d * R[:, 2]).max()))
    return float(t[0]), alpha, theta, d, residual


def ur_proxy(model: RobotModel, slots=None, ideal: bool = False) -> tuple[RobotModel, np.ndarray] | None:
    """A table model of the UR structure with the same forward kinematics as ``model`` at ``slots``
    (a UR URDF or an imported kinematics file, whose rebuilt frames have other twist signs), and its
    slots; ``None`` when the chain is not of the UR structure (a calibrated one) or not a UR.
    ``ideal``: the nearest chain of the UR structure instead (twists exact, off-structure parts
    dropped) where the chain is a UR's calibrated one, for starting numerical IK."""

    if not is_ur(model):
        return None
    x = model.nominal if slots is None else np.asarray(slots, dtype=float)
    kin = ur_kinematics(model, x, hash="")
    dh = [_dh_of(o) for o in kin.origins]
    if ideal:  # a, alpha, theta, d of the UR structure: twists exact, a_0 = a_1 = a_4 = a_5 = d_2 = d_3 = 0
        alphas = [0.0, *_UR_ALPHA]
        dh = [(a if k in (2, 3) else 0.0, alphas[k], t, 0.0 if k in (1, 2) else dd, 0.0)
              for k, (a, _, t, dd, _) in enumerate(dh)]
    if max(r for *_, r in dh) > 1e-6:
        return None
    first = np.eye(4)
    first[:3, :3] = rot(0, dh[0][1])
    first[0, 3] = dh[0][0]
    base = base_transform(model, x) @ np.linalg.inv(kin.own_base) @ rot_z4(np.pi) @ first @ rot_z4(dh[0][2])
    base[:3, 3] += base[:3, 2] * dh[0][3]
    tool = rot_z4(dh[5][2])
    tool[2, 3] = dh[5][3]
    tool = tool @ kin.tcp
    from fgcal.robots.transforms import to_euler_zyx_trans

    links = []
    for k in range(5):  # theta, d, beta, a, alpha of link k + 1; link 1's theta and d are in the base
        theta, d = (0.0, 0.0) if k == 0 else (dh[k][2], dh[k][3])
        links += [theta, d, 0.0, dh[k + 1][0], dh[k + 1][1]]
    try:
        nominal = np.concatenate([to_euler_zyx_trans(base), links, to_euler_zyx_trans(tool)])
    except ValueError:  # a tool turned by 90 deg about y: no closed form through this proxy
        return None
    proxy = RobotModel(name=f"{model.name} (UR table)", nominal=nominal, joint_limits=model.joint_limits)
    return (proxy, proxy.nominal) if is_ur_structure(proxy) else None


def solve_ur_any(model: RobotModel, T_target, branch: Branch, slots=None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`solve_ur_batch` for any UR model: through :func:`ur_proxy` when its frames are not the table's."""
    if is_ur_structure(model, slots):
        return solve_ur_batch(model, T_target, branch, slots)
    found = ur_proxy(model, slots)
    if found is not None:
        return solve_ur_batch(found[0], T_target, branch, found[1])
    found = ur_proxy(model, slots, ideal=True)  # a UR's calibrated chain: the ideal one's solution, refined
    if found is None:
        raise IKError(f"{model.name}: closed-form IK needs the UR structure (a UR's nominal geometry)")
    from fgcal.robots.ik import solve_numeric

    T_target = check_transform(T_target, "T_target").reshape(-1, 4, 4)
    q, reachable = solve_ur_batch(found[0], T_target, branch, found[1])
    x = model.nominal if slots is None else np.asarray(slots, dtype=float)
    for i in np.nonzero(reachable)[0]:
        try:
            q[i] = solve_numeric(model, T_target[i], q[i], slots=x)
        except IKError:
            q[i], reachable[i] = np.nan, False
    return q, reachable
