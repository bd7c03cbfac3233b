"""Non-geometric joint errors: gravity compliance and a per-joint error map, as a parameter block.

The joint variable is the reading plus a correction linear in the block's parameters ``phi``::

    q = reading + G(reading) @ phi          G: (N, n_joints, K)

- ``jJ.compliance`` (µrad/Nm): torsional compliance of joint J; its column of ``G`` is the
  gravity torque of joint J (N m, :mod:`fgcal.robots.gravity`) at each pose.
- ``map.jJ.sinH`` / ``map.jJ.cosH`` (µrad): harmonics ``sin(H q_J)``, ``cos(H q_J)`` of joint
  J's reading, with a zero-mean prior. A map describes the robot in the set-up and joint region it
  was fitted on: the ranges of the readings are kept with it, and using it outside them warns.

The block is appended after the geometric parameters (:class:`BlockParameters`), so covariances
and results carry it. No I/O here.
"""
from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

import numpy as np

from fgcal.robots.gravity import Inertials, Payload, gravity_torques, model_inertials

__all__ = [
    "COMPLIANCE_MIN_NM",
    "BlockParameters",
    "JointErrorBlock",
    "JointErrorSpec",
    "ModelKind",
    "commands_for",
    "compliance_joints",
    "corrected_joints",
    "is_block_name",
    "outside_region",
]

log = logging.getLogger(__name__)

MICRO = 1e6  # internal rad (per N m) -> file µrad (per N m)
COMPLIANCE_PRIOR = 1e-3  # rad/Nm: a weak prior (1000 µrad/Nm), far above any real arm's
_NAME = re.compile(r"^(j(\d+)\.compliance|map\.j(\d+)\.(sin|cos)(\d+))$")


class ModelKind(str, Enum):
    """What the calibration models beyond the geometry."""

    GEOMETRIC = "geometric"
    COMPLIANCE = "compliance"
    COMPLIANCE_MAP = "compliance+map"

    @property
    def order(self) -> int:
        return list(ModelKind).index(self)


def is_block_name(name: str) -> bool:
    """``True`` for a joint-error parameter name (``j2.compliance``, ``map.j1.sin3``)."""
    return bool(_NAME.match(name))


@dataclass(frozen=True)
class JointErrorSpec:
    """Which joint-error parameters to estimate.

    Attributes
    ----------
    compliance : tuple of int
        Joints (1-based) with a torsional compliance.
    harmonics : int
        Map harmonics per joint (0: no map); terms ``sin(h q)``, ``cos(h q)`` for h = 1..harmonics.
    map_joints : tuple of int
        Joints (1-based) with a map; all joints when empty.
    map_sigma : float
        Prior standard deviation of each map coefficient (rad).
    compliance_sigma : float
        Prior standard deviation of each compliance (rad/Nm), weak.
    payload : Payload
        Load on the tool for the gravity torques (not fitted).
    """

    compliance: tuple = ()
    harmonics: int = 0
    map_joints: tuple = ()
    map_sigma: float = 50e-6
    compliance_sigma: float = COMPLIANCE_PRIOR
    payload: Payload = field(default_factory=Payload)

    def names(self, n_joints: int) -> list[str]:
        out = [f"j{j}.compliance" for j in self.compliance]
        joints = self.map_joints or tuple(range(1, n_joints + 1))
        for j in joints:
            for h in range(1, self.harmonics + 1):
                out += [f"map.j{j}.sin{h}", f"map.j{j}.cos{h}"]
        return out

    def to_dict(self) -> dict:
        return {"compliance": list(self.compliance), "harmonics": int(self.harmonics),
                "map_joints": list(self.map_joints), "map_sigma_urad": float(self.map_sigma * MICRO),
                "compliance_sigma_urad_per_Nm": float(self.compliance_sigma * MICRO),
                "payload": {"mass": float(self.payload.mass), "com": [float(c) for c in self.payload.com]}}

    @classmethod
    def from_dict(cls, d: dict) -> JointErrorSpec:
        p = d.get("payload") or {}
        return cls(tuple(int(j) for j in d.get("compliance", ())), int(d.get("harmonics", 0)),
                   tuple(int(j) for j in d.get("map_joints", ())), float(d.get("map_sigma_urad", 50.0)) / MICRO,
                   float(d.get("compliance_sigma_urad_per_Nm", COMPLIANCE_PRIOR * MICRO)) / MICRO,
                   Payload(float(p.get("mass", 0.0)), tuple(p.get("com", (0.0, 0.0, 0.0)))))


COMPLIANCE_MIN_NM = 1.0  # N m: a joint whose gravity torque varies less carries no identifiable compliance


def compliance_joints(torques, fraction: float = 0.1, minimum_nm: float = COMPLIANCE_MIN_NM) -> tuple:
    """Joints (1-based) whose gravity torque varies enough over the poses to carry a compliance.

    A joint qualifies when the spread (max - min) of its torque is at least ``fraction`` of the
    largest joint's spread and at least ``minimum_nm`` N m. ``torques``: (N, n) N m.
    """
    spread = np.ptp(np.asarray(torques), axis=0)
    if not spread.size or spread.max() <= 0:
        return ()
    keep = (spread >= fraction * spread.max()) & (spread >= minimum_nm)
    return tuple(int(j) + 1 for j in np.nonzero(keep)[0])


@dataclass(frozen=True)
class JointErrorBlock:
    """The block's parameters, in estimation order, for one model.

    Attributes
    ----------
    names : tuple of str
    inertials : Inertials or None
        Needed when a compliance is estimated.
    payload : Payload
    map_sigma, compliance_sigma : float
        Prior standard deviations (rad, rad/Nm).
    chain : fgcal.robots.kinematics.Chain or None
        The model's chain, for the gravity torques (a 6R chain when None).
    """

    names: tuple
    inertials: Inertials | None
    payload: Payload = field(default_factory=Payload)
    map_sigma: float = 50e-6
    compliance_sigma: float = COMPLIANCE_PRIOR
    chain: object = None

    @classmethod
    def build(cls, spec: JointErrorSpec, n_joints: int, inertials: Inertials | None, names=None,
              chain=None) -> JointErrorBlock:
        """The block of ``spec``; ``names`` restricts it (for example after dropping unidentifiable ones)."""
        all_names = spec.names(n_joints)
        chosen = tuple(n for n in all_names if names is None or n in set(names))
        if any(n.endswith(".compliance") for n in chosen) and inertials is None:
            from fgcal.errors import ModelError

            raise ModelError("the compliance model needs the robot's link masses and centres of mass "
                             "(an 'inertials:' block in the model file)")
        return cls(chosen, inertials, spec.payload, spec.map_sigma, spec.compliance_sigma, chain)

    def __len__(self) -> int:
        return len(self.names)

    def _terms(self):
        for n in self.names:
            m = _NAME.match(n)
            if m.group(2):
                yield "compliance", int(m.group(2)) - 1, 0
            else:
                yield m.group(4), int(m.group(3)) - 1, int(m.group(5))

    @property
    def units(self) -> list[str]:
        return ["urad/Nm" if n.endswith(".compliance") else "urad" for n in self.names]

    @property
    def prior_sigma(self) -> np.ndarray:
        """(K,) internal units."""
        return np.array([self.compliance_sigma if n.endswith(".compliance") else self.map_sigma for n in self.names])

    @property
    def joints(self) -> np.ndarray:
        """(K,) int: the joint (0-based) each parameter corrects (every column of ``G`` has one)."""
        return np.array([j for _, j, _ in self._terms()], dtype=int)

    def design_columns(self, q, slots) -> np.ndarray:
        """``g`` (N, K): the nonzero entry of each column of :meth:`design`, ``G[:, joints[k], k]``.

        The compact form of ``G``: each parameter corrects one joint, so ``G`` is ``n_joints``
        times larger and mostly zeros (on 8,000 poses with 30 harmonics: 146 MB against 24 MB).
        """
        q = np.atleast_2d(np.asarray(q, dtype=float))
        g = np.empty((len(q), len(self)))
        tau = None
        for k, (kind, j, h) in enumerate(self._terms()):
            if kind == "compliance":
                if tau is None:
                    assert self.inertials is not None  # a compliance term needs the masses
                    tau = gravity_torques(slots, q, self.inertials, self.payload, self.chain)
                g[:, k] = tau[:, j]
            else:
                g[:, k] = np.sin(h * q[:, j]) if kind == "sin" else np.cos(h * q[:, j])
        return g

    def design(self, q, slots) -> np.ndarray:
        """``G`` (N, n_joints, K): the joint correction per unit of each parameter at readings ``q`` (rad)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        G = np.zeros(q.shape + (len(self),))
        G[:, self.joints, np.arange(len(self))] = self.design_columns(q, slots)
        return G


@dataclass(frozen=True)
class BlockParameters:
    """A geometric :class:`~fgcal.robots.model.ParameterSet` with a joint-error block appended.

    Duck-types the parameter set for the solver and the results: ``index`` and ``full`` concern the
    geometry only; ``names``, ``units``, ``nominal`` and the unit conversions cover both.
    """

    geometric: Any  # a ParameterSet (or a SetupParameters over one)
    block: JointErrorBlock

    @property
    def model(self):
        return self.geometric.model

    @property
    def n_geometric(self) -> int:
        return len(self.geometric)

    @property
    def names(self) -> tuple:
        return tuple(self.geometric.names) + tuple(self.block.names)

    @property
    def index(self) -> np.ndarray:
        return self.geometric.index

    @property
    def units(self) -> list[str]:
        return list(self.geometric.units) + self.block.units

    def __len__(self) -> int:
        return self.n_geometric + len(self.block)

    def nominal(self) -> np.ndarray:
        return np.concatenate([self.geometric.nominal(), np.zeros(len(self.block))])

    def full(self, values, held=None) -> np.ndarray:
        return self.geometric.full(np.asarray(values, dtype=float)[: self.n_geometric], held)

    def take(self, slots) -> np.ndarray:
        return np.concatenate([self.geometric.take(slots), np.zeros(len(self.block))])

    def _scale(self) -> np.ndarray:
        return np.concatenate([np.where(self.geometric.is_angle, np.degrees(1.0), 1.0), np.full(len(self.block), MICRO)])

    def to_file_units(self, values) -> np.ndarray:
        return np.asarray(values, dtype=float) * self._scale()

    def from_file_units(self, values) -> np.ndarray:
        return np.asarray(values, dtype=float) / self._scale()

    def covariance_to_file_units(self, cov) -> np.ndarray:
        s = self._scale()
        return np.asarray(cov) * np.outer(s, s)


def _block_of_result(result, model=None):
    """``(block, phi (K,) internal, slots)`` of a result, or ``(None, None, None)`` for a geometric one."""
    info = getattr(result, "joint_errors", None) or {}
    if not info.get("names"):
        return None, None, None
    spec = JointErrorSpec.from_dict(info.get("spec", {}))
    model = result.model() if model is None else model
    block = JointErrorBlock.build(spec, model.n_joints, model_inertials(model), info["names"], model.chain)
    est = {p.name: p.estimate for p in result.parameters}
    phi = np.array([est[n] for n in block.names]) / MICRO
    return block, phi, result.slot_vector(model)


def corrected_joints(result, q, model=None) -> np.ndarray:
    """The joint readings (internal units) corrected by a result's block, for readings ``q`` (N, n).

    ``model``: the result's own by default.
    """
    block, phi, slots = _block_of_result(result, model)
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if block is None:
        return q
    return q + block.design(q, slots) @ phi


def commands_for(result, q_actual, iterations: int = 10, model=None) -> np.ndarray:
    """Joint commands whose corrected joints are ``q_actual`` (N, n): the inverse of
    :func:`corrected_joints`, by fixed-point iteration (the corrections are small and smooth)."""
    block, phi, slots = _block_of_result(result, model)
    q_actual = np.atleast_2d(np.asarray(q_actual, dtype=float))
    if block is None:
        return q_actual
    cmd = q_actual.copy()
    for _ in range(iterations):
        cmd = q_actual - block.design(cmd, slots) @ phi
    return cmd


def outside_region(result, q) -> list[str]:
    """Messages for readings ``q`` (N, n) rad outside the joint region a map was fitted on."""
    info = getattr(result, "joint_errors", None) or {}
    ranges = info.get("joint_ranges_deg")
    if not info.get("map_terms") or not ranges:
        return []
    qd = result.model().joints_to_file_units(np.atleast_2d(q))
    out = []
    for j, (lo, hi) in enumerate(ranges):
        bad = np.nonzero((qd[:, j] < lo - 1e-9) | (qd[:, j] > hi + 1e-9))[0]
        if bad.size:
            out.append(f"joint {j + 1}: {bad.size} value(s) outside the range {lo:.2f}..{hi:.2f} deg the joint "
                       f"error map was fitted on (first at row {bad[0] + 1}); the map is not valid there")
    return out
