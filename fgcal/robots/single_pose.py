"""Forward kinematics and Jacobians of one joint set, for the callers that take one pose at a time
(the online engines, GTSAM's per-pose factors, inverse kinematics).

:class:`~fgcal.robots.kinematics.Chain` walks its operations one by one, vectorised over the poses
(:mod:`fgcal.robots.chain_walk`): for a single pose that is ~40 steps of numpy calls on 3-vectors,
dominated by call overhead.
Here every operation becomes a 4x4 matrix at once, and the frames before each operation are the
running products of those matrices, formed by a scan of ``ceil(log2 K)`` batched products. The
results are those of :meth:`Chain.jacobians` up to rounding (the products are associated
differently: ~1e-13 relative). Units and shapes as there. No I/O here.
"""
from __future__ import annotations

import numpy as np

from fgcal.robots.chain_jacobians import ChainJacobians

__all__ = ["OperationTables", "jacobians_one"]

_EYE4 = np.eye(4)
# (a x P)_i = sum_j a_j C[j, i], C[j, i] = sum_l P_l _SKEW[l, 3 j + i]: C = [[0, -P2, P1], [P2, 0, -P0], [-P1, P0, 0]]
_SKEW = np.zeros((3, 9))
for _l, _j, _i, _sign in ((2, 0, 1, -1), (1, 0, 2, 1), (2, 1, 0, 1), (0, 1, 2, -1), (1, 2, 0, -1), (0, 2, 1, 1)):
    _SKEW[_l, 3 * _j + _i] = _sign


class OperationTables:
    """Where each operation's values go in the (K + 1, 16) flat frames (row 0 the identity), built once per
    chain (:attr:`Chain.single_pose`); the rest (kinds, axes, slot and joint maps) is the chain's.

    Attributes
    ----------
    rot_ops, trans_ops : ndarray of int
        The rotations and the translations among the K operations.
    cos_a, cos_b, minus_sin, plus_sin : ndarray of int, shape (len(rot_ops),)
        Flat indices of each rotation's cosines and sines.
    shift : ndarray of int, shape (len(trans_ops),)
        Flat index of each translation's value.
    """

    def __init__(self, chain):
        axis = chain.axis
        r = np.flatnonzero(chain.kind_rot)
        t = np.flatnonzero(~chain.kind_rot)
        self.rot_ops, self.trans_ops = r, t
        i = (axis[r] + 1) % 3  # a rotation about axis a mixes the two other axes i, j
        j = (axis[r] + 2) % 3
        self.cos_a, self.cos_b = r * 16 + i * 5, r * 16 + j * 5
        self.minus_sin, self.plus_sin = r * 16 + i * 4 + j, r * 16 + j * 4 + i
        self.shift = t * 16 + axis[t] * 4 + 3
        K = len(chain.ops)
        # the frames with the identity before the first operation: (K + 1, 16), row k + 1 after op k
        self.identity = np.zeros((K + 1, 16))
        self.identity[:, [0, 5, 10, 15]] = 1.0
        self.ops = np.arange(K)
        # every value's flat index in rows 1.. (a rotation's cos, cos, -sin, sin; a translation's shift)
        self.put_at = 16 + np.concatenate([self.cos_a, self.cos_b, self.minus_sin, self.plus_sin, self.shift])
        self.slot_and_joint = np.hstack([chain.slot_map, chain.joint_op_map])  # (K, S + n): each op's slot, joint


def _frames(chain, x, v):
    """``(B (K, 4, 4), T (4, 4))``: the frame before each operation and the tool frame."""
    tb = chain.single_pose
    K = len(chain.ops)
    value = chain.slot_map @ x + chain.joint_op_map @ v  # each op's slot plus its joint variable
    angle = value[tb.rot_ops]
    c, s = np.cos(angle), np.sin(angle)
    M = tb.identity.copy()
    M.reshape(-1)[tb.put_at] = np.concatenate([c, c, -s, s, value[tb.trans_ops]])
    F = M.reshape(K + 1, 4, 4)
    shift = 1
    while shift < K:  # inclusive scan over rows 1..K: F[k] = M[1] ... M[k]
        F[shift + 1:] = np.matmul(F[1:-shift], F[shift + 1:])
        shift *= 2
    T = F[K] if chain.tool_offset is None else F[K] @ chain.tool_offset
    return F[:K], T  # row 0 the identity: the frame before op k is row k


def jacobians_one(chain, x, readings, offsets=None):
    """:meth:`Chain.jacobians` at one joint set ``readings`` (n,) or (1, n); the same
    :class:`~fgcal.robots.chain_jacobians.ChainJacobians` (leading dimension 1).

    ``offsets``: tool-frame points (B, 3) or (1, B, 3), mm.
    """
    v = chain.joint_values(np.asarray(readings, dtype=float).reshape(1, -1))[0]
    B, T = _frames(chain, x, v)
    K = len(chain.ops)
    axes = B[chain.single_pose.ops, :3, chain.axis]  # (K, 3) world axis of each operation
    origins = B[:, :3, 3]
    offsets = np.zeros((0, 3)) if offsets is None else np.asarray(offsets, dtype=float).reshape(-1, 3)
    n_pts = len(offsets)
    points = np.empty((n_pts + 1, 3))  # the tool origin, then the points
    points[0] = T[:3, 3]
    points[1:] = T[:3, 3] + offsets @ T[:3, :3].T
    # A rotation moves a point P by a x (P - o) = a x P - a x o; a translation by a itself.
    # (a x P)_i = sum_j a_j C[j, i] with C = [[0, -P2, P1], [P2, 0, -P0], [-P1, P0, 0]] = P . _SKEW, per point
    cross_p = (points @ _SKEW).reshape(n_pts + 1, 3, 3).transpose(1, 0, 2).reshape(3, -1)
    moment = np.einsum("kj,kji->ki", axes, (origins @ _SKEW).reshape(K, 3, 3))  # axes x origins
    d = (axes @ cross_p).reshape(K, n_pts + 1, 3) - moment[:, None, :]
    rot = chain.kind_rot
    d = np.where(rot[:, None, None], d, axes[:, None, :])
    rows = np.concatenate([d[:, 0], np.where(rot[:, None], axes, 0.0), d[:, 1:].reshape(K, -1)], axis=1).T
    both = rows @ chain.single_pose.slot_and_joint  # (6 + 3B, S + n)
    by_slot = both[:, :chain.n_slots]  # (6 + 3B, S)
    by_joint = chain._to_readings(both[:, chain.n_slots:])  # (6 + 3B, n)
    out = ChainJacobians(T=T[None], pose_slots=by_slot[None, :6], pose_joints=by_joint[None, :6])
    if n_pts:
        out.points = points[None, 1:]
        out.point_slots = by_slot[6:].reshape(1, n_pts, 3, -1)
        out.point_joints = by_joint[6:].reshape(1, n_pts, 3, -1)
    return out
