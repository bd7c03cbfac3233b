"""Reading a dataset's CSV tables (``joints.csv``, ``probes.csv`` and each measurement type's file)
into typed arrays, streamed: memory linear in the rows with a small constant (bench/bench_memory.py).

Every problem ends in a :class:`~fgcal.errors.DatasetError` whose one-line message names the file
and the line (the header is line 1). A plain file is read whole columns at a time
(:mod:`fgcal.io.fast_tables`); anything out of the ordinary goes to the checked row-by-row path.
"""
from __future__ import annotations

import csv
from array import array
from pathlib import Path

import numpy as np

from fgcal.errors import DatasetError
from fgcal.io.fast_tables import float_columns, int_column, read_column_chunks, read_columns
from fgcal.io.setup_io import read_pixels
from fgcal.measurements.cells import MAX_DEG, MAX_MM, ball_name, pose_id
from fgcal.measurements.cells import integer as _integer
from fgcal.measurements.cells import number as _number
from fgcal.measurements.contact import CONTACT_COLUMNS, ContactObservations
from fgcal.measurements.dataset import PointObservations
from fgcal.measurements.pixels import PIXEL_COLUMNS
from fgcal.measurements.point import POINT
from fgcal.measurements.setup import SetupSpec
from fgcal.util.yamlio import check_regular_file, short_repr

__all__ = ["MAX_JOINTS", "POINT_COLUMNS", "joint_columns", "read_joints", "read_joints_and_stations"]

MAX_JOINTS = 64


def joint_columns(n: int) -> list[str]:
    """``pose, q1 .. qn``: the header of joints.csv for an ``n``-joint robot."""
    return ["pose"] + [f"q{i}" for i in range(1, n + 1)]
POINT_COLUMNS = list(POINT.columns)  # probes.csv has the columns of centres.csv


def _table_records(path: Path, columns: list[str], optional=()):
    """The header and the non-blank records of a CSV file, streamed: yields ``(line, header, cells)``.

    The header must hold ``columns`` and may hold ``optional``; line numbers are 1-based (the
    header is line 1). Only a regular file is opened.
    """
    check_regular_file(path, DatasetError)
    try:
        fh = path.open(newline="", encoding="utf-8")
    except OSError as exc:
        raise DatasetError(f"{path}: cannot read: {exc.strerror or exc}") from None
    with fh:
        reader = csv.reader(fh)
        try:
            header = next(reader, None)
            if header is None:
                raise DatasetError(f"{path}: empty file (expected the header {','.join(columns)})")
            header = [h.strip() for h in header]
            missing = [c for c in columns if c not in header]
            if missing:
                raise DatasetError(f"{path}: line 1: missing column(s) {', '.join(missing)} "
                                   f"(expected {','.join(columns)})")
            unknown = [h[:24] for h in header if h not in columns and h not in optional]
            if unknown:
                raise DatasetError(f"{path}: line 1: unknown column(s) {', '.join(unknown[:3])}"
                                   f"{' ...' if len(unknown) > 3 else ''} "
                                   f"(expected {','.join(list(columns) + list(optional))})")
            if len(set(header)) != len(header):
                raise DatasetError(f"{path}: line 1: a column is repeated in the header")
            n = len(header)
            for record in reader:
                if not record or all(not c.strip() for c in record):
                    continue
                if len(record) != n:
                    raise DatasetError(f"{path}: line {reader.line_num}: {len(record)} fields, expected {n}")
                yield reader.line_num, header, [c.strip() for c in record]
        except csv.Error as exc:
            raise DatasetError(f"{path}: line {reader.line_num}: {exc}") from None
        except UnicodeDecodeError:
            raise DatasetError(f"{path}: line {reader.line_num + 1}: not UTF-8 text") from None
        except OSError as exc:
            raise DatasetError(f"{path}: cannot read: {exc.strerror or exc}") from None


def _read_table(path: Path, columns: list[str], optional: tuple[str, ...] | list[str] = ()):
    """Rows of a CSV file as (line number, dict); the header holds ``columns`` and maybe ``optional``."""
    return [(line, dict(zip(header, cells))) for line, header, cells in _table_records(path, columns, optional)]


def _point_table(path: Path, known_poses: set, balls: dict) -> PointObservations:
    """A ``pose,ball,x,y,z`` file (probe points), streamed into compact arrays (memory linear in the
    rows, small constant): probe files are the largest a dataset has."""
    names = list(balls)
    ball_index = {b: i for i, b in enumerate(names)}
    fast = _fast_point_table(path, known_poses, ball_index)
    if fast is not None:
        return fast
    pose, ball, xyz, lines = array("q"), array("h"), array("d"), array("q")
    cols = None
    for line, header, cells in _table_records(path, POINT_COLUMNS):
        if cols is None:
            cols = [header.index(c) for c in POINT_COLUMNS]
        where = f"{path}: line {line}"
        p_txt, b, x, y, z = (cells[i] for i in cols)
        pid = pose_id(p_txt, where, known_poses)
        k = ball_index.get(b)
        if k is None:
            ball_name(b, where, balls)  # raises, naming the tool's balls
            continue
        pose.append(pid)
        ball.append(k)
        xyz.extend((_number(x, where, "x"), _number(y, where, "y"), _number(z, where, "z")))
        lines.append(line)
    ball_names = np.array(names, dtype=str)[np.frombuffer(ball, dtype=np.int16).astype(int)] if len(ball) \
        else np.zeros(0, dtype=str)
    return PointObservations(np.frombuffer(pose, dtype=np.int64).astype(int), ball_names,
                             np.frombuffer(xyz, dtype=float).reshape(-1, 3).copy(),
                             np.frombuffer(lines, dtype=np.int64).astype(int))


def _fast_point_table(path: Path, known_poses: set, ball_index: dict) -> PointObservations | None:
    """:func:`_point_table` of a plain file whose every cell is valid, whole columns at once
    (:mod:`fgcal.io.fast_tables`; a large file in chunks of whole lines, in memory linear in the rows
    with a small constant); None sends the file to the checked reader."""
    known = np.fromiter(known_poses, dtype=np.int64, count=len(known_poses))
    names = np.array(list(ball_index), dtype=str)
    poses, balls, points = [], [], []
    for cols in read_column_chunks(path, POINT_COLUMNS):
        if cols is None:
            return None
        pose = int_column(cols["pose"])
        xyz = float_columns([cols[c] for c in POINT_COLUMNS[2:]], MAX_MM)
        ball = [ball_index.get(b.strip()) for b in cols["ball"]]
        if pose is None or xyz is None or None in ball or not np.isin(pose, known).all():
            return None
        poses.append(pose)
        balls.append(np.array(ball, dtype=np.int16))
        points.append(xyz)
    if not poses:
        return None
    pose = np.concatenate(poses).astype(int)
    return PointObservations(pose, names[np.concatenate(balls)], np.concatenate(points),
                             np.arange(2, len(pose) + 2))


def _first_repeat(keys: np.ndarray) -> tuple[int, int] | None:
    """``(row, first row)`` of the first row (in file order) whose key an earlier row has, or None.

    ``keys`` (M,) or (M, k) integers; found by sorting (no dict of every row's key)."""
    if len(keys) < 2:
        return None
    keys = keys.reshape(len(keys), -1)
    order = np.lexsort(keys.T[::-1])
    same = np.all(keys[order[1:]] == keys[order[:-1]], axis=1)
    if not same.any():
        return None
    later = order[1:][same]  # each a row with an equal key before it in the sorted (stable) order
    row = int(later.min())
    k = int(np.flatnonzero(order == row)[0])
    while k > 0 and np.array_equal(keys[order[k - 1]], keys[row]):  # back to the key's first row
        k -= 1
    return row, int(order[k])


def _measurement_table(path: Path, kind, known_poses: set, balls: dict):
    """The observations of a kinematic measurement type from its file (:mod:`fgcal.measurements.types`).

    One row per pose and ball (or per pose, for types measured once per pose); each row is
    parsed and checked by the type and kept in typed arrays (8 bytes a number).
    """
    pose, ball, values, lines = array("q"), array("i"), array("d"), array("q")
    ball_index: dict[str, int] = {}
    width = None
    for line, header, cells in _table_records(path, list(kind.columns)):
        where = f"{path}: line {line}"
        record = dict(zip(header, cells))
        pid = pose_id(record["pose"], where, known_poses)
        b, v = kind.parse(where, record, balls)
        v = np.asarray(v, dtype=float).reshape(-1)
        width = len(v) if width is None else width
        pose.append(pid)
        ball.append(ball_index.setdefault(b, len(ball_index)))
        values.extend(v.tolist())
        lines.append(line)
    pose_a, ball_a = np.frombuffer(pose, dtype=np.int64), np.frombuffer(ball, dtype=np.int32)
    line_a = np.frombuffer(lines, dtype=np.int64)
    repeat = _first_repeat(np.column_stack([pose_a, ball_a]))
    if repeat is not None:
        row, first = repeat
        names = list(ball_index)
        what = (f"{kind.noun} of ball {names[ball_a[row]]} at pose {pose_a[row]}" if kind.per_ball
                else f"{kind.noun} {pose_a[row]}")
        raise DatasetError(f"{path}: line {line_a[row]}: duplicate {what} (first on line {line_a[first]})")
    names_a = np.array(list(ball_index) or [""], dtype=str)
    return kind.observations(pose_a.astype(int), names_a[ball_a], np.frombuffer(values, dtype=float).reshape(
        len(pose_a), width or 0), line_a.astype(int))


def _contact_tables(path: Path, kinds, known_poses: set, balls: dict, setup: SetupSpec) -> dict:
    """``contacts.csv`` (``pose,ball,fixture``) split by the kind of each row's fixture."""
    by_type = {k.fixture_type: k for k in kinds}
    rows: dict = {k: ([], [], [], []) for k in kinds}
    seen: dict = {}
    for line, header, cells in _table_records(path, list(CONTACT_COLUMNS)):
        where = f"{path}: line {line}"
        record = dict(zip(header, cells))
        pid = pose_id(record["pose"], where, known_poses)
        b = ball_name(record["ball"], where, balls)
        f = record["fixture"]
        kind_name = setup.kind_of(f)
        if kind_name is None:
            names = ", ".join(list(setup.fixtures)[:6]) or "none"
            raise DatasetError(f"{where}: fixture {short_repr(f)} is not in dataset.yaml's fixtures: ({names})")
        key = (pid, b)
        if key in seen:
            raise DatasetError(f"{where}: ball {b} at pose {pid} has a contact already (line {seen[key]})")
        seen[key] = line
        for lst, v in zip(rows[by_type[kind_name]], (pid, b, f, line)):
            lst.append(v)
    return {k: ContactObservations(np.array(p, dtype=int), np.array(b, dtype=str), np.array(f, dtype=str),
                                   np.array(ln, dtype=int))
            for k, (p, b, f, ln) in rows.items() if p}


def _pixel_table(path: Path, known_poses: set, setup: SetupSpec):
    """``pixels.csv`` with the dataset's cameras and targets (DESIGN.md 8.4)."""
    if not any(f.type == "camera" for f in setup.fixtures.values()):
        raise DatasetError(f"{path}: dataset.yaml has no cameras: for its pixels")

    def records():
        for line, header, cells in _table_records(path, list(PIXEL_COLUMNS)):
            record = dict(zip(header, cells, strict=True))
            yield line, pose_id(record["pose"], f"{path}: line {line}", known_poses), record

    return read_pixels(path, known_poses, dict(setup.fixtures), records())


def read_joints(path) -> tuple[np.ndarray, np.ndarray]:
    """A ``joints.csv``-like file: ``(pose ids (N,), joint readings (N, n) deg or mm)``, columns
    ``pose,q1..qn`` (and an optional ``station``, see :func:`read_joints_and_stations`).

    Raises :class:`DatasetError` naming the file and line for a malformed row or repeated id.
    """
    ids, q, _ = read_joints_and_stations(path)
    return ids, q


def read_joints_and_stations(path):
    """:func:`read_joints` and the ``station`` column ``(N,)`` of str, or None without one."""
    joints_path = Path(path)
    fast = _fast_joints(joints_path)
    if fast is not None:
        return fast
    ids, q, lines, stations = array("q"), array("d"), array("q"), []
    columns = has_station = None
    for line, header, cells in _table_records(joints_path, ["pose", "q1"],
                                              optional=[f"q{i}" for i in range(2, MAX_JOINTS + 1)] + ["station"]):
        if columns is None:
            has_station = "station" in header
            columns = joint_columns(sum(1 for c in header if c not in ("pose", "station")))
            if set(header) - {"station"} != set(columns):
                raise DatasetError(f"{joints_path}: line 1: joint columns must be q1..qn without gaps, got "
                                   f"{','.join(c for c in header if c not in ('pose', 'station'))}")
            col = [header.index(c) for c in columns]
            st_col = header.index("station") if has_station else None
        where = f"{joints_path}: line {line}"
        ids.append(_integer(cells[col[0]], where, "pose"))
        q.extend(_number(cells[i], where, c, MAX_DEG) for i, c in zip(col[1:], columns[1:]))
        lines.append(line)
        if st_col is not None:
            if not cells[st_col]:
                raise DatasetError(f"{where}: station is empty (name the station the pose was measured from)")
            stations.append(cells[st_col])
    if columns is None:
        raise DatasetError(f"{joints_path}: no poses")
    ids_a = np.frombuffer(ids, dtype=np.int64)
    repeat = _first_repeat(ids_a)
    if repeat is not None:
        row, first = repeat
        raise DatasetError(f"{joints_path}: line {lines[row]}: duplicate pose id {ids_a[row]} (first on line "
                           f"{lines[first]})")
    return (ids_a.astype(int), np.frombuffer(q, dtype=float).reshape(len(ids_a), len(columns) - 1),
            np.array(stations, dtype=str) if has_station else None)


def _fast_joints(path: Path):
    """:func:`read_joints_and_stations` of a plain file whose every cell is valid, whole columns at
    once (:mod:`fgcal.io.fast_tables`); None sends the file to the checked reader."""
    cols = read_columns(path, ["pose", "q1"], optional=[f"q{i}" for i in range(2, MAX_JOINTS + 1)] + ["station"])
    if cols is None:
        return None
    columns = joint_columns(sum(1 for c in cols if c not in ("pose", "station")))
    if set(cols) - {"station"} != set(columns):
        return None
    ids = int_column(cols["pose"])
    q = float_columns([cols[c] for c in columns[1:]], MAX_DEG)
    if ids is None or q is None or len(np.unique(ids)) != len(ids):
        return None
    stations = None
    if "station" in cols:
        names = [c.strip() for c in cols["station"]]
        if not all(names):
            return None
        stations = np.array(names, dtype=str)
    return ids.astype(int), q, stations
