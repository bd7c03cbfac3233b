"""Forward kinematics and analytic Jacobians of a serial chain, vectorised over many joint sets.

The chain ``T(r) = A_b L_1(v_1) ... L_{n-1}(v_{n-1}) J_n(v_n) A_t`` is a fixed sequence of
elementary operations (rotations about, or translations along, a local axis). Each operation
depends on at most one slot (a geometric parameter) and at most one joint variable. A revolute
link is ``Rz(v + theta) Tz(d) Tx(a) Rx(alpha) Ry(beta)``, a prismatic one
``Rz(theta) Tz(v + d) Tx(a) Rx(alpha) Ry(beta)``. Joint variables ``v`` come from the readings
``r`` by a fixed linear map ``v = M r + c`` (sign, scale, offset, coupling such as FANUC's J2/J3);
by default ``v = r``. Differentiating the chain through an operation is then a screw about (or
along) that operation's world axis, which gives exact Jacobians with no symbolic algebra.

Units: mm and rad (prismatic readings mm). Slot vectors have ``6 + 5 (n - 1) + 6`` entries
(37 for six joints) in :attr:`fgcal.robots.model.RobotModel.slot_names` order. Jacobians of a pose are
``(6, ·)``: rows ``[dp_x, dp_y, dp_z, w_x, w_y, w_z]``, the world-frame translation of the tool
origin and the world-frame rotation vector (``dR = [w]x R``), the paper's differential
displacement and orientation (eq. 17). Jacobians with respect to joints are with respect to the
readings. No I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from fgcal.robots.chain_jacobians import ChainJacobians
from fgcal.robots.chain_walk import (
    STACKED_MAX,
    WalkPlan,
    frame_points,
    homogeneous,
    point_slot_screws,
    projected_screws,
    screws,
    walk,
)
from fgcal.robots.single_pose import OperationTables, jacobians_one

__all__ = [
    "Chain",
    "ChainJacobians",
    "ChainOp",
    "chain_for",
    "check_joints",
    "default_chain",
    "forward",
    "forward_frames",
    "jacobians",
    "n_slots",
    "projected_point_jacobians",
    "tool_points",
]

REVOLUTE, PRISMATIC = "revolute", "prismatic"


@dataclass(frozen=True)
class ChainOp:
    """One elementary operation: ``kind`` 'R' (rotate) or 'T' (translate) about/along ``axis``."""

    kind: str
    axis: int
    slot: int | None
    joint: int | None


def n_slots(n_joints: int) -> int:
    """Number of geometric slots of an ``n_joints`` chain: base 6, 5 per link 1..n-1, tool 6."""
    return 12 + 5 * (n_joints - 1)


class Chain:
    """The operation sequence of a serial chain and the map from readings to joint variables.

    Parameters
    ----------
    joint_types : sequence of {"revolute", "prismatic"}, length n
    joint_map : ndarray, shape (n, n), optional
        ``M`` of ``v = M r + c``; identity by default.
    joint_offset : ndarray, shape (n,), optional
        ``c`` (rad or mm); zero by default.
    tool_offset : ndarray, shape (4, 4), optional
        A constant transform after the tool parameters (mm); identity by default.
    """

    def __init__(self, joint_types, joint_map=None, joint_offset=None, tool_offset=None):
        self.joint_types = tuple(str(t) for t in joint_types)
        bad = [t for t in self.joint_types if t not in (REVOLUTE, PRISMATIC)]
        if bad or not self.joint_types:
            raise ValueError(f"joint types must be 'revolute' or 'prismatic' (at least one), got {joint_types!r}")
        n = self.n_joints = len(self.joint_types)
        self.n_slots = n_slots(n)
        self.joint_map = None if joint_map is None else np.asarray(joint_map, dtype=float).reshape(n, n)
        self.joint_offset = None if joint_offset is None else np.asarray(joint_offset, dtype=float).reshape(n)
        if self.joint_map is not None and np.allclose(self.joint_map, np.eye(n), rtol=0, atol=0):
            self.joint_map = None
        if self.joint_offset is not None and not np.any(self.joint_offset):
            self.joint_offset = None
        # A constant transform after the tool's parameters (the user's tool frame where the
        # paper's Euler angles would be singular); not calibrated.
        self.tool_offset = None if tool_offset is None else np.asarray(tool_offset, dtype=float).reshape(4, 4)
        if self.tool_offset is not None and np.allclose(self.tool_offset, np.eye(4), rtol=0, atol=0):
            self.tool_offset = None
        ops = []
        ops += [ChainOp("R", 2, 0, None), ChainOp("R", 1, 1, None), ChainOp("R", 0, 2, None)]
        ops += [ChainOp("T", i, 3 + i, None) for i in range(3)]
        for k in range(n - 1):
            s = 6 + 5 * k  # theta, d, beta, a, alpha
            rev = self.joint_types[k] == REVOLUTE
            ops += [ChainOp("R", 2, s, k if rev else None), ChainOp("T", 2, s + 1, None if rev else k),
                    ChainOp("T", 0, s + 3, None), ChainOp("R", 0, s + 4, None), ChainOp("R", 1, s + 2, None)]
        ops.append(ChainOp("R" if self.joint_types[-1] == REVOLUTE else "T", 2, None, n - 1))
        t = self.n_slots - 6
        ops += [ChainOp("R", 2, t, None), ChainOp("R", 1, t + 1, None), ChainOp("R", 0, t + 2, None)]
        ops += [ChainOp("T", i, t + 3 + i, None) for i in range(3)]
        self.ops = tuple(ops)
        K = len(ops)
        self.kind_rot = np.array([op.kind == "R" for op in ops])
        self.axis = np.array([op.axis for op in ops])
        self.slot_of_op = np.array([-1 if op.slot is None else op.slot for op in ops])
        self.joint_of_op = np.array([-1 if op.joint is None else op.joint for op in ops])
        self.slot_map = np.zeros((K, self.n_slots))
        self.joint_op_map = np.zeros((K, n))
        for k, op in enumerate(ops):
            if op.slot is not None:
                self.slot_map[k, op.slot] = 1.0
            if op.joint is not None:
                self.joint_op_map[k, op.joint] = 1.0
        # The screws' scatters (fgcal.robots.chain_walk) need each slot and joint in one operation at most.
        slot_cols, joint_cols = self.slot_of_op[self.slot_of_op >= 0], self.joint_of_op[self.joint_of_op >= 0]
        assert len(set(slot_cols.tolist())) == len(slot_cols)
        assert len(set(joint_cols.tolist())) == len(joint_cols)
        self.walk_plan = WalkPlan(self)  # for N joint sets (fgcal.robots.chain_walk)
        self.single_pose = OperationTables(self)  # for one joint set (fgcal.robots.single_pose)

    def __repr__(self) -> str:
        return f"Chain({self.joint_types!r}, coupled={self.joint_map is not None})"

    # ------------------------------------------------------------------ checks and maps
    def check_slots(self, x) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        if x.shape != (self.n_slots,):
            raise ValueError(f"slot vector must have shape ({self.n_slots},) for {self.n_joints} joints, got {x.shape}")
        return x

    def check_joints(self, q) -> np.ndarray:
        """Convert joint readings to a float ``(N, n)`` array; raise with the expected shape."""
        q = np.asarray(q, dtype=float)
        if q.ndim == 1:
            q = q[None, :]
        if q.ndim != 2 or q.shape[1] != self.n_joints:
            raise ValueError(f"joint readings must have shape (N, {self.n_joints}) or ({self.n_joints},), "
                             f"got {np.shape(q)}")
        return q

    def joint_values(self, readings) -> np.ndarray:
        """Joint variables ``v = M r + c`` (N, n) of readings ``r`` (N, n)."""
        v = readings if self.joint_map is None else readings @ self.joint_map.T
        return v if self.joint_offset is None else v + self.joint_offset

    def readings_of(self, values) -> np.ndarray:
        """Readings ``r`` (N, n) that give joint variables ``values`` (inverse of :meth:`joint_values`)."""
        v = np.asarray(values, dtype=float)
        if self.joint_offset is not None:
            v = v - self.joint_offset
        return v if self.joint_map is None else np.linalg.solve(self.joint_map, v.T).T

    # ------------------------------------------------------------------ kinematics
    def forward_frames(self, x, q):
        """Frames before every operation and the final tool frame.

        Returns
        -------
        R_before : ndarray, shape (K, N, 3, 3)
        p_before : ndarray, shape (K, N, 3)
        T : ndarray, shape (N, 4, 4)
        """
        x = self.check_slots(x)
        v = self.joint_values(self.check_joints(q))
        frames, tool = walk(self, x, v, keep=True)
        n = v.shape[0]
        K = len(self.ops)
        R_before = np.empty((K, n, 3, 3))
        p_before = np.empty((K, n, 3))
        for k, (X, Y, Z, p) in enumerate(frames):
            R_before[k, :, :, 0], R_before[k, :, :, 1], R_before[k, :, :, 2], p_before[k] = X.T, Y.T, Z.T, p.T
        return R_before, p_before, homogeneous(tool)

    def forward(self, x, q) -> np.ndarray:
        """Tool poses ``(N, 4, 4)`` in the world frame for joint readings ``q`` (N, n)."""
        x = self.check_slots(x)
        _, tool = walk(self, x, self.joint_values(self.check_joints(q)), keep=False)
        return homogeneous(tool)

    def jacobians(self, x, q, offsets=None) -> ChainJacobians:
        """Analytic Jacobians of the tool pose, and of tool-frame points, w.r.t. slots and readings.

        Parameters
        ----------
        x : array_like, shape (S,)
            Slot values (mm, rad).
        q : array_like, shape (N, n)
            Joint readings (rad or mm).
        offsets : array_like, shape (B, 3) or (N, B, 3), optional
            Tool-frame points (mm), for example ball centres: the same at every pose, or per pose.
        """
        q = self.check_joints(q)
        if len(q) == 1 and (offsets is None or np.ndim(offsets) < 3 or np.shape(offsets)[0] == 1):
            return jacobians_one(self, self.check_slots(x), q, offsets)  # one pose: by a scan, not op by op
        return self.jacobians_walk(x, q, offsets)

    def jacobians_walk(self, x, q, offsets=None) -> ChainJacobians:
        """:meth:`jacobians` by walking the operations, vectorised over the poses (what
        :meth:`jacobians` does for more than one pose; :mod:`fgcal.robots.chain_walk`)."""
        x = self.check_slots(x)
        v = self.joint_values(self.check_joints(q))
        n = v.shape[0]
        if offsets is not None:
            offsets = np.asarray(offsets, dtype=float)
            offsets = offsets.reshape(-1, 3) if offsets.ndim < 3 else offsets
            if offsets.ndim == 3 and offsets.shape[0] != n:
                raise ValueError(f"per-pose offsets must have shape ({n}, B, 3), got {offsets.shape}")
        frames, tool = walk(self, x, v, keep=True)
        points = None if offsets is None else frame_points(tool, offsets)  # (B, 3, N)
        pose_slots, pose_values, point_slots, point_values = screws(self, frames, tool, points)
        out = ChainJacobians(T=homogeneous(tool), pose_slots=pose_slots, pose_joints=self._to_readings(pose_values))
        if points is not None:
            out.points = np.ascontiguousarray(points.transpose(2, 0, 1))
            out.point_slots, out.point_joints = point_slots, self._to_readings(point_values)
        return out

    def point_slot_jacobian(self, x, q, offsets, idx) -> np.ndarray:
        """The stacked Jacobian ``(N B 3, P)`` of tool-frame points ``offsets`` (B, 3) with respect
        to the slots ``idx`` (P,) at slots ``x`` (S,) and readings ``q`` (N, n): rows in the order
        pose, point, coordinate, as ``jacobians(x, q, offsets).point_slots[..., idx]`` stacked, the
        same numbers, without the pose and joint Jacobians (many poses: those cost most of it)."""
        x = self.check_slots(x)
        q = self.check_joints(q)
        offsets = np.asarray(offsets, dtype=float).reshape(-1, 3)
        idx = np.asarray(idx, dtype=int)
        n = q.shape[0]
        if len(self.walk_plan.rot_ops) * (1 + len(offsets)) * 3 * n <= STACKED_MAX:  # few poses: that path's roundings
            slots = self.jacobians(x, q, offsets).point_slots
            assert slots is not None  # points were given
            return slots[..., idx].reshape(-1, len(idx))
        frames, tool = walk(self, x, self.joint_values(q), keep=True)
        J = point_slot_screws(self, frames, frame_points(tool, offsets), idx)  # (P, B, 3, N)
        return np.ascontiguousarray(J.transpose(3, 1, 2, 0)).reshape(-1, len(idx))

    def projected_point_jacobians(self, x, q, offsets, directions):
        """Jacobians of one tool-frame point per pose along one world direction per pose, ``u . dp``
        (a plane contact's one row), without forming the ``(N, 3, S)`` point Jacobians.

        Parameters
        ----------
        x : array_like, shape (S,)
            Slot values (mm, rad).
        q : array_like, shape (N, n)
            Joint readings (rad or mm).
        offsets : array_like, shape (N, 3)
            The tool-frame point of each pose (mm).
        directions : array_like, shape (N, 3)
            The world direction ``u`` of each pose (a unit vector, for a distance along it).

        Returns
        -------
        points : ndarray, shape (N, 3)
            The points in the world (mm).
        along_slots : ndarray, shape (N, S)
            ``u . d point / d slots``.
        along_joints : ndarray, shape (N, n)
            ``u . d point / d readings``.
        """
        x = self.check_slots(x)
        q = self.check_joints(q)
        n = q.shape[0]
        offsets = np.asarray(offsets, dtype=float)
        directions = np.asarray(directions, dtype=float)
        for name, a in (("offsets", offsets), ("directions", directions)):
            if a.shape != (n, 3):
                raise ValueError(f"{name} must have shape ({n}, 3), one per pose, got {a.shape}")
        if n == 1:  # one pose (GTSAM's per-pose factors): the scan, then projected
            one = jacobians_one(self, x, q, offsets)
            u = directions[0]
            return one.points[:, 0], (u @ one.point_slots[0, 0])[None], (u @ one.point_joints[0, 0])[None]
        frames, tool = walk(self, x, self.joint_values(q), keep=True)
        points = frame_points(tool, offsets[:, None, :])[0]  # (3, N)
        along_slots, along_values = projected_screws(self, frames, points, np.ascontiguousarray(directions.T))
        return np.ascontiguousarray(points.T), along_slots, self._to_readings(along_values)

    def _to_readings(self, J_values):
        """Chain rule from joint variables to readings: ``dv/dr = M``."""
        return J_values if self.joint_map is None else J_values @ self.joint_map


@lru_cache(maxsize=64)
def _all_revolute(n: int) -> Chain:
    return Chain((REVOLUTE,) * n)


def default_chain(n_joints: int = 6) -> Chain:
    """The all-revolute, uncoupled chain of ``n_joints`` joints (the built-in robots' kind)."""
    return _all_revolute(int(n_joints))


def chain_for(x, chain: Chain | None = None) -> Chain:
    """``chain``, or the all-revolute uncoupled chain whose slot count matches ``x``."""
    if chain is not None:
        return chain
    size = np.shape(x)[0] if np.ndim(x) else 0
    if size < 12 or (size - 12) % 5:
        raise ValueError(f"slot vector of shape ({size},) fits no chain: expected (12 + 5 (n - 1),), "
                         "for example (37,) for 6 joints")
    return default_chain((size - 12) // 5 + 1)


def check_joints(q, n_joints: int = 6) -> np.ndarray:
    """Convert joint readings to a float ``(N, n_joints)`` array; raise with the expected shape."""
    return default_chain(n_joints).check_joints(q)


def forward_frames(x, q, chain: Chain | None = None):
    """See :meth:`Chain.forward_frames`; ``chain`` defaults to the all-revolute chain of ``x``."""
    return chain_for(x, chain).forward_frames(x, q)


def forward(x, q, chain: Chain | None = None) -> np.ndarray:
    """Tool poses ``(N, 4, 4)``; see :meth:`Chain.forward`."""
    return chain_for(x, chain).forward(x, q)


def tool_points(T, offsets) -> np.ndarray:
    """World positions ``(N, B, 3)`` of tool-frame points at poses ``T`` (N, 4, 4).

    ``offsets`` is ``(B, 3)`` (the same points at every pose) or ``(N, B, 3)`` (per pose).
    """
    offsets = np.asarray(offsets, dtype=float)
    if offsets.ndim == 3:
        return T[:, None, :3, 3] + np.einsum("nij,nbj->nbi", T[:, :3, :3], offsets)
    o = offsets.reshape(-1, 3)[None]  # (1, B, 3): the same at every pose, by columns (einsum loops slower here)
    T = np.asarray(T, dtype=float)
    return (T[:, None, :3, 3] + T[:, None, :3, 0] * o[..., 0:1] + T[:, None, :3, 1] * o[..., 1:2]
            + T[:, None, :3, 2] * o[..., 2:3])


def projected_point_jacobians(x, q, offsets, directions, chain: Chain | None = None):
    """See :meth:`Chain.projected_point_jacobians`; ``chain`` defaults to the all-revolute chain of ``x``."""
    return chain_for(x, chain).projected_point_jacobians(x, q, offsets, directions)


def jacobians(x, q, offsets=None, chain: Chain | None = None) -> ChainJacobians:
    """See :meth:`Chain.jacobians`; ``chain`` defaults to the all-revolute chain of ``x``."""
    return chain_for(x, chain).jacobians(x, q, offsets)
