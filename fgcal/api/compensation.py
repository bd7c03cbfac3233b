"""``fgcal.compensate``: joint commands that bring the calibrated robot to target poses (``fgcal compensate``)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from fgcal.api.notes import note, warn
from fgcal.api.selection import as_result
from fgcal.errors import FgcalError
from fgcal.util.parsing import finite_floats

__all__ = ["Commands", "compensate", "parse_branch", "parse_seed_joints", "parse_tcp"]


@dataclass
class Commands:
    """Joint commands for targets, as ``fgcal compensate`` writes them.

    Attributes
    ----------
    ids : ndarray of int, shape (N,)
        The targets' pose ids.
    joints : ndarray, shape (N, n)
        Commands in file units (deg; mm for prismatic joints), NaN rows for unreachable targets.
    reasons : list of str, length N
        Empty for a reached target, else why it was not.
    solution : Compensation
        The solver's record (residuals, joint changes from the seeds, branch).
    columns : list of str
        ``pose, q1..qn``.
    position_only : bool
        The targets were positions only (their orientation kept at the seed's).
    """

    ids: np.ndarray
    joints: np.ndarray
    reasons: list[str]
    solution: Any
    columns: list[str]
    position_only: bool = False

    @property
    def reachable(self) -> np.ndarray:
        """Boolean (N,): the targets with a command."""
        return np.array([not r for r in self.reasons], dtype=bool)

    def rows(self) -> list[list]:
        """``[pose, q1, ..., qn]`` of each reachable target."""
        return [[int(p), *map(float, q)] for p, q, ok in zip(self.ids, self.joints, self.reachable, strict=True)
                if ok]

    def save(self, path) -> None:
        """Write the reachable targets' commands as CSV ``pose,q1..qn`` (deg), atomically."""
        from fgcal.io.dataset_io import write_csv

        write_csv(path, self.columns, self.rows())


def parse_tcp(value):
    """The 4x4 TCP transform from ``"X,Y,Z[,RX,RY,RZ]"`` or a sequence (mm, deg), or None."""
    from fgcal.robots.compensate import tcp_matrix

    if value is None:
        return None
    v = finite_floats(value, (3, 6))
    if v is None:
        raise FgcalError(f"--tcp {value!r}: give X,Y,Z or X,Y,Z,RX,RY,RZ (mm, deg) in the tool frame")
    return tcp_matrix(v[:3], v[3:] if len(v) == 6 else (0.0, 0.0, 0.0))


def parse_branch(text):
    """The IK branch named ``text`` (e.g. ``righty/up/noflip``), or None."""
    from fgcal.robots.ik import BRANCHES

    if text is None:
        return None
    for b in BRANCHES:
        if str(b) == str(text):
            return b
    raise FgcalError(f"--branch {text!r}: one of {', '.join(map(str, BRANCHES))}")


def parse_seed_joints(value, model):
    """``"q1,..,qn"`` or a sequence (deg; mm for prismatic joints) to internal units (rad, mm), or None."""
    if value is None:
        return None
    v = finite_floats(value, (model.n_joints,))
    if v is None:
        raise FgcalError(f"--seed-joints {value!r}: give {model.n_joints} joint values "
                         f"({','.join(model.joint_names)}; {', '.join(sorted(set(model.joint_units)))})")
    return model.joints_to_internal(np.array(v))


def compensate(result, targets, *, frame: str = "instrument", tcp=None, branch=None,
               max_change: float = 10.0, seed_joints=None) -> Commands:
    """Solve each target on the calibrated model in the configuration commanded.

    Parameters
    ----------
    result : path or CalibrationResult
    targets : path
        CSV ``pose,x,y,z,qw,qx,qy,qz[,q1..qn]`` (mm; seed joints in deg, the commands for the nominal
        model), or ``pose,x,y,z[,q1..qn]`` for positions only (a reflector's calibration: the position
        is reached, the orientation kept at the seed's).
    frame : {"instrument", "base"}
        Frame of the targets: the measuring instrument's, or the robot's own base frame placed by
        the calibrated base.
    tcp : str or sequence, optional
        ``X,Y,Z[,RX,RY,RZ]``: the point the targets are for, in the model's tool frame (mm, deg).
    branch : str, optional
        Configuration of targets without seed joints (PUMA-type arms); default: the one reaching most.
    max_change : float
        Refuse a solution moving a joint further than this from its seed, deg.
    seed_joints : str or sequence, optional
        ``q1,..,qn`` (deg; mm for prismatic joints): where the numerical IK starts for targets
        without seed joints on an arm with no closed form (PUMA- and UR-type arms have one).

    Returns
    -------
    Commands
        ``.save(path)`` writes the reachable ones; ``.reasons`` names the others.

    Warns
    -----
    FgcalWarning
        Targets outside the region a joint error map was fitted in.
    FgcalNote
        What the solver chose (the branch).
    """
    from fgcal.io.dataset_io import joint_columns
    from fgcal.io.targets import read_targets
    from fgcal.robots.compensate import Frame, compensate_targets

    tcp_T = parse_tcp(tcp)
    chosen = parse_branch(branch)
    if frame not in ("instrument", "base"):
        raise FgcalError(f"--frame {frame!r}: instrument or base")
    result = as_result(result)
    model = result.model()
    ids, T, seeds, position_only = read_targets(targets, model.n_joints)
    if seeds is not None:
        seeds = model.joints_to_internal(seeds)
    start = parse_seed_joints(seed_joints, model)
    if position_only and tcp_T is not None:
        raise FgcalError(f"{targets}: positions only (no qw,qx,qy,qz) with --tcp: a TCP's position is "
                         "reached through its orientation; give full poses")
    c = compensate_targets(model, result.slot_vector(model), T, seeds, frame=Frame(frame), tcp=tcp_T,
                           branch=chosen, max_change_deg=max_change, start=start,
                           position_only=np.full(len(ids), position_only))
    for message in c.notes:
        note(message)
    ok = c.reachable
    q = np.array(c.q, dtype=float)
    if result.joint_errors.get("names") and ok.any():  # joint-error block: command what lands on q
        from fgcal.estimation.joint_errors import commands_for, outside_region

        for message in outside_region(result, q[ok]):
            warn(f"{targets}: {message}")
        q[ok] = commands_for(result, q[ok])
    joints = np.full_like(q, np.nan)
    joints[ok] = model.joints_to_file_units(q[ok])
    return Commands(np.asarray(ids, dtype=int), joints, list(c.reasons), c, joint_columns(model.n_joints),
                    bool(position_only))
