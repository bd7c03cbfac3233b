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
from fgcal.robots.base_frame import base_transform, mounting
from fgcal.robots.ik import BRANCHES, Branch, IKError, _check_puma_structure, solve_numeric, solve_puma_batch
from fgcal.robots.model import SLOT_NAMES, RobotModel
from fgcal.robots.transforms import pose_difference, rot

__all__ = [
    "MAX_CHANGE_DEG",
    "Compensation",
    "Frame",
    "base_transform",
    "compensate",
    "compensate_targets",
    "mounting",
    "solve_from_start",
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


def _closed_form(model: RobotModel):
    """The nominal model's closed-form batch solver (PUMA or UR structure), or None."""
    from fgcal.robots.ik_ur import is_ur_structure, solve_ur_any, solve_ur_batch, ur_proxy

    if is_ur_structure(model):
        return solve_ur_batch
    if ur_proxy(model, ideal=True) is not None:  # a UR URDF or kinematics file: through a UR table
        return solve_ur_any
    if tuple(model.slot_names) == tuple(SLOT_NAMES) and model.n_joints == 6:
        try:
            _check_puma_structure(model.nominal)
            return solve_puma_batch
        except IKError:
            return None
    return None


def _choose_branch(model: RobotModel, solver, x_seed, targets) -> tuple[Branch | None, np.ndarray | None]:
    """The branch whose nominal solutions are within the limits for the most targets."""
    best: tuple[Branch | None, np.ndarray | None, int] = (None, None, -1)
    for branch in BRANCHES:
        q, ok = solver(model, targets, branch, slots=x_seed)
        ok = ok & np.all(np.isfinite(q), axis=1) & model.in_limits(np.nan_to_num(q))
        if ok.sum() > best[2]:
            best = (branch, np.where(ok[:, None], q, np.nan), int(ok.sum()))
    return best[0], best[1]


def _with_orientation(model: RobotModel, x, T, q):
    """``T`` (4, 4) with the rotation the geometry ``x`` has at joints ``q``: a position-only target's pose."""
    out = np.array(T, dtype=float)
    out[:3, :3] = model.forward(x, q)[0, :3, :3]
    return out


def _solve(model: RobotModel, x, T, seed, position_only: bool):
    """Joints reaching ``T`` from ``seed``; a position-only target keeps the orientation at the seed
    (the full pose when the arm can, else the position alone, nearest the seed)."""
    if not position_only:
        return solve_numeric(model, T, seed, slots=x)
    try:
        return solve_numeric(model, _with_orientation(model, x, T, seed), seed, slots=x)
    except IKError:
        return solve_numeric(model, T, seed, slots=x, orientation_scale=0.0)


def _nominal_seeds(model, x, T, seed, missing, position_only, start, branch, notes):
    """Seeds of the targets without commanded joints: the nominal model's own IK (closed form in one
    branch, or numerical from ``start``), i.e. the command the nominal model would be sent."""
    # the nominal link geometry with the calibrated base and tool: the user's nominal command
    x_seed = model.nominal.copy()
    for part in ("base", "tool"):
        a, b = model.slot(f"{part}.phi"), model.slot(f"{part}.pz") + 1
        x_seed[a:b] = x[a:b]
    rows = np.nonzero(missing)[0]
    if start is not None:
        for i in rows:
            try:
                seed[i] = solve_from_start(model, T[i], start, x_seed, bool(position_only[i]))
            except IKError:
                pass  # named below: no seed
        notes.append("targets without seed joints are solved from the start joints given (nominal model first)")
        return branch
    solver = _closed_form(model)
    full = rows[~position_only[rows]]
    if solver is None or not len(full):
        if solver is None:
            notes.append("no closed-form IK for this arm (PUMA 560 and UR structures have one): give the "
                         "commanded joints or a start (--seed-joints)")
        return branch
    if branch is None:
        branch, q_nom = _choose_branch(model, solver, x_seed, T[full])
        notes.append(f"targets without seed joints are solved in the {branch} configuration")
    else:
        q_nom, _ = solver(model, T[full], branch, slots=x_seed)
    seed[full] = q_nom
    return branch


def solve_from_start(model: RobotModel, T, start, slots, position_only: bool = False, steps: int = 12):
    """Numerical IK from one start ``start`` (n,) rad for a target that may be far from it: directly,
    else by continuation (the target moved in ``steps`` steps from the start's pose)."""
    from scipy.spatial.transform import Rotation

    from fgcal.robots.transforms import so3_log

    x = np.asarray(slots, dtype=float)
    try:
        return _solve(model, x, T, start, position_only)
    except IKError:
        pass
    T0 = model.forward(x, start)[0]
    target = _with_orientation(model, x, T, start) if position_only else np.asarray(T, dtype=float)
    w = so3_log(target[:3, :3] @ T0[:3, :3].T)
    q = np.asarray(start, dtype=float)
    for t in np.linspace(0.0, 1.0, steps + 1)[1:]:
        Ti = np.eye(4)
        Ti[:3, :3] = Rotation.from_rotvec(t * w).as_matrix() @ T0[:3, :3]
        Ti[:3, 3] = (1 - t) * T0[:3, 3] + t * target[:3, 3]
        q = solve_numeric(model, Ti, q, slots=x)
    return _solve(model, x, T, q, position_only)


def compensate_targets(model: RobotModel, slots, targets, seeds=None, frame: Frame = Frame.INSTRUMENT,
                       tcp=None, branch: Branch | None = None, max_change_deg: float = MAX_CHANGE_DEG,
                       start=None, position_only=None) -> Compensation:
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
        The configuration of targets without seed joints (PUMA- and UR-structured arms); by default
        the one whose nominal solutions are within the limits for the most targets.
    max_change_deg : float
        Refuse a solution that moves a joint further than this from its seed.
    start : array_like, shape (n_joints,), optional
        Joints (rad) to start the numerical IK from for targets without seed joints (any arm): the
        nominal model is solved from it, then the calibrated one from that nominal command.
    position_only : array_like of bool, shape (N,), optional
        Targets whose rotation is not given (a reflector's points): the position is reached and the
        orientation kept at the seed's.
    """
    x = np.asarray(slots, dtype=float)
    T = np.asarray(targets, dtype=float).reshape(-1, 4, 4)
    n, nj = len(T), len(model.joint_limits)
    pos_only = np.zeros(n, dtype=bool) if position_only is None else np.asarray(position_only, dtype=bool).reshape(n)
    if Frame(frame) is Frame.BASE:
        T = base_transform(model, x) @ T
    if tcp is not None:
        if pos_only.any():  # the TCP's point, whatever the orientation: only the flange's position is free
            raise FgcalError("a TCP with position-only targets: give the TCP as a tool ball or full-pose targets")
        T = T @ np.linalg.inv(np.asarray(tcp, dtype=float))  # where the tool frame must be
    seed = np.full((n, nj), np.nan) if seeds is None else np.array(seeds, dtype=float).reshape(n, nj)
    notes: list[str] = []
    missing = ~np.all(np.isfinite(seed), axis=1)
    if missing.any():
        start = None if start is None else np.asarray(start, dtype=float).reshape(nj)
        branch = _nominal_seeds(model, x, T, seed, missing, pos_only, start, branch, notes)
    q = np.full((n, nj), np.nan)
    reasons = [""] * n
    change = np.full(n, np.nan)
    for i in range(n):
        if not np.all(np.isfinite(seed[i])):
            if start is not None:
                reasons[i] = "the nominal model does not reach it from the start joints given"
            elif pos_only[i]:
                reasons[i] = "a position-only target needs seed joints q1..qn or a start (--seed-joints)"
            elif branch is None:
                reasons[i] = "no seed joints: give the commanded joints q1..qn or a start (--seed-joints)"
            else:
                reasons[i] = f"out of reach (or beyond the joint limits) in the {branch} configuration"
            continue
        try:
            qi = _solve(model, x, T[i], seed[i], bool(pos_only[i]))
        except IKError as exc:
            reasons[i] = f"{exc}; the target may lie beyond the reach or joint limits of the calibrated robot"
            continue
        change[i] = float(np.degrees(np.max(np.abs(qi - seed[i]))))
        if change[i] > max_change_deg:
            j = int(np.argmax(np.abs(qi - seed[i])))
            reasons[i] = (f"the only solution found leaves the commanded configuration ({model.joint_names[j]} "
                          f"moves {change[i]:.3g} deg from the seed, more than {max_change_deg:g})")
            continue
        q[i] = qi
    ok = np.all(np.isfinite(q), axis=1)
    pos = np.full(n, np.nan)
    ang = np.full(n, np.nan)
    if ok.any():
        d, delta = pose_difference(model.forward(x, q[ok]), T[ok])
        pos[ok], ang[ok] = np.linalg.norm(d, axis=1), np.degrees(np.linalg.norm(delta, axis=1))
        ang[ok & pos_only] = np.nan  # no orientation was asked for
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
