"""Forward kinematics and analytic Jacobians, vectorised over many joint readings.

The chain ``T(q) = A_b A_1 ... A_5 Rz(q_6) A_t`` is a fixed sequence of elementary operations
(rotations about, or translations along, a local axis). Each operation depends on one slot
(a geometric parameter) and possibly on one joint reading. Differentiating the chain through an
operation is then a screw about (or along) that operation's world axis, which gives exact
Jacobians with no symbolic algebra.

Units: mm and rad. Slot vectors have shape (37,) in :data:`fgcal.model.SLOT_NAMES` order.
Jacobians of a pose are ``(6, ·)``: rows ``[dp_x, dp_y, dp_z, w_x, w_y, w_z]``, the world-frame
translation of the tool origin and the world-frame rotation vector (``dR = [w]x R``), the same
quantities as the paper's differential displacement and orientation (eq. 17).
No I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .model import EULER_FIELDS, N_JOINTS, N_LINKS_IN_CHAIN, SLOT_NAMES, slot
from .transforms import rot

__all__ = ["ChainOp", "CHAIN", "check_joints", "forward", "forward_frames", "ChainJacobians", "jacobians"]

N_SLOTS = len(SLOT_NAMES)


@dataclass(frozen=True)
class ChainOp:
    """One elementary operation: ``kind`` 'R' (rotate) or 'T' (translate) about/along ``axis``."""

    kind: str
    axis: int
    slot: int | None
    joint: int | None


def _build_chain() -> tuple[ChainOp, ...]:
    ops = []
    for prefix in ("base",):
        ops += [ChainOp("R", 2, slot(f"{prefix}.phi"), None), ChainOp("R", 1, slot(f"{prefix}.theta"), None),
                ChainOp("R", 0, slot(f"{prefix}.psi"), None)]
        ops += [ChainOp("T", i, slot(f"{prefix}.{f}"), None) for i, f in enumerate(EULER_FIELDS[3:])]
    for n in range(1, N_LINKS_IN_CHAIN + 1):
        ops += [ChainOp("R", 2, slot(f"j{n}.theta"), n - 1), ChainOp("T", 2, slot(f"j{n}.d"), None),
                ChainOp("T", 0, slot(f"j{n}.a"), None), ChainOp("R", 0, slot(f"j{n}.alpha"), None),
                ChainOp("R", 1, slot(f"j{n}.beta"), None)]
    ops.append(ChainOp("R", 2, None, N_JOINTS - 1))
    ops += [ChainOp("R", 2, slot("tool.phi"), None), ChainOp("R", 1, slot("tool.theta"), None),
            ChainOp("R", 0, slot("tool.psi"), None)]
    ops += [ChainOp("T", i, slot(f"tool.{f}"), None) for i, f in enumerate(EULER_FIELDS[3:])]
    return tuple(ops)


CHAIN: tuple[ChainOp, ...] = _build_chain()


def _cross(a, b) -> np.ndarray:
    """Cross product over the last axis; np.cross costs ~20 us of overhead per call on small arrays."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def check_joints(q) -> np.ndarray:
    """Convert joint readings to a float ``(N, 6)`` array (rad); raise with the expected shape."""
    q = np.asarray(q, dtype=float)
    if q.ndim == 1:
        q = q[None, :]
    if q.ndim != 2 or q.shape[1] != N_JOINTS:
        raise ValueError(f"joint readings must have shape (N, 6) or (6,), got {np.shape(q)}")
    return q


def _check_slots(x) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    if x.shape != (N_SLOTS,):
        raise ValueError(f"slot vector must have shape ({N_SLOTS},), got {x.shape}")
    return x


_KIND_ROT = np.array([op.kind == "R" for op in CHAIN])
_AXIS = np.array([op.axis for op in CHAIN])
_SLOT_MAP = np.zeros((len(CHAIN), N_SLOTS))
_JOINT_MAP = np.zeros((len(CHAIN), N_JOINTS))
for _k, _op in enumerate(CHAIN):
    if _op.slot is not None:
        _SLOT_MAP[_k, _op.slot] = 1.0
    if _op.joint is not None:
        _JOINT_MAP[_k, _op.joint] = 1.0


_CONST_ROT = [[k for k, op in enumerate(CHAIN) if op.kind == "R" and op.joint is None and op.axis == a]
              for a in range(3)]
_JOINT_ROT = [k for k, op in enumerate(CHAIN) if op.joint is not None]
_JOINT_SLOT = np.array([CHAIN[k].slot if CHAIN[k].slot is not None else -1 for k in _JOINT_ROT])


def _op_rotations(x, q):
    """Per chain operation: its rotation, (3, 3) or (N, 3, 3), or None for a translation.

    Built with four vectorised calls (constant rotations by axis, then all joints), since
    per-operation calls dominate the cost for a few poses.
    """
    out = [None] * len(CHAIN)
    for axis, ks in enumerate(_CONST_ROT):
        mats = rot(axis, x[[CHAIN[k].slot for k in ks]])
        for k, M in zip(ks, mats):
            out[k] = M
    offsets = np.where(_JOINT_SLOT >= 0, x[np.maximum(_JOINT_SLOT, 0)], 0.0)
    mats = rot(2, q[:, [CHAIN[k].joint for k in _JOINT_ROT]] + offsets)  # (N, 6, 3, 3)
    for i, k in enumerate(_JOINT_ROT):
        out[k] = mats[:, i]
    return out


def forward_frames(x, q):
    """Frames before every chain operation and the final tool frame.

    Parameters
    ----------
    x : array_like, shape (37,)
        Slot values (mm, rad).
    q : array_like, shape (N, 6)
        Joint readings (rad).

    Returns
    -------
    R_before : ndarray, shape (K, N, 3, 3)
        World rotation of the frame before each of the K chain operations.
    p_before : ndarray, shape (K, N, 3)
        World origin of those frames (mm).
    T : ndarray, shape (N, 4, 4)
        Tool pose in the world frame.
    """
    x = _check_slots(x)
    q = check_joints(q)
    n = q.shape[0]
    R_before = np.empty((len(CHAIN), n, 3, 3))
    p_before = np.empty((len(CHAIN), n, 3))
    R = np.broadcast_to(np.eye(3), (n, 3, 3))
    p = np.zeros((n, 3))
    for k, (op, M) in enumerate(zip(CHAIN, _op_rotations(x, q))):
        R_before[k] = R
        p_before[k] = p
        if M is not None:
            R = R @ M
        else:
            p = p + R[:, :, op.axis] * x[op.slot]
    T = np.zeros((n, 4, 4))
    T[:, :3, :3] = R
    T[:, :3, 3] = p
    T[:, 3, 3] = 1.0
    return R_before, p_before, T


def forward(x, q) -> np.ndarray:
    """Tool poses ``(N, 4, 4)`` in the world frame for joint readings ``q`` (N, 6) rad."""
    x = _check_slots(x)
    q = check_joints(q)
    n = q.shape[0]
    R = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    p = np.zeros((n, 3))
    for op in CHAIN:
        value = x[op.slot] if op.slot is not None else 0.0
        if op.kind == "R":
            if op.joint is None:
                if value != 0.0:
                    R = R @ rot(op.axis, value)
            else:
                R = R @ rot(op.axis, value + q[:, op.joint])
        elif value != 0.0:
            p = p + R[:, :, op.axis] * value
    T = np.zeros((n, 4, 4))
    T[:, :3, :3] = R
    T[:, :3, 3] = p
    T[:, 3, 3] = 1.0
    return T


def tool_points(T, offsets) -> np.ndarray:
    """World positions ``(N, B, 3)`` of tool-frame points at poses ``T`` (N, 4, 4).

    ``offsets`` is ``(B, 3)`` (the same points at every pose) or ``(N, B, 3)`` (per pose).
    """
    offsets = np.asarray(offsets, dtype=float)
    if offsets.ndim == 3:
        return T[:, None, :3, 3] + np.einsum("nij,nbj->nbi", T[:, :3, :3], offsets)
    offsets = offsets.reshape(-1, 3)
    return T[:, None, :3, 3] + np.einsum("nij,bj->nbi", T[:, :3, :3], offsets)


@dataclass
class ChainJacobians:
    """Tool poses and their Jacobians at N joint readings.

    Attributes
    ----------
    T : ndarray, shape (N, 4, 4)
        Tool poses (mm).
    pose_slots : ndarray, shape (N, 6, 37)
        d[p; w] / d slots (mm per mm, mm per rad; rad per mm, rad per rad).
    pose_joints : ndarray, shape (N, 6, 6)
        d[p; w] / d q.
    points : ndarray, shape (N, B, 3) or None
        World positions of the requested tool-frame points.
    point_slots : ndarray, shape (N, B, 3, 37) or None
    point_joints : ndarray, shape (N, B, 3, 6) or None
    """

    T: np.ndarray
    pose_slots: np.ndarray
    pose_joints: np.ndarray
    points: np.ndarray | None = None
    point_slots: np.ndarray | None = None
    point_joints: np.ndarray | None = None


def jacobians(x, q, offsets=None) -> ChainJacobians:
    """Analytic Jacobians of the tool pose, and of tool-frame points, w.r.t. slots and joints.

    Parameters
    ----------
    x : array_like, shape (37,)
        Slot values (mm, rad).
    q : array_like, shape (N, 6)
        Joint readings (rad).
    offsets : array_like, shape (B, 3) or (N, B, 3), optional
        Tool-frame points (mm), for example ball centres: the same at every pose, or per pose.

    Returns
    -------
    ChainJacobians
    """
    R_before, p_before, T = forward_frames(x, q)
    n = T.shape[0]
    p_tool = T[:, :3, 3]
    # World direction of every operation's local axis: (K, N, 3).
    axes = R_before[np.arange(len(CHAIN)), :, :, _AXIS]
    rot_ops = _KIND_ROT[:, None, None]
    # A rotation moves a point by axis x (point - origin); a translation by the axis itself.
    d_pos = np.where(rot_ops, _cross(axes, p_tool[None] - p_before), axes)
    d_rot = np.where(rot_ops, axes, 0.0)
    d_pose = np.concatenate([d_pos, d_rot], axis=2)  # (K, N, 6)
    pose_slots = np.einsum("knr,ks->nrs", d_pose, _SLOT_MAP)
    pose_joints = np.einsum("knr,kj->nrj", d_pose, _JOINT_MAP)
    have_points = offsets is not None
    if have_points:
        offsets = np.asarray(offsets, dtype=float)
        offsets = offsets.reshape(-1, 3) if offsets.ndim < 3 else offsets
        if offsets.ndim == 3 and offsets.shape[0] != n:
            raise ValueError(f"per-pose offsets must have shape ({n}, B, 3), got {offsets.shape}")
        points = tool_points(T, offsets)
        d_pts = np.where(rot_ops[..., None], _cross(axes[:, :, None, :], points[None] - p_before[:, :, None, :]),
                         axes[:, :, None, :])  # (K, N, B, 3)
        point_slots = np.einsum("knbr,ks->nbrs", d_pts, _SLOT_MAP)
        point_joints = np.einsum("knbr,kj->nbrj", d_pts, _JOINT_MAP)
    out = ChainJacobians(T=T, pose_slots=pose_slots, pose_joints=pose_joints)
    if have_points:
        out.points, out.point_slots, out.point_joints = points, point_slots, point_joints
    return out
