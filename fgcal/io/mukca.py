"""Import of the MUKCa two-socket tool's layout (DESIGN.md 8.2).

A directory holds one folder per placement of the plate; each folder has ``hole_0.csv`` and
``hole_1.csv`` (one joint set per line, radians, no header): the ball on the flange seated in
socket 0 or 1, in many arm configurations. Each socket is an unknown fixture point
``PLACEMENT/hole_K``; the two sockets of a placement are ``distance`` mm apart (a constraint).
Files such as ``hole_0_pose.csv`` (the controller's own forward kinematics) are not measurements
and are ignored. The robot file (a URDF) is copied into the dataset so that it stands alone.
"""
from __future__ import annotations

import logging
import math
import os
import stat
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fgcal.errors import DatasetError, FgcalError
from fgcal.measurements.contact import ContactObservations
from fgcal.measurements.dataset import Dataset, Noise
from fgcal.measurements.setup import DistanceConstraint, FixtureSpec, SetupSpec
from fgcal.robots.model import Tooling
from fgcal.util.yamlio import check_regular_file, read_text_file

__all__ = ["HOLES", "MAX_ROWS", "MukcaImport", "read_mukca"]

HOLES = ("hole_0", "hole_1")
MAX_ROWS = 100_000  # per file: far beyond a hand-recorded session
BALL = "B"
MAX_RAD = 2 * math.pi + 1e-9  # a joint reading beyond a turn: degrees, most likely

log = logging.getLogger(__name__)


@dataclass
class MukcaImport:
    """The datasets of a MUKCa directory: training placements and (maybe) held-out ones."""

    calibration: Dataset
    holdout: Dataset | None
    placements: list
    held_out: list


def _joint_file(path: Path, n_joints: int) -> np.ndarray:
    """The joint sets of a hole file: ``n_joints`` radians a line, separated by commas (or by blanks,
    semicolons or tabs); an empty field between commas is an error, not a value left out."""
    check_regular_file(path, DatasetError)
    text = read_text_file(path, DatasetError, max_bytes=64 << 20)
    if text.startswith("\ufeff"):
        text = text[1:]
    rows = []
    for k, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        if "," in line:
            cells = [c.strip() for c in line.split(",")]
            if cells[-1] == "":  # one trailing comma: the end of the line
                cells.pop()
            if "" in cells:
                raise DatasetError(f"{path}: line {k}: an empty field among the joint angles "
                                   f"(value {cells.index('') + 1} of {len(cells)})")
        else:
            cells = line.replace(";", " ").split()
        if len(cells) != n_joints:
            raise DatasetError(f"{path}: line {k}: {len(cells)} values, expected {n_joints} joint angles (rad)")
        try:
            q = [float(c) for c in cells]
        except ValueError:
            raise DatasetError(f"{path}: line {k}: not a number among the joint angles") from None
        bad = [j for j, v in enumerate(q, start=1) if not math.isfinite(v)]
        if bad:
            raise DatasetError(f"{path}: line {k}: joint {bad[0]} is not a finite number")
        beyond = [j for j, v in enumerate(q, start=1) if abs(v) > MAX_RAD]
        if beyond:
            j = beyond[0]
            raise DatasetError(f"{path}: line {k}: joint {j} is {q[j - 1]:.6g}, beyond 2 pi rad: the files hold "
                               "radians (are these degrees?)")
        rows.append(q)
        if len(rows) > MAX_ROWS:
            raise DatasetError(f"{path}: more than {MAX_ROWS} joint sets")
    if not rows:
        raise DatasetError(f"{path}: no joint sets")
    return np.array(rows, dtype=float)


def _placement_name(directory: Path, name: str) -> str:
    """``name`` if it can name fixtures (``NAME/hole_K``: no commas, no edge spaces, printable)."""
    if "," in name or name != name.strip() or not name.isprintable():
        raise DatasetError(f"{directory}: placement folder {name!r}: its name becomes a fixture name, which must not "
                           "contain commas, control characters or edge spaces; rename the folder")
    return name


def _scan(directory: Path) -> list[str]:
    """The placement folders of ``directory``; what is skipped is said, what cannot be read is an error."""
    try:
        entries = sorted(directory.iterdir())
    except OSError as exc:
        raise DatasetError(f"{directory}: cannot list: {exc.strerror or exc}") from None
    placements, skipped = [], []
    for entry in entries:
        if entry.name.startswith("."):
            continue
        try:
            st = entry.stat()
        except OSError as exc:
            raise DatasetError(f"{entry}: cannot read: {exc.strerror or exc}") from None
        if not stat.S_ISDIR(st.st_mode):
            skipped.append(entry.name)
            continue
        try:
            files = {f.name for f in entry.iterdir()}
        except OSError as exc:
            raise DatasetError(f"{entry}: cannot list: {exc.strerror or exc}") from None
        holes = [h for h in HOLES if f"{h}.csv" in files]
        if not holes:
            skipped.append(entry.name + "/")
            continue
        placements.append(_placement_name(directory, entry.name))
        known = {f"{h}{s}.csv" for h in HOLES for s in ("", "_pose")}
        stray = sorted(f for f in files if f not in known and not f.startswith("."))
        if stray:
            log.warning("%s: ignored %s (only %s are read)", entry, ", ".join(stray[:5]) + (" ..." if len(stray) > 5 else ""),
                        " and ".join(f"{h}.csv" for h in HOLES))
        if len(holes) < len(HOLES):
            missing = [f"{h}.csv" for h in HOLES if h not in holes]
            log.warning("%s: no %s: its socket %s has no distance constraint", entry, ", ".join(missing),
                        ", ".join(holes))
    if skipped:
        log.warning("%s: ignored %s (no %s inside)", directory, ", ".join(skipped[:5]) + (" ..." if len(skipped) > 5 else ""),
                    " or ".join(f"{h}.csv" for h in HOLES))
    return placements


def read_mukca(directory, robot_file, n_joints: int, chain: dict | None, distance: float = 50.0,
               distance_sigma: float = 0.05, contact_sigma: float = 0.05, holdout_placements=()) -> MukcaImport:
    """Read a MUKCa directory into datasets (file units: deg, mm).

    Parameters
    ----------
    directory : path
        One folder per placement, each with ``hole_0.csv`` and ``hole_1.csv``.
    robot_file : path
        The robot (a URDF or model file); its name is written as ``robot:`` (the caller copies it).
    n_joints : int
        Joints of the robot's chain (columns of the files).
    distance, distance_sigma : float
        The sockets' distance and its uncertainty (mm).
    contact_sigma : float
        Declared seating error per axis (mm); estimated from the data by default.
    holdout_placements : sequence of str
        Placements written to the held-out dataset instead.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise DatasetError(f"{directory}: not a directory of placements")
    placements = _scan(directory)
    if not placements:
        raise DatasetError(f"{directory}: no placement folder with hole_0.csv or hole_1.csv")
    holdout_placements = list(dict.fromkeys(holdout_placements))
    unknown = [p for p in holdout_placements if p not in placements]
    if unknown:
        raise FgcalError(f"--holdout-placements: {', '.join(unknown)} not among the placements "
                         f"({', '.join(placements)})")
    sides = {"calibration": [p for p in placements if p not in holdout_placements],
             "holdout": [p for p in placements if p in holdout_placements]}
    if not sides["calibration"]:
        raise FgcalError("--holdout-placements: every placement is held out; nothing is left to calibrate")
    out = {}
    for side, names in sides.items():
        if not names:
            continue
        q_all: list = []
        pose: list[int] = []
        fixture: list[str] = []
        lines: list = []
        fixtures, distances = {}, []
        for p in names:
            present = []
            for h in HOLES:
                path = directory / p / f"{h}.csv"
                if not os.path.lexists(path):
                    continue
                q = _joint_file(path, n_joints)
                if len(q) < 2:
                    log.warning("%s: one joint set: socket %s/%s is seen once, which says nothing of the robot",
                                path, p, h)
                name = f"{p}/{h}"
                fixtures[name] = FixtureSpec(name, "point")
                present.append(name)
                start = len(q_all)
                q_all += list(q)
                pose += list(range(start + 1, start + len(q) + 1))
                fixture += [name] * len(q)
                lines += list(range(1, len(q) + 1))
            if len(present) == 2:
                distances.append(DistanceConstraint(present[0], present[1], float(distance), float(distance_sigma)))
        ids = np.arange(1, len(q_all) + 1)
        obs = ContactObservations(ids, np.full(len(ids), BALL), np.array(fixture), None)
        ds = Dataset(robot=str(robot_file), tooling=Tooling(radius=0.0, balls={BALL: np.zeros(3)}),
                     noise=Noise(cmm_sigma=contact_sigma, joint_resolution=0.0,
                                 extra=(("contact_sigma", float(contact_sigma)),)),
                     provenance={"importer": "fgcal import mukca", "source": str(directory), "placements": names,
                                 "note": "pose ids in order of placement, socket and line; joints from radians"},
                     pose_ids=ids, joints_deg=np.degrees(np.array(q_all)), chain=chain,
                     setup=SetupSpec(fixtures, tuple(distances)))
        ds.contacts = obs
        out[side] = ds
    return MukcaImport(out["calibration"], out.get("holdout"), sides["calibration"], sides["holdout"])
