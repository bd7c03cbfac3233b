"""The walk of a chain's operations vectorised over N poses, by frame columns (what
:class:`~fgcal.robots.kinematics.Chain` computes its batch kinematics with).

A frame is kept as its three world axes ``X, Y, Z`` and its origin ``p``, each a ``(3, N)`` array
(component-major: each row is contiguous), or ``(3, 1)`` while no joint has entered (the base's
operations are the same at every pose). A rotation about a local axis by an angle of cosine ``c``
and sine ``s`` mixes the two other columns (``R @ Rz`` is ``[c X + s Y, c Y - s X, Z]``), a few
element-wise products, not an ``(N, 3, 3) @ (3, 3)`` product; a translation adds its value times
one column to the origin. Nothing is updated in place, so the frames before the operations are
references to arrays the walk makes anyway.

The screw of an operation (its Jacobian column, :mod:`fgcal.robots.kinematics`) is ``[a x (p_tool -
o); a]`` for a rotation about the world axis ``a`` through ``o``, ``[a; 0]`` for a translation; a
tool point's column is ``a x (point - o)`` or ``a``. They are written one column at a time into the
output arrays: every temporary is ``(3, N)``, since a fresh array of the outputs' size costs more in
page faults than the vectorised products over all operations save. Rotations with no translation
between them share their origin (one arm per run). Units mm, rad; no I/O here.
"""
from __future__ import annotations

import numpy as np

__all__ = ["Frame", "WalkPlan", "frame_points", "homogeneous", "point_slot_screws", "projected_screws", "screws", "walk"]

Frame = tuple  # (X, Y, Z, p): world axes and origin, each (3, N), or (3, 1) while the same at every pose
_UNIT = np.eye(3)[:, :, None]  # the world axes as (3, 1) columns
_OTHER = ((1, 2), (2, 0), (0, 1))  # the two columns a rotation about axis 0, 1, 2 mixes
_NEXT, _PREV = [1, 2, 0], [2, 0, 1]  # the cross product's cyclic row orders
# Up to this many numbers in the (R, 1 + B, 3, N) arrays of all rotations' screws, they are formed at
# once (few poses: fewer numpy calls); beyond, column by column (fresh arrays that large cost more in
# page faults than the calls they save).
STACKED_MAX = 16384


class WalkPlan:
    """Index tables of a chain's walk, built once per chain (``Chain.walk_plan``).

    Attributes
    ----------
    slot_ops : ndarray of int
        The operations that take a slot.
    joint_rot_ops, joint_rot_joints, joint_rot_slots : ndarray of int
        The rotations a joint variable turns, that joint, and the slot added to it (-1: none).
    turned : dict
        The row of each of ``joint_rot_ops`` in the joint angles.
    steps : tuple of (is_rotation, axis, slot or None, joint or None), one per operation
    rot_ops, trans_ops : ndarray of int
        The rotations and the translations.
    origin_runs : list of (start, stop, op)
        Runs of positions in ``rot_ops`` with no translation between them: one origin, that of ``op``.
    rot_slots, rot_joints, trans_slots, trans_joints : (ndarray, ndarray)
        Positions in ``rot_ops`` or ``trans_ops`` of those that take a slot or a joint, and which.
    """

    def __init__(self, chain):
        ops = chain.ops
        self.slot_ops = np.array([k for k, op in enumerate(ops) if op.slot is not None], dtype=int)
        self.joint_rot_ops = np.array([k for k, op in enumerate(ops) if op.kind == "R" and op.joint is not None],
                                      dtype=int)
        self.joint_rot_joints = chain.joint_of_op[self.joint_rot_ops]
        self.joint_rot_slots = chain.slot_of_op[self.joint_rot_ops]
        self.turned = {int(k): i for i, k in enumerate(self.joint_rot_ops)}
        self.steps = tuple((op.kind == "R", op.axis, op.slot, op.joint) for op in ops)
        # For few poses, the screws of all rotations at once (:func:`_stacked_screws`).
        rot = chain.kind_rot
        self.rot_ops, self.trans_ops = np.flatnonzero(rot), np.flatnonzero(~rot)
        moved = np.cumsum(~rot)[self.rot_ops]  # translations before each rotation: which origin it has
        starts = [0] + [i for i in range(1, len(self.rot_ops)) if moved[i] != moved[i - 1]]
        self.origin_runs = [(a, b, int(self.rot_ops[a])) for a, b in zip(starts, starts[1:] + [len(self.rot_ops)])]
        self.rot_slots = _columns(self.rot_ops, chain.slot_of_op)
        self.rot_joints = _columns(self.rot_ops, chain.joint_of_op)
        self.trans_slots = _columns(self.trans_ops, chain.slot_of_op)
        self.trans_joints = _columns(self.trans_ops, chain.joint_of_op)


def _columns(ops, column_of_op):
    """``(positions in ops, columns)`` of the operations of ``ops`` that have a column (slot or joint)."""
    cols = column_of_op[ops]
    at = np.flatnonzero(cols >= 0)
    return at, cols[at]


def walk(chain, x, v, keep: bool):
    """Walk the operations at slot values ``x`` (S,) and joint variables ``v`` (N, n).

    Returns
    -------
    frames : list of Frame, length K, or None
        The frame before each operation (if ``keep``).
    tool : Frame
        The frame after the last operation and the chain's ``tool_offset``, ``(3, N)`` arrays.
    """
    plan = chain.walk_plan
    value = np.zeros(len(chain.ops))
    value[plan.slot_ops] = x[chain.slot_of_op[plan.slot_ops]]
    const_cos, const_sin = np.cos(value).tolist(), np.sin(value).tolist()
    values = value.tolist()
    readings = np.ascontiguousarray(v.T)  # (n, N): a joint's values in one row
    angles = readings[plan.joint_rot_joints]
    if len(plan.joint_rot_ops):
        angles = angles + np.where(plan.joint_rot_slots >= 0, x[np.maximum(plan.joint_rot_slots, 0)], 0.0)[:, None]
    cos, sin = np.cos(angles), np.sin(angles)
    cols = [_UNIT[0], _UNIT[1], _UNIT[2]]
    p = np.zeros((3, 1))
    frames: list | None = [] if keep else None
    for k, (rotation, axis, _, joint) in enumerate(plan.steps):
        if frames is not None:
            frames.append((cols[0], cols[1], cols[2], p))
        if rotation:
            if joint is None:
                c, s = const_cos[k], const_sin[k]
                if s == 0.0 and c == 1.0:
                    continue  # exactly the identity
            else:
                i = plan.turned[k]
                c, s = cos[i], sin[i]
            a, b = _OTHER[axis]
            ca, cb = cols[a], cols[b]
            cols[a], cols[b] = c * ca + s * cb, c * cb - s * ca
        else:
            t = values[k]
            if joint is not None:
                p = p + (t + readings[joint]) * cols[axis]
            elif t != 0.0:
                p = p + t * cols[axis]
    X, Y, Z = cols
    if chain.tool_offset is not None:
        M, o = chain.tool_offset[:3, :3], chain.tool_offset[:3, 3]
        p = p + (X * o[0] + Y * o[1] + Z * o[2])
        X, Y, Z = (X * M[0, j] + Y * M[1, j] + Z * M[2, j] for j in range(3))
    n = v.shape[0]
    tool = tuple(np.broadcast_to(c, (3, n)) for c in (X, Y, Z, p))
    return frames, tool


def homogeneous(frame: Frame) -> np.ndarray:
    """``(N, 4, 4)`` transforms of a frame of ``(3, N)`` columns."""
    X, Y, Z, p = frame
    T = np.empty((p.shape[1], 4, 4))
    T[:, :3, 0], T[:, :3, 1], T[:, :3, 2], T[:, :3, 3] = X.T, Y.T, Z.T, p.T
    T[:, 3, :3] = 0.0
    T[:, 3, 3] = 1.0
    return T


def frame_points(frame: Frame, offsets) -> np.ndarray:
    """World positions ``(B, 3, N)`` of points ``offsets`` (B, 3) or (N, B, 3) of a frame of ``(3, N)``
    columns (mm)."""
    o = offsets[:, :, None] if offsets.ndim == 2 else offsets.transpose(1, 2, 0)  # (B, 3, 1 or N)
    X, Y, Z, p = frame
    return p + X * o[:, 0:1] + Y * o[:, 1:2] + Z * o[:, 2:3]


def _cross(a, b_next, b_prev, out, tmp):
    """``out`` = a x b for columns ``a`` (3, N) or (3, 1) and ``b`` given as its rows rolled,
    ``b_next = b[[1, 2, 0]]`` and ``b_prev = b[[2, 0, 1]]`` (..., 3, N): ``a[[1, 2, 0]] b_prev -
    a[[2, 0, 1]] b_next``, the products written out (the same roundings)."""
    np.multiply(a[_NEXT], b_prev, out=out)
    np.multiply(a[_PREV], b_next, out=tmp)
    out -= tmp


def _rolled(b):
    return b[..., _NEXT, :], b[..., _PREV, :]


def screws(chain, frames, tool: Frame, points=None):
    """The Jacobians of the tool pose and of world points on the tool, written column by column
    straight into their arrays.

    Parameters
    ----------
    frames, tool : from :func:`walk`
    points : ndarray, shape (B, 3, N), optional
        World positions of tool points (:func:`frame_points`).

    Returns
    -------
    pose_slots : (N, 6, S); pose_values : (N, 6, n) w.r.t. the joint variables;
    point_slots : (N, B, 3, S) and point_values : (N, B, 3, n), or None without ``points``.
    """
    p_tool = tool[3]
    n = p_tool.shape[1]
    B = 0 if points is None else points.shape[0]
    pose_slots = np.empty((n, 6, chain.n_slots))
    pose_values = np.zeros((n, 6, chain.n_joints))
    point_slots = np.empty((n, B, 3, chain.n_slots))
    point_values = np.zeros((n, B, 3, chain.n_joints))
    # The tool origin and the points at once: a rotation moves each by a x (it - o).
    tracked = p_tool[None] if points is None else np.concatenate([p_tool[None], points])  # (1 + B, 3, N)
    out = (pose_slots, pose_values, point_slots, point_values)
    if len(chain.walk_plan.rot_ops) * tracked.size <= STACKED_MAX:
        _stacked_screws(chain, frames, tracked, *out)
    else:
        _column_screws(chain, frames, tracked, *out)
    return out if B else (pose_slots, pose_values, None, None)


def _column_screws(chain, frames, tracked, pose_slots, pose_values, point_slots, point_values):
    """:func:`screws` one operation at a time, each column written straight into the outputs."""
    B, _, n = tracked.shape
    B -= 1
    moved, tmp = np.empty((1 + B, 3, n)), np.empty((1 + B, 3, n))
    pose_moved, points_moved = moved[0].T, moved[1:].transpose(2, 0, 1)  # (N, 3), (N, B, 3): the outputs' columns
    origin = None
    arm = (tmp, tmp)
    for k, (rotation, axis, s, j) in enumerate(chain.walk_plan.steps):
        frame = frames[k]
        a = frame[axis]
        if rotation:
            if frame[3] is not origin:  # rotations with no translation between them share their origin
                origin = frame[3]
                arm = _rolled(tracked - origin)
            _cross(a, arm[0], arm[1], moved, tmp)
            for J, P, c in ((pose_slots, point_slots, s), (pose_values, point_values, j)):
                if c is not None:
                    J[:, :3, c] = pose_moved
                    J[:, 3:, c] = a.T
                    if B:
                        P[:, :, :, c] = points_moved
        else:
            if s is not None:
                pose_slots[:, :3, s] = a.T
                pose_slots[:, 3:, s] = 0.0
                if B:
                    point_slots[:, :, :, s] = a.T[:, None, :]
            if j is not None:
                pose_values[:, :3, j] = a.T
                if B:
                    point_values[:, :, :, j] = a.T[:, None, :]


def _stacked_screws(chain, frames, tracked, pose_slots, pose_values, point_slots, point_values):
    """:func:`screws` for all rotations at once on ``(R, 1 + B, 3, N)`` arrays (few poses: fewer calls)."""
    plan = chain.walk_plan
    axis = chain.axis
    A = np.empty((len(plan.rot_ops), 1, 3, tracked.shape[2]))  # each rotation's world axis
    for i, k in enumerate(plan.rot_ops):
        A[i, 0] = frames[k][axis[k]]
    arm = np.empty((len(plan.rot_ops),) + tracked.shape)
    for a, b, k in plan.origin_runs:
        arm[a:b] = tracked - frames[k][3]
    moved = A[:, :, _NEXT] * arm[:, :, _PREV]
    moved -= A[:, :, _PREV] * arm[:, :, _NEXT]  # (R, 1 + B, 3, N): a x (it - o)
    shift = np.empty((len(plan.trans_ops), 3, tracked.shape[2]))  # each translation's world axis
    for i, k in enumerate(plan.trans_ops):
        shift[i] = frames[k][axis[k]]
    for J, P, (at, cols) in ((pose_slots, point_slots, plan.rot_slots), (pose_values, point_values, plan.rot_joints)):
        J[:, :3, cols] = moved[at, 0].transpose(2, 1, 0)
        J[:, 3:, cols] = A[at, 0].transpose(2, 1, 0)
        P[:, :, :, cols] = moved[at, 1:].transpose(3, 1, 2, 0)
    for J, P, (at, cols) in ((pose_slots, point_slots, plan.trans_slots),
                             (pose_values, point_values, plan.trans_joints)):
        J[:, :3, cols] = shift[at].transpose(2, 1, 0)
        J[:, 3:, cols] = 0.0
        P[:, :, :, cols] = shift[at].transpose(2, 1, 0)[:, None]


def projected_screws(chain, frames, points, directions):
    """The Jacobians of one world point per pose along a world direction per pose, ``u . dp``,
    without the point Jacobians: a rotation about ``a`` through ``o`` gives ``a . ((p - o) x u)``
    (the cross product once per origin), a translation along ``a`` gives ``a . u``.

    Parameters
    ----------
    frames : from :func:`walk`
    points, directions : ndarray, shape (3, N)
        The points (mm) and the unit directions ``u``.

    Returns
    -------
    along_slots : ndarray, shape (N, S)
    along_values : ndarray, shape (N, n)
        w.r.t. the joint variables.
    """
    n = points.shape[1]
    along_slots = np.empty((n, chain.n_slots))
    along_values = np.zeros((n, chain.n_joints))
    u_next, u_prev = _rolled(directions)
    lever, tmp = np.empty((3, n)), np.empty((3, n))
    origin = None
    for k, (rotation, axis, s, j) in enumerate(chain.walk_plan.steps):
        frame = frames[k]
        if rotation:
            if frame[3] is not origin:
                origin = frame[3]
                _cross(points - origin, u_next, u_prev, lever, tmp)  # (p - o) x u
            value = np.einsum("in,in->n", np.broadcast_to(frame[axis], (3, n)), lever)
        else:
            value = np.einsum("in,in->n", np.broadcast_to(frame[axis], (3, n)), directions)
        if s is not None:
            along_slots[:, s] = value
        if j is not None:
            along_values[:, j] = value
    return along_slots, along_values


def point_slot_screws(chain, frames, points, slots) -> np.ndarray:
    """The Jacobians of world points on the tool with respect to the slots ``slots`` (P,) only,
    slot-major: ``(P, B, 3, N)``, each slot's block written once, contiguous (no pose Jacobians,
    no joint columns, no ``(N, ..., S)`` arrays written column by column).

    The same products as :func:`_column_screws`' point columns (the same roundings).

    Parameters
    ----------
    frames : from :func:`walk`
    points : ndarray, shape (B, 3, N)
        World positions of the tool points (:func:`frame_points`).
    slots : ndarray of int, shape (P,)
    """
    B, _, n = points.shape
    out = np.zeros((len(slots),) + points.shape)
    where: dict[int, list[int]] = {}
    for i, s in enumerate(np.asarray(slots, dtype=int).tolist()):
        where.setdefault(s, []).append(i)
    moved, tmp = np.empty((B, 3, n)), np.empty((B, 3, n))
    origin = None
    arm = (tmp, tmp)
    for k, (rotation, axis, s, _) in enumerate(chain.walk_plan.steps):
        if s is None or s not in where:
            continue
        frame = frames[k]
        a = frame[axis]
        if rotation:
            if frame[3] is not origin:
                origin = frame[3]
                arm = _rolled(points - origin)
            _cross(a, arm[0], arm[1], moved, tmp)
            for i in where[s]:
                out[i] = moved
        else:
            for i in where[s]:
                out[i] = a[None]
    return out
