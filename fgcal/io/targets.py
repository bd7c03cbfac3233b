"""Target tool poses for ``fgcal compensate``: ``pose,x,y,z,qw,qx,qy,qz`` (or ``pose,x,y,z``: positions
only, a reflector's points) and optional seed joints."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fgcal.errors import DatasetError
from fgcal.io.dataset_tables import _read_table, joint_columns
from fgcal.measurements.cells import MAX_DEG, integer, number
from fgcal.measurements.pose import POSE
from fgcal.robots.transforms import pose_matrices

__all__ = ["read_targets"]


def read_targets(path, n_joints: int = 6):
    """Target tool poses (the columns of ``poses.csv``) or positions, optionally with seed joints ``q1..qn``.

    Parameters
    ----------
    path : path-like
    n_joints : int
        The robot's joints: the seed columns are ``q1..q{n_joints}`` (all or none).

    Returns
    -------
    ids : ndarray of int, shape (N,)
    T : ndarray, shape (N, 4, 4)
        Target poses (mm); identity rotations when the file gives positions only.
    seeds : ndarray, shape (N, n_joints), or None
        Seed joints in file units (deg; mm for prismatic joints), when given.
    position_only : bool
        The file gives positions only (``pose,x,y,z``: a reflector's points).
    """
    path = Path(path)
    q_columns = joint_columns(n_joints)[1:]
    quaternion = ["qw", "qx", "qy", "qz"]
    rows = _read_table(path, ["pose", "x", "y", "z"], optional=quaternion + q_columns)
    if not rows:
        raise DatasetError(f"{path}: no targets")
    has_quaternion = [c in rows[0][1] for c in quaternion]
    if any(has_quaternion) and not all(has_quaternion):
        raise DatasetError(f"{path}: line 1: give all of qw,qx,qy,qz (a pose) or none (a position)")
    position_only = not any(has_quaternion)
    has_q = [c in rows[0][1] for c in q_columns]
    if any(has_q) and not all(has_q):
        raise DatasetError(f"{path}: line 1: give all of {q_columns[0]}..{q_columns[-1]} or none")
    ids: list[int] = []
    T: list = []
    seeds: list = []
    seen: dict[int, int] = {}
    for line, r in rows:
        where = f"{path}: line {line}"
        pid = integer(r["pose"], where, "pose")
        if position_only:
            values = np.array([number(r[c], where, c) for c in "xyz"] + [1.0, 0.0, 0.0, 0.0])
        else:
            _, values = POSE.parse(where, r, {})
        if pid in seen:
            raise DatasetError(f"{where}: duplicate pose {pid} (first on line {seen[pid]})")
        seen[pid] = line
        ids.append(pid)
        T.append(pose_matrices(values[:3], values[3:]))
        if all(has_q):
            seeds.append([number(r[c], where, c, MAX_DEG) for c in q_columns])
    return np.array(ids), np.array(T).reshape(-1, 4, 4), (np.array(seeds) if seeds else None), position_only

