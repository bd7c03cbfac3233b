"""The kinematic model of a 6R arm in the paper's convention, and its parameters.

Frames: world -> base -> links 1..6 -> tool (DESIGN.md section 1)::

    A_b = Rz(phi) Ry(theta) Rx(psi) Trans(px, py, pz)
    A_n = Rz(q_n + theta_n) Tz(d_n) Tx(a_n) Rx(alpha_n) Ry(beta_n)      n = 1..5
    A_t = Rz(phi) Ry(theta) Rx(psi) Trans(px, py, pz)                   after Rz(q_6)
    T(q) = A_b A_1 ... A_5 Rz(q_6) A_t

Every geometric quantity of this chain is a *slot* (37 of them: 6 base, 5 per link for links
1..5, 6 tool). The identifiable parameters are a subset of the slots, derived from the nominal
geometry: theta_1 and d_1 are absorbed by the base, link 6 by the tool, and where the nominal
alpha_n is 0 (axes n and n+1 parallel) beta_n replaces d_n (Hayati). Slots that are not
parameters are held at their nominal values.

Internally lengths are millimetres and angles radians; files and reports use degrees.
This module does no I/O.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["SLOT_NAMES", "SLOT_IS_ANGLE", "Tooling", "RobotModel", "ParameterSet"]

EULER_FIELDS = ("phi", "theta", "psi", "px", "py", "pz")
LINK_FIELDS = ("theta", "d", "beta", "a", "alpha")
N_JOINTS = 6
N_LINKS_IN_CHAIN = 5  # link 6 is absorbed by the tool

SLOT_NAMES: tuple[str, ...] = (
    tuple(f"base.{f}" for f in EULER_FIELDS)
    + tuple(f"j{n}.{f}" for n in range(1, N_LINKS_IN_CHAIN + 1) for f in LINK_FIELDS)
    + tuple(f"tool.{f}" for f in EULER_FIELDS)
)
SLOT_INDEX = {name: i for i, name in enumerate(SLOT_NAMES)}
_ANGLE_FIELDS = {"phi", "theta", "psi", "alpha", "beta"}
SLOT_IS_ANGLE = np.array([name.split(".")[1] in _ANGLE_FIELDS for name in SLOT_NAMES])


def slot(name: str) -> int:
    """Index of the slot called ``name`` (for example ``"j2.beta"``); ``KeyError`` if unknown."""
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
    """Nominal geometry, joint limits and measuring set-up of a 6R arm.

    Attributes
    ----------
    name : str
        Model name (``puma560``, ``ur10``, ... or a file's own name).
    nominal : ndarray, shape (37,)
        Nominal slot values in :data:`SLOT_NAMES` order (mm, rad).
    joint_limits : ndarray, shape (6, 2)
        Lower and upper joint limits (rad).
    tooling : Tooling or None
        Default calibration tool (balls), if the model file has one.
    volume : ndarray, shape (2, 3) or None
        Measuring volume in world coordinates, ``[min, max]`` (mm).
    paper_box : ndarray, shape (2, 3) or None
        Parallelepiped for the paper's 48-pose plan, ``[min, max]`` (mm, world).
    description : str
    """

    name: str
    nominal: np.ndarray
    joint_limits: np.ndarray
    tooling: Tooling | None = None
    volume: np.ndarray | None = None
    paper_box: np.ndarray | None = None
    description: str = ""
    extra: dict = field(default_factory=dict)

    def __post_init__(self):
        nominal = np.asarray(self.nominal, dtype=float)
        if nominal.shape != (len(SLOT_NAMES),):
            raise ValueError(f"nominal must have shape ({len(SLOT_NAMES)},), got {nominal.shape}")
        limits = np.asarray(self.joint_limits, dtype=float)
        if limits.shape != (N_JOINTS, 2):
            raise ValueError(f"joint_limits must have shape (6, 2), got {limits.shape}")
        object.__setattr__(self, "nominal", nominal)
        object.__setattr__(self, "joint_limits", limits)

    @property
    def parallel_axes(self) -> np.ndarray:
        """``(5,)`` bool: link n's axes n and n+1 are nominally parallel (alpha_n = 0)."""
        alphas = np.array([self.nominal[slot(f"j{n}.alpha")] for n in range(1, N_LINKS_IN_CHAIN + 1)])
        return np.abs(np.sin(alphas)) < 1e-9

    def identifiable_names(self) -> list[str]:
        """The identifiable parameter names, derived from the nominal geometry (DESIGN.md order)."""
        names = [f"base.{f}" for f in EULER_FIELDS]
        for n in range(1, N_LINKS_IN_CHAIN + 1):
            parallel = self.parallel_axes[n - 1]
            if n > 1:
                names.append(f"j{n}.theta")
            if parallel:
                names.append(f"j{n}.beta")
            elif n > 1:
                names.append(f"j{n}.d")
            names += [f"j{n}.a", f"j{n}.alpha"]
        names += [f"tool.{f}" for f in EULER_FIELDS]
        return names

    def parameters(self, extra=(), exclude=()) -> "ParameterSet":
        """The identifiable :class:`ParameterSet`, with ``extra`` slots added and ``exclude`` removed.

        Extra slots are appended after the standard ones (so that rank checks blame them first).
        """
        names = [n for n in self.identifiable_names() if n not in set(exclude)]
        for name in extra:
            slot(name)
            if name not in names:
                names.append(name)
        return ParameterSet(self, tuple(names))

    def in_limits(self, q, tol: float = 1e-9) -> np.ndarray:
        """``(N,)`` bool: joint readings ``q`` (N, 6) rad are within the joint limits."""
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
        return np.array([slot(n) for n in self.names], dtype=int)

    @property
    def is_angle(self) -> np.ndarray:
        return SLOT_IS_ANGLE[self.index]

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
        """The 37-slot vector with the parameters set to ``values`` (P,) and others from ``held``.

        ``held`` is a slot vector (37,), the nominal by default.
        """
        values = np.asarray(values, dtype=float)
        if values.shape != (len(self),):
            raise ValueError(f"values must have shape ({len(self)},), got {values.shape}")
        out = np.array(self.model.nominal if held is None else held, dtype=float)
        out[self.index] = values
        return out

    def take(self, slots) -> np.ndarray:
        """The parameters' values (P,) from a slot vector (37,)."""
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
    """A 37-slot vector in internal units to file units (mm, deg)."""
    return np.where(SLOT_IS_ANGLE, np.degrees(slots), slots)


def slots_from_file_units(values) -> np.ndarray:
    """A 37-slot vector in file units (mm, deg) to internal units (mm, rad)."""
    return np.where(SLOT_IS_ANGLE, np.radians(values), values)
