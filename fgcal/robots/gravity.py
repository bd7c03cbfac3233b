"""Gravity torques on the joints of a serial arm, from its links' masses and centres of mass.

A model file may state the inertial parameters of its links (``inertials:``)::

    inertials:
      gravity: [0, 0, -9.81]        # m/s^2 in the robot's base frame (optional; this default)
      links:                        # one row per link, in chain order
        - {mass: 7.1, com: [21, 0, 27]}     # kg; centre of mass (mm) in the link's frame
        ...

Link n's frame is the frame after its row of the link table (standard DH: frame n). When a
table's last row is folded into the tool on loading, the last link's centre of mass is moved into
the frame after the last joint's rotation, which is where it is kept internally and written back.

The torque of joint j is the moment about its axis of the weight of every body beyond it
(links j..n and the payload): ``tau_j = sum_b ((c_b - o_j) x m_b g) . z_j`` (N m). It is the
torque gravity exerts on the joint, so a positive torsional compliance moves the joint along it.
No I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgcal.errors import ModelError
from fgcal.robots.kinematics import chain_for
from fgcal.util.numbers import finite_number
from fgcal.util.yamlio import short_repr

__all__ = ["Inertials", "Payload", "gravity_torques", "inertials_from_dict", "inertials_to_dict", "model_inertials"]

STANDARD_GRAVITY = 9.81


@dataclass(frozen=True)
class Payload:
    """A load carried by the tool: ``mass`` (kg) at ``com`` (mm, tool frame)."""

    mass: float = 0.0
    com: tuple = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Inertials:
    """Masses and centres of mass of the links.

    Attributes
    ----------
    mass : ndarray, shape (n,)
        Link masses (kg), link 1 first.
    com : ndarray, shape (n, 3)
        Centres of mass (mm), each in its link's frame as kept internally (see the module).
    gravity : ndarray, shape (3,)
        Gravity (m/s^2) in the robot's base frame (the frame of joint 1's axis).
    """

    mass: np.ndarray
    com: np.ndarray
    gravity: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "mass", np.asarray(self.mass, dtype=float).reshape(-1))
        object.__setattr__(self, "com", np.asarray(self.com, dtype=float).reshape(-1, 3))
        object.__setattr__(self, "gravity", np.asarray(self.gravity, dtype=float).reshape(3))


def _number(v, where):
    if not finite_number(v):
        raise ModelError(f"{where}: expected a finite number, got {short_repr(v)}")
    return float(v)


def _triple(v, where):
    if not isinstance(v, (list, tuple)) or len(v) != 3:
        raise ModelError(f"{where}: expected a list of 3 numbers, got {short_repr(v)}")
    return [_number(x, f"{where}[{i}]") for i, x in enumerate(v)]


def inertials_from_dict(value, n_links: int, source: str, last_row=None) -> Inertials:
    """Parse a model file's ``inertials:`` mapping.

    Parameters
    ----------
    value : dict
        The parsed mapping.
    n_links : int
        Number of links (joints) of the chain; ``links`` must have that many rows.
    source : str
        File name for error messages.
    last_row : ndarray, shape (4, 4), optional
        The last link row's transform when the loader folds it into the tool: the last link's
        centre of mass is moved through it into the frame after the last joint's rotation.

    Raises
    ------
    ModelError
        Naming the file and the key that is wrong.
    """
    where = f"{source}: inertials"
    if not isinstance(value, dict):
        raise ModelError(f"{where}: expected a mapping with 'links' (and optionally 'gravity')")
    unknown = set(value) - {"links", "gravity"}
    if unknown:
        raise ModelError(f"{where}: unknown key(s) {', '.join(sorted(map(str, unknown)))}; allowed: links, gravity")
    links = value.get("links")
    if not isinstance(links, list) or len(links) != n_links:
        raise ModelError(f"{where}.links: expected a list of {n_links} rows {{mass: kg, com: [x, y, z] mm}}")
    mass: list[float] = []
    com_rows: list = []
    for i, row in enumerate(links):
        w = f"{where}.links[{i}]"
        if not isinstance(row, dict) or set(row) - {"mass", "com"} or "mass" not in row:
            raise ModelError(f"{w}: expected {{mass: kg, com: [x, y, z] mm}}, got {short_repr(row)}")
        m = _number(row["mass"], f"{w}.mass")
        if m < 0:
            raise ModelError(f"{w}.mass: must not be negative")
        mass.append(m)
        com_rows.append(_triple(row.get("com", [0, 0, 0]), f"{w}.com"))
    com = np.array(com_rows)
    if last_row is not None:
        com[-1] = last_row[:3, :3] @ com[-1] + last_row[:3, 3]
    gravity = _triple(value.get("gravity", [0.0, 0.0, -STANDARD_GRAVITY]), f"{where}.gravity")
    return Inertials(np.array(mass), com, np.array(gravity))


def inertials_to_dict(inertials: Inertials) -> dict:
    """The ``inertials:`` mapping of a model file (centres of mass as kept internally)."""
    return {"gravity": [float(g) for g in inertials.gravity],
            "links": [{"mass": float(m), "com": [round(float(c), 9) for c in cm]}
                      for m, cm in zip(inertials.mass, inertials.com)]}


def model_inertials(model) -> Inertials | None:
    """The inertials a :class:`~fgcal.robots.model.RobotModel` carries (``extra["inertials"]``), or None."""
    raw = model.extra.get("inertials")
    if raw is None:
        return None
    return raw if isinstance(raw, Inertials) else inertials_from_dict(raw, model.n_joints, model.name)


def gravity_torques(slots, q, inertials: Inertials, payload: Payload | None = None, chain=None) -> np.ndarray:
    """Gravity torque on every joint at each joint reading (for a prismatic joint: the force along it, N).

    Parameters
    ----------
    slots : array_like
        Geometry (mm, rad) in the kinematic model's slot order.
    q : array_like, shape (N, n)
        Joint readings (rad).
    inertials : Inertials
        Link masses and centres of mass (n links).
    payload : Payload, optional
        Load on the tool (kg, mm in the tool frame).
    chain : fgcal.robots.kinematics.Chain, optional
        The model's chain (``model.chain``); a 6R chain by default.

    Returns
    -------
    ndarray, shape (N, n)
        Torque (N m) that gravity exerts on each joint.
    """
    chain = chain_for(slots, chain)
    R_before, p_before, T = chain.forward_frames(slots, q)
    ops = chain.ops
    joint_ops = sorted((k for k, op in enumerate(ops) if op.joint is not None), key=lambda k: ops[k].joint)
    nj = len(joint_ops)
    if len(inertials.mass) != nj:
        raise ValueError(f"inertials have {len(inertials.mass)} links, the chain {nj} joints")
    # Frame of body b: after link b's row, i.e. before the next joint's rotation; the last body
    # sits in the frame after the last joint's rotation.
    body_ops = joint_ops[1:] + [joint_ops[-1] + 1]
    R_body, p_body = R_before[body_ops], p_before[body_ops]  # (n, N, 3, 3), (n, N, 3)
    c = p_body + np.einsum("bnij,bj->bni", R_body, inertials.com)  # (n, N, 3) mm, world
    g_world = R_before[joint_ops[0]] @ inertials.gravity  # (N, 3)
    weights = inertials.mass[:, None, None] * g_world[None]  # (n, N, 3) N
    if payload is not None and payload.mass > 0:
        c_p = T[:, :3, 3] + T[:, :3, :3] @ np.asarray(payload.com, dtype=float)
        c = np.concatenate([c, c_p[None]], axis=0)
        weights = np.concatenate([weights, payload.mass * g_world[None]], axis=0)
    o = p_before[joint_ops]  # (n, N, 3)
    z = R_before[joint_ops][..., :, 2]  # (n, N, 3)
    body_joint = np.minimum(np.arange(len(c)), nj - 1)  # the payload rides on the last link
    tau = np.zeros((T.shape[0], nj))
    for j in range(nj):
        beyond = body_joint >= j
        if ops[joint_ops[j]].kind == "T":  # prismatic: the weight's component along the axis
            tau[:, j] = np.einsum("ni,ni->n", weights[beyond].sum(axis=0), z[j])
            continue
        arm = c[beyond] - o[j][None]  # mm
        moment = np.cross(arm, weights[beyond]).sum(axis=0)  # N mm
        tau[:, j] = np.einsum("ni,ni->n", moment, z[j]) * 1e-3
    return tau
