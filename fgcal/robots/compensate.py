"""Using a calibration: joint commands that bring the calibrated robot to target tool poses.

Each target is solved numerically on the calibrated model (:func:`fgcal.robots.ik.solve_numeric`) from
one seed in the arm configuration (branch) the user commanded: the commanded joints when given
(the joints the nominal model would be sent), otherwise, for a PUMA-structured arm, the closed-form
solution of the nominal geometry in one branch kept for every target. A solution that moves any
joint further than ``max_change_deg`` from its seed has left the configuration (an elbow or wrist
flip, a turn of a joint) and is refused. Unreachable targets are named with the reason; the others
are still solved. Targets may be given in the instrument (world) frame or in the robot's base
frame, for the model's tool frame or for a user TCP fixed in it. Units: mm, rad. No I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

import numpy as np

from fgcal.errors import FgcalError
from fgcal.robots.ik import BRANCHES, Branch, IKError, solve_numeric, solve_puma_batch
from fgcal.robots.model import EULER_FIELDS, SLOT_NAMES, RobotModel
from fgcal.robots.transforms import euler_zyx_trans, pose_difference, rot

__all__ = [
    "MAX_CHANGE_DEG",
    "Compensation",
    "Frame",
    "base_transform",
    "compensate",
    "compensate_targets",
    "mounting",
    "tcp_matrix",
]

MAX_CHANGE_DEG = 10.0  # a calibration moves joints by a degree or two; more is another configuration


class Frame(str, Enum):
    """The frame targets are given in."""

    INSTRUMENT = "instrument"
    BASE = "base"


def tcp_matrix(xyz_mm, rxyz_deg=(0.0, 0.0, 0.0)) -> np.ndarray:
    """A TCP in the tool frame as (4, 4): position (mm), rotation ``Rz(RZ) Ry(RY) Rx(RX)`` (deg)."""
    rx, ry, rz = np.radians(np.asarray(rxyz_deg, dtype=float))
    T = np.eye(4)
    T[:3, :3] = rot(2, rz) @ rot(1, ry) @ rot(0, rx)
    T[:3, 3] = np.asarray(xyz_mm, dtype=float)
    return T


def mounting(model: RobotModel) -> np.ndarray:
    """The chain's base frame in the robot's own base frame (4, 4; mm): what loading folded into the base.

    A robot file's first link theta and d (and, in modified DH, its a and alpha) are folded into the
    base; a URDF's chain starts at the first joint, placed in the base link. The model keeps that
    transform (``model.extra["mounting"]``, from :mod:`fgcal.robots.robot_file` and
    :mod:`fgcal.robots.urdf_import`); identity when nothing was folded.
    """
    m = model.extra.get("mounting")
    if m is None:
        return np.eye(4)
    v = [float(m.get(f, 0.0)) for f in EULER_FIELDS]
    return euler_zyx_trans(*np.radians(v[:3]), *v[3:])


def base_transform(model: RobotModel, slots) -> np.ndarray:
    """The robot's own base frame in the instrument frame (4, 4; mm) for a slot vector (mm, rad).

    The frame of the robot's mounting flange as its maker or URDF defines it: for a URDF robot the
    base link; for a built-in robot or a DH table the table's base frame (joint 1's axis as z, at
    the mounting face: for the UR10 127.3 mm below the chain's first frame). It is the calibrated
    base (the chain's first frame) times the inverse of the nominal :func:`mounting`: the height of
    the mounting face along joint 1 cannot be told from the base placement by any measurement of
    the tool, so it keeps its nominal value.
    """
    x = np.asarray(slots, dtype=float)
    chain = euler_zyx_trans(*x[model.slot("base.phi"):model.slot("base.pz") + 1])
    return chain @ np.linalg.inv(mounting(model))


@dataclass
class Compensation:
    """Joint commands for targets; unreachable targets have NaN joints and a reason.

    Attributes
    ----------
    q : ndarray, shape (N, n_joints)
        Joint commands (rad) for the calibrated robot; NaN rows for unreachable targets.
    reasons : list of str, length N
        Empty for a reached target, otherwise why it was not.
    position_error_mm, orientation_error_deg : ndarray, shape (N,)
        The calibrated model's numerical residual at ``q`` (NaN where unreachable).
    joint_change_deg : ndarray, shape (N,)
        Largest joint change from the seed (the configuration check), NaN without a solution.
    seeds : ndarray, shape (N, n_joints)
        The seed of every target (rad), NaN where there was none.
    """

    q: np.ndarray
    reasons: list[str]
    position_error_mm: np.ndarray
    orientation_error_deg: np.ndarray
    joint_change_deg: np.ndarray
    seeds: np.ndarray
    branch: Branch | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def reachable(self) -> np.ndarray:
        return np.array([not r for r in self.reasons], dtype=bool)


def _choose_branch(model: RobotModel, x_seed, targets) -> tuple[Branch | None, np.ndarray | None]:
    """The PUMA branch whose nominal solutions are within the limits for the most targets."""
    best: tuple[Branch | None, np.ndarray | None, int] = (None, None, -1)
    for branch in BRANCHES:
        q, ok = solve_puma_batch(model, targets, branch, slots=x_seed)
        ok = ok & np.all(np.isfinite(q), axis=1) & model.in_limits(np.nan_to_num(q))
        if ok.sum() > best[2]:
            best = (branch, np.where(ok[:, None], q, np.nan), int(ok.sum()))
    return best[0], best[1]


def compensate_targets(model: RobotModel, slots, targets, seeds=None, frame: Frame = Frame.INSTRUMENT,
                       tcp=None, branch: Branch | None = None,
                       max_change_deg: float = MAX_CHANGE_DEG) -> Compensation:
    """Joint commands (rad) for the calibrated geometry ``slots`` to reach ``targets``, in the commanded branch.

    Parameters
    ----------
    model : RobotModel
        Nominal model (joint limits, and the closed-form seed where it applies).
    slots : array_like, shape (S,)
        Calibrated geometry (mm, rad).
    targets : array_like, shape (N, 4, 4)
        Target poses (mm) of the TCP in ``frame``.
    seeds : array_like, shape (N, n_joints), optional
        The commanded joints (rad); rows of NaN where unknown.
    frame : Frame
        ``instrument``: the measuring instrument's (world) frame; ``base``: the robot's own base
        frame (:func:`base_transform`: a URDF's base link, a DH table's base frame), placed by the
        calibrated base.
    tcp : array_like, shape (4, 4), optional
        The TCP in the model's tool frame (:func:`tcp_matrix`); the tool frame itself by default.
    branch : Branch, optional
        The configuration of targets without seed joints (PUMA-structured arms); by default the one
        whose nominal solutions are within the limits for the most targets.
    max_change_deg : float
        Refuse a solution that moves a joint further than this from its seed.
    """
    x = np.asarray(slots, dtype=float)
    T = np.asarray(targets, dtype=float).reshape(-1, 4, 4)
    if Frame(frame) is Frame.BASE:
        T = base_transform(model, x) @ T
    if tcp is not None:
        T = T @ np.linalg.inv(np.asarray(tcp, dtype=float))  # where the tool frame must be
    n, nj = len(T), len(model.joint_limits)
    seed = np.full((n, nj), np.nan) if seeds is None else np.array(seeds, dtype=float).reshape(n, nj)
    notes = []
    missing = ~np.all(np.isfinite(seed), axis=1)
    if missing.any() and tuple(model.slot_names) != tuple(SLOT_NAMES):
        notes.append("no closed-form seeds for this arm (the PUMA closed form needs a 6R chain)")
    elif missing.any():
        # the nominal link geometry with the calibrated base and tool: the user's nominal command
        x_seed = model.nominal.copy()
        for part in ("base", "tool"):
            a, b = model.slot(f"{part}.phi"), model.slot(f"{part}.pz") + 1
            x_seed[a:b] = x[a:b]
        try:
            if branch is None:
                branch, q_nom = _choose_branch(model, x_seed, T[missing])
                notes.append(f"targets without seed joints are solved in the {branch} configuration")
            else:
                q_nom, _ = solve_puma_batch(model, T[missing], branch, slots=x_seed)
            seed[missing] = q_nom
        except IKError as exc:
            notes.append(f"no closed-form seeds: {exc}")
    q = np.full((n, nj), np.nan)
    reasons = [""] * n
    change = np.full(n, np.nan)
    for i in range(n):
        if not np.all(np.isfinite(seed[i])):
            reasons[i] = ("no seed joints: give the commanded joints q1..qn" if branch is None else
                          f"out of reach (or beyond the joint limits) in the {branch} configuration")
            continue
        try:
            qi = solve_numeric(model, T[i], seed[i], slots=x)
        except IKError as exc:
            reasons[i] = f"{exc}; the target may lie beyond the reach or joint limits of the calibrated robot"
            continue
        change[i] = float(np.degrees(np.max(np.abs(qi - seed[i]))))
        if change[i] > max_change_deg:
            j = int(np.argmax(np.abs(qi - seed[i])))
            reasons[i] = (f"the only solution found leaves the commanded configuration (q{j + 1} moves "
                          f"{change[i]:.3g} deg from the seed, more than {max_change_deg:g})")
            continue
        q[i] = qi
    ok = np.all(np.isfinite(q), axis=1)
    pos = np.full(n, np.nan)
    ang = np.full(n, np.nan)
    if ok.any():
        d, delta = pose_difference(model.forward(x, q[ok]), T[ok])
        pos[ok], ang[ok] = np.linalg.norm(d, axis=1), np.degrees(np.linalg.norm(delta, axis=1))
    return Compensation(q, reasons, pos, ang, change, seed, branch, notes)


def compensate(model: RobotModel, slots, targets, seeds=None):
    """Joint commands (rad) for world-frame tool ``targets`` (N, 4, 4); all must be reachable.

    Returns ``(q (N, n), position_error_mm (N,), orientation_error_deg (N,))``; raises
    :class:`~fgcal.errors.FgcalError` naming the first unreachable target. See
    :func:`compensate_targets` for partial results, other frames and a TCP.
    """
    c = compensate_targets(model, slots, targets, seeds)
    for i, why in enumerate(c.reasons):
        if why:
            raise FgcalError(f"target {i + 1}: {why}")
    return c.q, c.position_error_mm, c.orientation_error_deg
