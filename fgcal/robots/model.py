"""The kinematic model of a serial arm of n joints in the paper's convention, and its parameters.

Frames: world -> base -> links 1..n -> tool (DESIGN.md section 1, generalised)::

    A_b = Rz(phi) Ry(theta) Rx(psi) Trans(px, py, pz)
    A_k = Rz(v_k + theta_k) Tz(d_k) Tx(a_k) Rx(alpha_k) Ry(beta_k)   revolute, k = 1..n-1
    A_k = Rz(theta_k) Tz(v_k + d_k) Tx(a_k) Rx(alpha_k) Ry(beta_k)   prismatic
    A_t = Rz(phi) Ry(theta) Rx(psi) Trans(px, py, pz)                after the last joint's motion
    T(r) = A_b A_1 ... A_{n-1} Rz(v_n) A_t         (Tz(v_n) for a prismatic last joint)

with joint variables ``v = M r + c`` from the readings ``r`` (identity by default; a coupling such
as FANUC's J2/J3 otherwise). Every geometric quantity of this chain is a *slot*
(``12 + 5 (n - 1)``: 37 for six joints). The identifiable parameters are a subset of the slots,
derived from the nominal geometry by the paper's rule (theta_1 and d_1 absorbed by the base, link
n by the tool, beta_k in place of d_k where axes k and k+1 are nominally parallel) and checked by
the rank of the identification Jacobian. Slots that are not parameters are held at their nominal
values. Slot names are ``base.*``, ``LINK.*`` (``j1`` .. for the built-ins, the joint names of an
imported URDF) and ``tool.*``.

Internally lengths are millimetres and angles radians; files and reports use degrees.
This module does no I/O.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum
from functools import cached_property

import numpy as np

from fgcal.robots.jacobian_rank import minimal_parameters
from fgcal.robots.transforms import euler_zyx_trans, to_euler_zyx_trans

__all__ = ["SLOT_IS_ANGLE", "SLOT_NAMES", "JointType", "ParameterSet", "RobotModel", "Tooling", "slot_names_for"]

EULER_FIELDS = ("phi", "theta", "psi", "px", "py", "pz")
LINK_FIELDS = ("theta", "d", "beta", "a", "alpha")
N_JOINTS = 6
N_LINKS_IN_CHAIN = 5  # link 6 is absorbed by the tool
_ANGLE_FIELDS = {"phi", "theta", "psi", "alpha", "beta"}


class JointType(str, Enum):
    """How a joint moves: about its z axis (revolute, readings in deg) or along it (prismatic, mm)."""

    REVOLUTE = "revolute"
    PRISMATIC = "prismatic"


def slot_names_for(link_names) -> tuple[str, ...]:
    """Slot names of a chain whose links 1..n-1 are called ``link_names`` (``j1``.. by default)."""
    return (tuple(f"base.{f}" for f in EULER_FIELDS) + tuple(f"{j}.{f}" for j in link_names for f in LINK_FIELDS)
            + tuple(f"tool.{f}" for f in EULER_FIELDS))


def slot_is_angle(names) -> np.ndarray:
    """``(S,)`` bool: the slot is an angle (rad inside, deg in files)."""
    return np.array([name.rsplit(".", 1)[1] in _ANGLE_FIELDS for name in names])


SLOT_NAMES: tuple[str, ...] = slot_names_for([f"j{n}" for n in range(1, N_LINKS_IN_CHAIN + 1)])
SLOT_INDEX = {name: i for i, name in enumerate(SLOT_NAMES)}
SLOT_IS_ANGLE = slot_is_angle(SLOT_NAMES)


def slot(name: str) -> int:
    """Index of the 6R chain's slot ``name`` (for example ``"j2.beta"``); ``KeyError`` if unknown."""
    try:
        return SLOT_INDEX[name]
    except KeyError:
        raise KeyError(f"unknown kinematic parameter {name!r}; known: {', '.join(SLOT_NAMES)}") from None


@dataclass(frozen=True)
class Tooling:
    """The calibration tool: tooling balls carried by the end-effector.

    Attributes
    ----------
    radius : float
        Ball radius (mm).
    balls : dict of str to ndarray, shape (3,)
        Ball centres in the tool frame (mm).
    """

    radius: float
    balls: dict[str, np.ndarray]

    @property
    def names(self) -> list[str]:
        return list(self.balls)

    def offsets(self, names=None) -> np.ndarray:
        """Tool-frame centres ``(B, 3)`` (mm) of the named balls (all, in order, by default)."""
        names = self.names if names is None else names
        return np.array([self.balls[n] for n in names], dtype=float).reshape(-1, 3)


@dataclass(frozen=True)
class RobotModel:
    """Nominal geometry, joints and measuring set-up of a serial arm of n joints.

    Attributes
    ----------
    name : str
        Model name (``puma560``, ``ur10``, ... or a file's own name).
    nominal : ndarray, shape (S,)
        Nominal slot values in :attr:`slot_names` order (mm, rad); ``S = 12 + 5 (n - 1)``.
    joint_limits : ndarray, shape (n, 2)
        Lower and upper joint limits on the readings (rad; mm for prismatic joints).
    tooling : Tooling or None
        Default calibration tool (balls), if the model file has one.
    volume : ndarray, shape (2, 3) or None
        Measuring volume in world coordinates, ``[min, max]`` (mm).
    paper_box : ndarray, shape (2, 3) or None
        Parallelepiped for the paper's 48-pose plan, ``[min, max]`` (mm, world).
    description : str
    joint_types : tuple of JointType, length n
        Revolute by default.
    link_names : tuple of str, length n - 1
        Prefixes of the link slots (``j1`` .. ``j{n-1}`` by default; a URDF's joint names).
    joint_names : tuple of str, length n
        The actuated joints' names (``q1`` .. ``qn`` by default), for messages and exports.
    joint_map, joint_offset : ndarray, shapes (n, n) and (n,), or None
        Joint variables from readings, ``v = joint_map r + joint_offset`` (coupling, sign, scale).
    tool_offset : ndarray, shape (4, 4), or None
        A constant transform after the tool parameters (mm): the user's tool frame where the
        paper's ZYX Euler angles of the tool would be singular. Not calibrated.
    extra : dict
        Format-specific data that travels with the model (an imported URDF, inertials).
    """

    name: str
    nominal: np.ndarray
    joint_limits: np.ndarray
    tooling: Tooling | None = None
    volume: np.ndarray | None = None
    paper_box: np.ndarray | None = None
    description: str = ""
    extra: dict = field(default_factory=dict)
    joint_types: tuple = ()
    link_names: tuple = ()
    joint_names: tuple = ()
    joint_map: np.ndarray | None = None
    joint_offset: np.ndarray | None = None
    tool_offset: np.ndarray | None = None

    def __post_init__(self):
        limits = np.asarray(self.joint_limits, dtype=float)
        if limits.ndim != 2 or limits.shape[1] != 2 or len(limits) < 1:
            raise ValueError(f"joint_limits must have shape (n, 2), got {limits.shape}")
        n = len(limits)
        types = tuple(JointType(t) for t in (self.joint_types or (JointType.REVOLUTE,) * n))
        links = tuple(self.link_names) or tuple(f"j{k}" for k in range(1, n))
        joints = tuple(self.joint_names) or tuple(f"q{k}" for k in range(1, n + 1))
        if len(types) != n or len(links) != n - 1 or len(joints) != n:
            raise ValueError(f"{n} joints need {n} joint types and names and {n - 1} link names")
        if len(set(links)) != len(links) or any(x in ("base", "tool") for x in links):
            raise ValueError(f"link names must be unique and not 'base' or 'tool': {links}")
        nominal = np.asarray(self.nominal, dtype=float)
        if nominal.shape != (12 + 5 * (n - 1),):
            raise ValueError(f"nominal must have shape ({12 + 5 * (n - 1)},) for {n} joints, got {nominal.shape}")
        object.__setattr__(self, "nominal", nominal)
        object.__setattr__(self, "joint_limits", limits)
        object.__setattr__(self, "joint_types", types)
        object.__setattr__(self, "link_names", links)
        object.__setattr__(self, "joint_names", joints)
        for key, shape in (("joint_map", (n, n)), ("joint_offset", (n,)), ("tool_offset", (4, 4))):
            value = getattr(self, key)
            if value is not None:
                value = np.asarray(value, dtype=float)
                if value.shape != shape:
                    raise ValueError(f"{key} must have shape {shape}, got {value.shape}")
                object.__setattr__(self, key, value)
        if self.joint_map is not None and not np.linalg.cond(self.joint_map) < 1e10:  # relative, not det
            raise ValueError("joint_map must be invertible")

    # ------------------------------------------------------------------ structure
    @property
    def n_joints(self) -> int:
        return len(self.joint_limits)

    @cached_property
    def slot_names(self) -> tuple[str, ...]:
        return slot_names_for(self.link_names)

    @cached_property
    def slot_index(self) -> dict[str, int]:
        return {name: i for i, name in enumerate(self.slot_names)}

    def slot(self, name: str) -> int:
        """Index of the slot called ``name``; ``KeyError`` naming the known ones if unknown."""
        try:
            return self.slot_index[name]
        except KeyError:
            raise KeyError(f"unknown kinematic parameter {name!r} of {self.name}; known: "
                           f"{', '.join(self.slot_names)}") from None

    @cached_property
    def slot_is_angle(self) -> np.ndarray:
        return slot_is_angle(self.slot_names)

    @cached_property
    def chain(self):
        """The :class:`fgcal.robots.kinematics.Chain` of this model (operations and joint map)."""
        from fgcal.robots.kinematics import Chain

        return Chain([t.value for t in self.joint_types], self.joint_map, self.joint_offset, self.tool_offset)

    @property
    def tool_offset_matrix(self) -> np.ndarray:
        """The constant transform (4, 4) after the tool parameters; identity unless set."""
        return np.eye(4) if self.tool_offset is None else self.tool_offset

    @property
    def joint_is_angle(self) -> np.ndarray:
        """``(n,)`` bool: the joint is revolute (readings in deg in files, rad inside)."""
        return np.array([t is JointType.REVOLUTE for t in self.joint_types])

    @property
    def joint_units(self) -> list[str]:
        return ["deg" if a else "mm" for a in self.joint_is_angle]

    def joints_to_internal(self, q_file) -> np.ndarray:
        """Readings in file units (deg, mm) ``(..., n)`` to internal units (rad, mm)."""
        return np.where(self.joint_is_angle, np.radians(q_file), np.asarray(q_file, dtype=float))

    def joints_to_file_units(self, q) -> np.ndarray:
        """Readings in internal units (rad, mm) ``(..., n)`` to file units (deg, mm)."""
        return np.where(self.joint_is_angle, np.degrees(q), np.asarray(q, dtype=float))

    def slots_to_file_units(self, slots) -> np.ndarray:
        return np.where(self.slot_is_angle, np.degrees(slots), slots)

    def slots_from_file_units(self, values) -> np.ndarray:
        return np.where(self.slot_is_angle, np.radians(values), values)

    def with_world_origin_at(self, slots, point) -> np.ndarray:
        """``slots`` (S,) with the world frame moved so that its origin is ``point`` (3,), mm in the
        current world frame: the base becomes ``Trans(-point) A_b`` (a ballbar's pivot frame)."""
        base = [self.slot(f"base.{f}") for f in EULER_FIELDS]
        shift = np.eye(4)
        shift[:3, 3] = -np.asarray(point, dtype=float)
        out = np.array(slots, dtype=float)
        out[base] = to_euler_zyx_trans(shift @ euler_zyx_trans(*out[base]))
        return out

    def forward(self, slots, q) -> np.ndarray:
        """Tool poses ``(N, 4, 4)`` (mm) at readings ``q`` (N, n) with geometry ``slots`` (S,)."""
        return self.chain.forward(slots, q)

    # ------------------------------------------------------------------ parameters
    @property
    def parallel_axes(self) -> np.ndarray:
        """``(n-1,)`` bool: link k's axes k and k+1 are nominally parallel (alpha_k = 0 or 180 deg; within
        2.9 deg, where a calibrated model or URDF taken as the nominal tilts them by alpha and beta)."""
        alphas = np.array([self.nominal[self.slot(f"{j}.alpha")] for j in self.link_names])
        betas = np.array([self.nominal[self.slot(f"{j}.beta")] for j in self.link_names])
        return (np.abs(np.sin(alphas)) < 0.05) & ((np.abs(np.sin(alphas)) < 1e-9) | (np.abs(betas) < 0.05))

    def _rule_names(self) -> list[str]:
        """The paper's rule: base 6; link k: theta (k > 1), beta where parallel else d (k > 1), a, alpha;
        tool 6. Prismatic links keep both theta and d as candidates; the rank check decides."""
        names = [f"base.{f}" for f in EULER_FIELDS]
        for k, (j, parallel) in enumerate(zip(self.link_names, self.parallel_axes), start=1):
            prismatic = self.joint_types[k - 1] is JointType.PRISMATIC
            if k > 1:
                names.append(f"{j}.theta")
            if parallel:
                names.append(f"{j}.beta")
            if k > 1 and (prismatic or not parallel):
                names.append(f"{j}.d")
            names += [f"{j}.a", f"{j}.alpha"]
        names += [f"tool.{f}" for f in EULER_FIELDS]
        return names

    @cached_property
    def _identifiable(self) -> tuple[tuple[str, ...], dict]:
        return minimal_parameters(self, self._rule_names())

    def identifiable_names(self) -> list[str]:
        """The identifiable minimal parameter names: the paper's rule, pruned by a rank check."""
        return list(self._identifiable[0])

    @property
    def rule_exceptions(self) -> dict:
        """Parameters of the paper's rule that the rank check dropped, with the reason."""
        return dict(self._identifiable[1])

    def parameters(self, extra=(), exclude=()) -> ParameterSet:
        """The identifiable :class:`ParameterSet`, with ``extra`` slots added and ``exclude`` removed.

        Extra slots are appended after the standard ones (so that rank checks blame them first).
        """
        names = [n for n in self.identifiable_names() if n not in set(exclude)]
        for name in extra:
            self.slot(name)
            if name not in names:
                names.append(name)
        return ParameterSet(self, tuple(names))

    def in_limits(self, q, tol: float = 1e-9) -> np.ndarray:
        """``(N,)`` bool: joint readings ``q`` (N, n) (rad, mm) are within the joint limits."""
        q = np.atleast_2d(q)
        return np.all((q >= self.joint_limits[:, 0] - tol) & (q <= self.joint_limits[:, 1] + tol), axis=1)


@dataclass(frozen=True)
class ParameterSet:
    """An ordered subset of the slots that is estimated; the other slots are held.

    Attributes
    ----------
    model : RobotModel
    names : tuple of str
        Parameter names in estimation order.
    """

    model: RobotModel
    names: tuple[str, ...]

    @property
    def index(self) -> np.ndarray:
        """Slot index of each parameter, shape (P,)."""
        return np.array([self.model.slot(n) for n in self.names], dtype=int)

    @property
    def is_angle(self) -> np.ndarray:
        return self.model.slot_is_angle[self.index]

    @property
    def units(self) -> list[str]:
        """File units: ``"deg"`` for angles, ``"mm"`` for lengths."""
        return ["deg" if a else "mm" for a in self.is_angle]

    def __len__(self) -> int:
        return len(self.names)

    def nominal(self) -> np.ndarray:
        """Nominal values of the parameters (P,) in internal units (mm, rad)."""
        return self.model.nominal[self.index]

    def full(self, values, held=None) -> np.ndarray:
        """The slot vector (S,) with the parameters set to ``values`` (P,) and others from ``held``.

        ``held`` is a slot vector (S,), the nominal by default.
        """
        values = np.asarray(values, dtype=float)
        if values.shape != (len(self),):
            raise ValueError(f"values must have shape ({len(self)},), got {values.shape}")
        out = np.array(self.model.nominal if held is None else held, dtype=float)
        out[self.index] = values
        return out

    def take(self, slots) -> np.ndarray:
        """The parameters' values (P,) from a slot vector (S,)."""
        return np.asarray(slots, dtype=float)[self.index]

    def to_file_units(self, values) -> np.ndarray:
        """Internal units (mm, rad) to file units (mm, deg); works on (P,) and on (..., P)."""
        return np.where(self.is_angle, np.degrees(values), values)

    def from_file_units(self, values) -> np.ndarray:
        """File units (mm, deg) to internal units (mm, rad)."""
        return np.where(self.is_angle, np.radians(values), values)

    def covariance_to_file_units(self, cov) -> np.ndarray:
        """A (P, P) covariance in internal units converted to file units."""
        scale = np.where(self.is_angle, np.degrees(1.0), 1.0)
        return np.asarray(cov) * np.outer(scale, scale)


def slots_to_file_units(slots) -> np.ndarray:
    """A slot vector of an n-joint chain in internal units to file units (mm, deg)."""
    return np.where(_angle_mask(slots), np.degrees(slots), slots)


def slots_from_file_units(values) -> np.ndarray:
    """A slot vector of an n-joint chain in file units (mm, deg) to internal units (mm, rad)."""
    return np.where(_angle_mask(values), np.radians(values), values)


def _angle_mask(slots) -> np.ndarray:
    """The angle slots of a chain of ``len(slots)`` slots (the pattern depends only on its length)."""
    size = np.shape(slots)[-1]
    if size < 12 or (size - 12) % 5:
        raise ValueError(f"slot vector of shape ({size},) fits no chain: expected (12 + 5 (n - 1),)")
    return slot_is_angle(slot_names_for([f"j{k}" for k in range(1, (size - 12) // 5 + 1)]))
