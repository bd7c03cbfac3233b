"""A TUM trajectory (as evo reads it) joined with a robot's joint log by timestamp.

The TUM format has one pose per line, ``timestamp tx ty tz qx qy qz qw`` separated by spaces
(commas are accepted too), positions in metres, ``#`` starting a comment. The joint log is any
table with a header (see :func:`fgcal.io.table_io.read_columns`): a time column and the joint
columns. Each measured pose takes the joint reading nearest in time when it is within the
tolerance; poses without one are named and skipped.
"""
from __future__ import annotations

import math
from array import array
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from fgcal.errors import DatasetError
from fgcal.io.skipped import bounded
from fgcal.io.table_io import QUATERNION_NORM_TOLERANCE, AngleUnit, LengthUnit, Measurements, read_columns, read_lines

__all__ = ["join_by_time", "read_tum", "read_tum_with_joint_log"]


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def read_tum(path, length_unit: LengthUnit = LengthUnit.M):
    """``(line, t, xyz, R, skipped)`` of a TUM trajectory file; xyz (N, 3) in mm, R (N, 3, 3)."""
    rows, lines, skipped = array("d"), array("q"), []  # 8 bytes a value, not a Python float
    for i, raw in enumerate(read_lines(path), start=1):
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        fields = s.replace(",", " ").split()
        if len(fields) != 8:
            skipped.append(f"line {i}: {len(fields)} fields, expected 8 (timestamp tx ty tz qx qy qz qw)")
            continue
        try:
            v = [float(f) for f in fields]
        except ValueError:
            k = next(j for j, f in enumerate(fields) if not _is_number(f))
            skipped.append(f"line {i}: field {k + 1} is not a number")
            continue
        if not all(math.isfinite(x) for x in v):
            skipped.append(f"line {i}: not finite")
            continue
        if abs(np.linalg.norm(v[4:]) - 1.0) > QUATERNION_NORM_TOLERANCE:
            skipped.append(f"line {i}: quaternion norm {np.linalg.norm(v[4:]):.4g} is not 1")
            continue
        rows.extend(v)
        lines.append(i)
    if not lines:
        raise DatasetError(f"{path}: no usable TUM rows ({len(skipped)} skipped{': ' + bounded(skipped[0]) if skipped else ''})")
    a = np.frombuffer(rows, dtype=float).reshape(-1, 8)
    return np.frombuffer(lines, dtype=np.int64), a[:, 0].copy(), a[:, 1:4] * LengthUnit(length_unit).to_mm, \
        Rotation.from_quat(a[:, 4:]).as_matrix(), skipped


def join_by_time(t_measured, t_log, tolerance: float):
    """Index into ``t_log`` of the reading nearest each of ``t_measured``, and whether it is within tolerance.

    Returns
    -------
    index : ndarray of int, shape (N,)
    ok : ndarray of bool, shape (N,)
    gap : ndarray, shape (N,)
        Time to the nearest reading (same unit as the timestamps).
    """
    t_measured = np.asarray(t_measured, dtype=float)
    order = np.argsort(t_log, kind="stable")
    ts = np.asarray(t_log, dtype=float)[order]
    right = np.clip(np.searchsorted(ts, t_measured), 0, len(ts) - 1)
    left = np.clip(right - 1, 0, len(ts) - 1)
    pick = np.where(np.abs(ts[left] - t_measured) <= np.abs(ts[right] - t_measured), left, right)
    gap = np.abs(ts[pick] - t_measured)
    return order[pick], gap <= tolerance, gap


def read_tum_with_joint_log(trajectory, joint_log, joints, time_column: str = "time",
                            joint_unit: AngleUnit = AngleUnit.RAD, tolerance: float = 0.01,
                            length_unit: LengthUnit = LengthUnit.M, delimiter: str | None = None,
                            decimal_comma: bool | None = None) -> Measurements:
    """Measured poses of a TUM file with the joint readings of a log, joined by timestamp.

    Parameters
    ----------
    joints : sequence of str
        Joint columns of the log in chain order.
    tolerance : float
        Largest time difference (timestamp units, usually s) between a pose and its joint reading.

    Returns
    -------
    Measurements
        Pose id = line of the TUM file; poses without a joint reading near enough are in ``skipped``.
    """
    joints = tuple(joints or ())
    if not joints:
        raise DatasetError("--joints: give the joint log's joint columns in chain order")
    line, t, xyz, R, skipped = read_tum(trajectory, length_unit)
    log_lines, values, log_skipped = read_columns(joint_log, [time_column, *joints], delimiter=delimiter,
                                                  decimal_comma=decimal_comma)
    log_name = Path(joint_log).name
    skipped += [f"{log_name} {s}" for s in log_skipped]
    t_log = values[time_column]
    # A timestamp the log repeats is ambiguous (which reading was at that time?): only its first
    # reading is kept, the others named.
    _, first = np.unique(t_log, return_index=True)
    repeated = np.setdiff1d(np.arange(len(t_log)), first)
    skipped += [f"{log_name} line {log_lines[i]}: timestamp {t_log[i]:.17g} repeats an earlier reading's (ignored)"
                for i in repeated]
    first.sort()
    index, ok, gap = join_by_time(t, t_log[first], tolerance)
    index = first[index]
    skipped += [f"line {ln}: no joint reading within {tolerance:g} (nearest {g:.3g} away)"
                for ln, g in zip(line[~ok], gap[~ok])]
    # One reading is one configuration: when several poses are nearest the same reading, the one
    # nearest in time keeps it and the others are named (a wide tolerance would pair them all).
    order = np.lexsort((gap, index))
    taken = np.zeros(len(index), dtype=bool)
    seen = -1
    for k in order:
        if ok[k] and index[k] != seen:
            taken[k], seen = True, index[k]
    for k in np.flatnonzero(ok & ~taken):
        keeper = int(line[np.flatnonzero(taken & (index == index[k]))[0]])
        skipped.append(f"line {line[k]}: its nearest joint reading ({log_name} line {log_lines[index[k]]}) is "
                       f"taken by line {keeper}, nearer in time (one reading, one pose)")
    ok = taken
    if not ok.any():
        raise DatasetError(f"{trajectory}: no pose has a joint reading of {joint_log} within {tolerance:g}; do the "
                           "clocks agree?")
    q = np.stack([values[j] for j in joints], axis=1)[index[ok]]
    if AngleUnit(joint_unit) is AngleUnit.DEG:
        q = np.radians(q)
    return Measurements(line[ok], q, xyz[ok], R[ok], skipped=skipped, source=str(trajectory))
