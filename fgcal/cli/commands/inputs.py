"""The inputs of a run: every file and folder a command reads, for the output checks.

One notion, used by every command's output check (:func:`~fgcal.cli.commands.checks.check_output_file`,
:func:`~fgcal.cli.commands.checks.check_output_dir`): a dataset folder, its ``dataset.yaml``, every
file the dataset format names, the robot file ``dataset.yaml`` names (resolved against the
dataset's folder, as the loader does) and the files that robot file refers to (none today: a
model file and a URDF are self-contained; URDF meshes are not read), plus the robot, result,
target and other files given on the command line. No output may replace any of them, and no
output folder that is replaced may contain or lie inside one.
"""
from __future__ import annotations

from pathlib import Path

__all__ = ["DATASET_FILES", "dataset_files", "robot_files", "run_inputs"]

# the files of the dataset format (the kinematic types add theirs)
DATASET_FILES = ("dataset.yaml", "joints.csv", "probes.csv", "centres.csv", "poses.csv", "truth.yaml", "robot.yaml")


def robot_files(ref, directory=None) -> list[Path]:
    """The files a robot reference reads: ``[]`` for a built-in name, else the model file or URDF
    (relative to ``directory`` when given: a dataset's ``robot:``)."""
    from fgcal.io.dataset_io import robot_path

    if ref is None:
        return []
    path = robot_path(directory, str(ref)) if directory is not None else robot_path(None, str(ref))
    return [] if path is None else [path]


def dataset_files(directory) -> list[Path]:
    """A dataset folder, the files of the dataset format in it and the robot file it names."""
    from fgcal.errors import FgcalError
    from fgcal.measurements.types import kinematic_types
    from fgcal.util.yamlio import read_yaml

    directory = Path(directory)
    names = list(DATASET_FILES) + [k.file for k in kinematic_types() if k.file not in DATASET_FILES]
    names += ["contacts.csv", "distances.csv"]
    files = [directory, *(directory / n for n in dict.fromkeys(names))]
    try:
        meta = read_yaml(directory / "dataset.yaml")
    except (FgcalError, OSError):
        return files  # the loader reports a dataset.yaml it cannot read
    if isinstance(meta, dict) and isinstance(meta.get("robot"), str):
        files += robot_files(meta["robot"], directory)
    return files


def run_inputs(datasets=(), robots=(), files=()) -> list[Path]:
    """Every input of a run: ``datasets`` (folders), ``robots`` (option values: a built-in name or a
    file) and other ``files`` (results, targets, logs, checkpoints); None entries are skipped."""
    out: list[Path] = []
    for d in datasets:
        if d is not None:
            out += dataset_files(d)
    for r in robots:
        out += robot_files(r)
    out += [Path(f) for f in files if f is not None]
    return out
