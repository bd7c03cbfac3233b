"""The operation-by-operation walk of ``fgcal.robots.kinematics.Chain`` as it was before issue 25's
speed pass (one (N, 3, 3) product per operation, the screws of all operations stacked and gathered),
kept for tests and bench/bench_kinematics.py as the reference the faster walk must reproduce.

Functions take the :class:`~fgcal.robots.kinematics.Chain` whose operations they walk; shapes and
units as its methods'.
"""
from __future__ import annotations

import numpy as np

from fgcal.robots.chain_jacobians import ChainJacobians
from fgcal.robots.transforms import rot


def _cross(a, b) -> np.ndarray:
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _op_rotations(chain, x, v):
    out = [None] * len(chain.ops)
    const_rot = [[k for k, op in enumerate(chain.ops) if op.kind == "R" and op.joint is None and op.axis == a]
                 for a in range(3)]
    joint_rot = [k for k, op in enumerate(chain.ops) if op.kind == "R" and op.joint is not None]
    for axis, ks in enumerate(const_rot):
        if ks:
            for k, M in zip(ks, rot(axis, x[chain.slot_of_op[ks]])):
                out[k] = M
    if joint_rot:
        ks = joint_rot
        slots = chain.slot_of_op[ks]
        offsets = np.where(slots >= 0, x[np.maximum(slots, 0)], 0.0)
        mats = rot(2, v[:, chain.joint_of_op[ks]] + offsets)  # (N, J, 3, 3)
        for i, k in enumerate(ks):
            out[k] = mats[:, i]
    return out


def _translation(chain, k, x, v):
    op = chain.ops[k]
    value = x[op.slot] if op.slot is not None else 0.0
    if op.joint is not None:
        return (value + v[:, op.joint])[:, None]
    return value


def _homogeneous(R, p) -> np.ndarray:
    T = np.zeros((R.shape[0], 4, 4))
    T[:, :3, :3] = R
    T[:, :3, 3] = p
    T[:, 3, 3] = 1.0
    return T


def _finish(chain, T):
    return T if chain.tool_offset is None else T @ chain.tool_offset


def forward_frames(chain, x, q):
    """``(R_before (K, N, 3, 3), p_before (K, N, 3), T (N, 4, 4))``."""
    x = chain.check_slots(x)
    v = chain.joint_values(chain.check_joints(q))
    n = v.shape[0]
    K = len(chain.ops)
    R_before = np.empty((K, n, 3, 3))
    p_before = np.empty((K, n, 3))
    R = np.broadcast_to(np.eye(3), (n, 3, 3))
    p = np.zeros((n, 3))
    for k, M in enumerate(_op_rotations(chain, x, v)):
        R_before[k] = R
        p_before[k] = p
        if M is not None:
            R = R @ M
        else:
            p = p + R[:, :, chain.ops[k].axis] * _translation(chain, k, x, v)
    return R_before, p_before, _finish(chain, _homogeneous(R, p))


def forward(chain, x, q) -> np.ndarray:
    """Tool poses (N, 4, 4)."""
    x = chain.check_slots(x)
    v = chain.joint_values(chain.check_joints(q))
    n = v.shape[0]
    R = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    p = np.zeros((n, 3))
    for k, op in enumerate(chain.ops):
        if op.kind == "R":
            value = x[op.slot] if op.slot is not None else 0.0
            if op.joint is None:
                if value != 0.0:
                    R = R @ rot(op.axis, value)
            else:
                R = R @ rot(op.axis, value + v[:, op.joint])
        else:
            t = _translation(chain, k, x, v)
            if np.any(t != 0.0):
                p = p + R[:, :, op.axis] * t
    return _finish(chain, _homogeneous(R, p))


def tool_points(T, offsets) -> np.ndarray:
    """World positions (N, B, 3) of tool-frame points (B, 3) or (N, B, 3)."""
    offsets = np.asarray(offsets, dtype=float)
    if offsets.ndim == 3:
        return T[:, None, :3, 3] + np.einsum("nij,nbj->nbi", T[:, :3, :3], offsets)
    offsets = offsets.reshape(-1, 3)
    return T[:, None, :3, 3] + np.einsum("nij,bj->nbi", T[:, :3, :3], offsets)


def moved_points(J_pose, arm) -> np.ndarray:
    """Jacobians (N, B, 3, C) of tool points at ``arm`` (N, B, 3, 1) from the tool's (N, 6, C)."""
    dp, w = J_pose[:, None, :3, :], J_pose[:, None, 3:, :]
    a0, a1, a2 = arm[:, :, 0], arm[:, :, 1], arm[:, :, 2]
    w0, w1, w2 = w[:, :, 0], w[:, :, 1], w[:, :, 2]
    return dp + np.stack([w1 * a2 - w2 * a1, w2 * a0 - w0 * a2, w0 * a1 - w1 * a0], axis=2)


def jacobians_walk(chain, x, q, offsets=None) -> ChainJacobians:
    """The Jacobians of the tool pose and of tool points (:meth:`Chain.jacobians_walk`)."""
    R_before, p_before, T = forward_frames(chain, x, q)
    n = T.shape[0]
    p_tool = T[:, :3, 3]
    axes = R_before[np.arange(len(chain.ops)), :, :, chain.axis]  # (K, N, 3)
    rot_ops = chain.kind_rot[:, None, None]
    d_pos = np.where(rot_ops, _cross(axes, p_tool[None] - p_before), axes)
    d_rot = np.where(rot_ops, axes, 0.0)
    d_pose = np.concatenate([d_pos, d_rot], axis=2).transpose(1, 2, 0)  # (N, 6, K)
    slot_ops = np.array([k for k, op in enumerate(chain.ops) if op.slot is not None], dtype=int)
    joint_ops = np.array([k for k, op in enumerate(chain.ops) if op.joint is not None], dtype=int)
    pose_slots = np.zeros((n, 6, chain.n_slots))
    pose_slots[:, :, chain.slot_of_op[slot_ops]] = d_pose[:, :, slot_ops]
    pose_values = np.zeros((n, 6, chain.n_joints))
    pose_values[:, :, chain.joint_of_op[joint_ops]] = d_pose[:, :, joint_ops]
    pose_joints = pose_values if chain.joint_map is None else pose_values @ chain.joint_map
    out = ChainJacobians(T=T, pose_slots=pose_slots, pose_joints=pose_joints)
    if offsets is not None:
        offsets = np.asarray(offsets, dtype=float)
        offsets = offsets.reshape(-1, 3) if offsets.ndim < 3 else offsets
        points = tool_points(T, offsets)
        out.points = points
        arm = (points - p_tool[:, None, :])[..., None]
        out.point_slots = moved_points(pose_slots, arm)
        out.point_joints = moved_points(pose_joints, arm)
    return out
