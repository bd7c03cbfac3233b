"""Reading and writing dataset directories (DESIGN.md section 3) with validation.

Every problem ends in a :class:`~fgcal.errors.DatasetError` whose one-line message names the file
and the line (the header is line 1) or the pose. Writing goes to a temporary directory first,
which then replaces the target, so a dataset on disk is never half written.
"""
from __future__ import annotations

import csv
import logging
import math
import os
import shutil
import tempfile
from array import array
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from fgcal.errors import DatasetError, FgcalError
from fgcal.io.fast_tables import float_columns, int_column, read_column_chunks, read_columns
from fgcal.io.setup_io import (
    cameras_dict,
    read_cameras,
    read_fixtures,
    read_pixels,
    read_stations,
    read_targets,
    stations_dict,
)
from fgcal.measurements.cells import MAX_DEG, MAX_MM, ball_name, pose_id
from fgcal.measurements.cells import integer as _integer
from fgcal.measurements.cells import number as _number
from fgcal.measurements.contact import CONTACT_COLUMNS, CONTACT_FILE, ContactObservations
from fgcal.measurements.dataset import FORMAT, Dataset, Noise, PointObservations
from fgcal.measurements.pixels import PIXEL_COLUMNS, PIXEL_FILE
from fgcal.measurements.point import POINT
from fgcal.measurements.setup import SetupSpec
from fgcal.measurements.types import kinematic_types, noise_keys
from fgcal.robots.model import EULER_FIELDS, LINK_FIELDS, RobotModel, Tooling
from fgcal.robots.robot_file import load_model
from fgcal.util.yamlio import atomic_write_text, check_regular_file, dump_yaml, make_dir, read_yaml, short_repr

__all__ = ["dataset_model", "load_dataset", "load_dataset_meta", "load_truth", "read_joints", "robot_path", "save_dataset",
           "write_csv"]

log = logging.getLogger(__name__)

_SLOT_FIELDS = set(EULER_FIELDS) | set(LINK_FIELDS)

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


def _measurement_table(path: Path, kind, known_poses: set, balls: dict):
    """The observations of a kinematic measurement type from its file (:mod:`fgcal.measurements.types`).

    One row per pose and ball (or per pose, for types measured once per pose); each row is
    parsed and checked by the type.
    """
    pose: list[int] = []
    ball: list[str] = []
    values: list = []
    lines: list[int] = []
    seen: dict[tuple, int] = {}
    for line, header, cells in _table_records(path, list(kind.columns)):
        where = f"{path}: line {line}"
        record = dict(zip(header, cells))
        pid = pose_id(record["pose"], where, known_poses)
        b, v = kind.parse(where, record, balls)
        key = (pid, b)
        if key in seen:
            what = f"{kind.noun} of ball {b} at pose {pid}" if kind.per_ball else f"{kind.noun} {pid}"
            raise DatasetError(f"{where}: duplicate {what} (first on line {seen[key]})")
        seen[key] = line
        pose.append(pid)
        ball.append(b)
        values.append(v)
        lines.append(line)
    width = len(values[0]) if values else 0
    return kind.observations(np.array(pose, dtype=int), np.array(ball, dtype=str),
                             np.array(values, dtype=float).reshape(len(values), width), np.array(lines, dtype=int))


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


def _meta(path: Path) -> tuple[str, Tooling, Noise, dict, dict | None, SetupSpec, str | None]:
    data = read_yaml(path, error=DatasetError)
    if not isinstance(data, dict):
        raise DatasetError(f"{path}: expected a mapping with format, robot, tool, noise, provenance")
    missing = [k for k in ("format", "robot", "tool", "noise", "provenance") if k not in data]
    if missing:
        raise DatasetError(f"{path}: missing key(s) {', '.join(missing)}")
    if data["format"] != FORMAT:
        raise DatasetError(f"{path}: format {short_repr(data['format'])} is not known (expected {FORMAT!r})")
    if not isinstance(data["robot"], str) or not data["robot"]:
        raise DatasetError(f"{path}: robot must be a model name or a model file path")
    unknown = set(data) - {"format", "robot", "chain", "tool", "noise", "provenance", "fixtures", "constraints",
                           "stations", "cameras", "targets"}
    if unknown:
        raise DatasetError(f"{path}: unknown key(s) {', '.join(sorted(map(str, unknown)))}")
    chain = data.get("chain")
    if chain is not None:
        if (not isinstance(chain, dict) or set(chain) - {"base", "tip"}
                or not all(isinstance(v, str) and v for v in chain.values())):
            raise DatasetError(f"{path}: chain must be {{base: LINK, tip: LINK}} (URDF link names)")

    def num(value, what, minimum=None):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise DatasetError(f"{path}: {what} must be a finite number, got {short_repr(value)}")
        if minimum is not None and value < minimum:
            raise DatasetError(f"{path}: {what} must be >= {minimum}, got {short_repr(value)}")
        if abs(value) > MAX_META_VALUE and not what.endswith(".normal"):  # squared in weights; a normal is a direction
            raise DatasetError(f"{path}: {what} = {value:g} is absurdly large (beyond {MAX_META_VALUE:g}; a unit "
                               "mistake?)")
        return float(value)

    tool = data["tool"]
    ball_free = bool(data.get("cameras"))  # camera-only data need no tool ball (DESIGN.md 8.4)
    if (not isinstance(tool, dict) or "radius" not in tool or not isinstance(tool.get("balls"), dict)
            or not (tool["balls"] or ball_free)):
        raise DatasetError(f"{path}: tool must have radius and balls {{name: [x, y, z]}}")
    balls = {}
    for name, centre in tool["balls"].items():
        if not isinstance(centre, list) or len(centre) != 3:
            raise DatasetError(f"{path}: tool.balls.{name} must be [x, y, z] (mm)")
        balls[str(name)] = np.array([num(c, f"tool.balls.{name}") for c in centre])
    tooling = Tooling(radius=num(tool["radius"], "tool.radius", 0.0), balls=balls)

    noise_raw = data["noise"]
    allowed = ("cmm_sigma", "joint_resolution", "repeatability", "pose_position_sigma", "pose_orientation_sigma",
               "centre_sigma", "distance_sigma") + noise_keys()
    if not isinstance(noise_raw, dict):
        raise DatasetError(f"{path}: noise must be a mapping with {', '.join(allowed)}")
    unknown = set(noise_raw) - set(allowed)
    if unknown:
        raise DatasetError(f"{path}: noise: unknown key(s) {', '.join(sorted(str(k)[:24] for k in unknown))}")
    values = {k: (None if v is None else num(v, f"noise.{k}", 0.0)) for k, v in noise_raw.items()}
    zero = [k for k, v in values.items() if k in noise_keys() and v == 0]
    if zero:  # a contact is never exact: at sigma 0 the joint readings would move to absorb every one
        raise DatasetError(f"{path}: noise.{zero[0]} must be positive (mm), got 0")
    extra = tuple(sorted((k, v) for k, v in values.items() if k in noise_keys()))
    fields: dict[str, Any] = {k: v for k, v in values.items() if k not in noise_keys()}
    noise = Noise(**fields, extra=extra)
    provenance = data["provenance"]
    if not isinstance(provenance, dict):
        provenance = {"text": str(provenance)}
    setup = read_fixtures(path, data, num)
    world, stations = read_stations(path, data, num)
    clash = set(stations) & set(setup.fixtures)
    if clash:
        raise DatasetError(f"{path}: {', '.join(sorted(clash))[:80]}: a name of both a station and a fixture")
    cameras = read_cameras(path, data, num, dict(noise.extra).get("pixel_sigma"))
    targets = read_targets(path, data, num)
    names = [*setup.fixtures, *stations, *cameras, *targets]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise DatasetError(f"{path}: {', '.join(twice)[:80]}: a name given to two of fixtures, stations, cameras, "
                           "targets")
    if cameras and dict(noise.extra).get("pixel_sigma") is None:  # the first camera's: the declared pixel noise
        first = next(iter(cameras.values())).pixel_sigma
        noise = replace(noise, extra=tuple(sorted(noise.extra + (("pixel_sigma", first),))))
    setup = SetupSpec({**setup.fixtures, **stations, **cameras, **targets}, setup.distances)
    return data["robot"], tooling, noise, provenance, chain, setup, world


def load_truth(path) -> tuple[dict, list]:
    """``truth.yaml``: parameter values {name: value} (mm, deg) and planted outliers."""
    path = Path(path)
    data = read_yaml(path, error=DatasetError)
    if not isinstance(data, dict) or not isinstance(data.get("parameters"), dict):
        raise DatasetError(f"{path}: expected 'parameters: {{name: value}}'")
    truth = {}
    for name, value in data["parameters"].items():
        if not isinstance(name, str) or name.rpartition(".")[2] not in _SLOT_FIELDS or not name.rpartition(".")[0]:
            raise DatasetError(f"{path}: unknown parameter {short_repr(name)}")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise DatasetError(f"{path}: parameter {name} must be a finite number, got {short_repr(value)}")
        truth[name] = float(value)
    outliers = []
    for i, item in enumerate(data.get("outliers") or []):
        if not (isinstance(item, list) and len(item) == 3):
            raise DatasetError(f"{path}: outliers[{i}] must be [pose, ball, probe index]")
        try:
            outliers.append((int(item[0]), str(item[1]), int(item[2])))
        except (TypeError, ValueError):
            raise DatasetError(f"{path}: outliers[{i}] must be [pose, ball, probe index] (integers)") from None
    return truth, outliers


def load_dataset_meta(directory) -> Dataset:
    """Only ``dataset.yaml`` of a dataset directory, as a dataset with no poses (for streams)."""
    directory = Path(directory)
    if not directory.is_dir():
        raise DatasetError(f"{directory}: not a dataset directory")
    robot, tooling, noise, provenance, chain, setup, world = _meta(directory / "dataset.yaml")
    return Dataset(robot=robot, tooling=tooling, noise=noise, provenance=provenance, pose_ids=np.zeros(0, dtype=int),
                   joints_deg=np.zeros((0, 6)), path=directory, chain=chain, setup=setup, world_station=world)


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
    rows = _read_table(joints_path, ["pose", "q1"], optional=[f"q{i}" for i in range(2, MAX_JOINTS + 1)] + ["station"])
    if not rows:
        raise DatasetError(f"{joints_path}: no poses")
    has_station = "station" in rows[0][1]
    n_joints = sum(1 for c in rows[0][1] if c not in ("pose", "station"))
    columns = joint_columns(n_joints)
    if set(rows[0][1]) - {"station"} != set(columns):
        raise DatasetError(f"{joints_path}: line 1: joint columns must be q1..qn without gaps, got "
                           f"{','.join(c for c in rows[0][1] if c not in ('pose', 'station'))}")
    ids, q, stations, seen = [], [], [], {}
    for line, r in rows:
        where = f"{joints_path}: line {line}"
        pid = _integer(r["pose"], where, "pose")
        if pid in seen:
            raise DatasetError(f"{where}: duplicate pose id {pid} (first on line {seen[pid]})")
        seen[pid] = line
        ids.append(pid)
        q.append([_number(r[c], where, c, MAX_DEG) for c in columns[1:]])
        if has_station:
            if not r["station"]:
                raise DatasetError(f"{where}: station is empty (name the station the pose was measured from)")
            stations.append(r["station"])
    return (np.array(ids, dtype=int), np.array(q, dtype=float).reshape(len(ids), n_joints),
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


def load_dataset(directory) -> Dataset:
    """Read and validate a dataset directory.

    Raises
    ------
    DatasetError
        With a one-line message naming the file and line, for any malformed input.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise DatasetError(f"{directory}: not a dataset directory")
    robot, tooling, noise, provenance, chain, setup, world = _meta(directory / "dataset.yaml")
    ids, q, stations = read_joints_and_stations(directory / "joints.csv")
    if stations is not None:
        if world is None:
            raise DatasetError(f"{directory / 'joints.csv'}: has a station column but dataset.yaml has no stations:")
        known_st = {world} | {n for n, f in setup.fixtures.items() if f.type == "station"}
        bad = [s_ for s_ in dict.fromkeys(stations.tolist()) if s_ not in known_st]
        if bad:
            raise DatasetError(f"{directory / 'joints.csv'}: station {short_repr(bad[0])} is not in dataset.yaml's "
                               f"stations: ({', '.join(sorted(known_st))[:80]})")
    known = set(ids.tolist())
    ds = Dataset(robot=robot, tooling=tooling, noise=noise, provenance=provenance, pose_ids=ids,
                 joints_deg=q, path=directory, chain=chain, setup=setup, stations=stations, world_station=world)
    if os.path.lexists(directory / "probes.csv"):
        if tooling.radius <= 0:
            raise DatasetError(f"{directory / 'dataset.yaml'}: tool.radius must be positive to use probes.csv")
        ds.probes = _point_table(directory / "probes.csv", known, tooling.balls)
    shared: dict[str, Any] = {}
    for kind in kinematic_types():
        if getattr(kind, "derived", False):
            continue  # split from another level's file below
        if kind.file == CONTACT_FILE:  # contacts at points and on planes share one file
            shared.setdefault(kind.file, []).append(kind)
        elif os.path.lexists(directory / kind.file):
            setattr(ds, kind.level, _measurement_table(directory / kind.file, kind, known, tooling.balls))
    for name, kinds in shared.items():
        if os.path.lexists(directory / name):
            for kind, obs in _contact_tables(directory / name, kinds, known, tooling.balls, setup).items():
                setattr(ds, kind.level, obs)
    if os.path.lexists(directory / PIXEL_FILE):
        ds.pixels = _pixel_table(directory / PIXEL_FILE, known, setup)
    ds.split_station_centres()
    if ds.stations is not None and (ds.probes is not None or ds.poses is not None or ds.distances is not None):
        raise DatasetError(f"{directory}: several stations are supported for centres.csv (and contacts) only")
    if setup.distances:  # a distance to a fixture no contact sees is not used: say so
        seen = {str(f) for lv in ds.levels() for f in getattr(getattr(ds, lv), "fixture", ())}
        for c in setup.distances:
            if (c.a in seen) != (c.b in seen):
                log.warning("%s: the distance between fixtures %s and %s is not used: no contact is at %s",
                            directory / "dataset.yaml", c.a, c.b, c.b if c.a in seen else c.a)
    if os.path.lexists(directory / "truth.yaml"):
        ds.truth, ds.truth_outliers = load_truth(directory / "truth.yaml")
    if not ds.levels():
        files = ["probes.csv", *dict.fromkeys(k.file for k in kinematic_types())]
        what = f"; dataset.yaml has fixtures but {CONTACT_FILE} has no contacts" if setup.fixtures else ""
        log.warning("%s: no measurements (%s or %s)%s; joint readings only", directory, ", ".join(files[:-1]),
                    files[-1], what)
    return ds


MODEL_SUFFIXES = (".yaml", ".yml", ".urdf")
MAX_META_VALUE = 1e9  # any number of dataset.yaml (mm, deg): 1000 km


def robot_path(directory, ref: str) -> Path | None:
    """The file a robot reference names (``robot:`` of a dataset, relative to its ``directory``;
    the current folder when None), or None for a built-in model name. Suffixes in any case."""
    if not (ref.lower().endswith(MODEL_SUFFIXES) or "/" in ref):
        return None
    path = Path(ref)
    return path if path.is_absolute() or directory is None else Path(directory) / path


def dataset_model(ds: Dataset) -> RobotModel:
    """The robot model a dataset names (built-in, or a file relative to the dataset directory)."""
    ref = ds.robot
    candidate = robot_path(ds.path, ref) if ds.path is not None else None
    if candidate is not None:
        model = load_model(candidate, chain=ds.chain)
    else:
        try:
            model = load_model(ref, chain=ds.chain)
        except FgcalError as exc:
            where = ds.path / "dataset.yaml" if ds.path else "dataset"
            raise DatasetError(f"{where}: robot: {exc}") from None
    check_joint_count(ds, model)
    return model


def check_joint_count(ds: Dataset, model: RobotModel) -> None:
    """joints.csv must hold one column per joint of the model's chain."""
    if ds.n_poses and ds.n_joints != model.n_joints:
        where = ds.path / "joints.csv" if ds.path else "joints"
        raise DatasetError(f"{where}: {ds.n_joints} joint columns, but robot {model.name} has {model.n_joints} "
                           f"joints ({', '.join(model.joint_names)})")


def _fmt(v: float | np.floating) -> str:
    from fgcal.util.numbers import format_number

    return format_number(float(v))


def write_csv(path, header, rows) -> None:
    """Write a CSV file atomically; floats with full (round-trip) precision."""
    lines = [",".join(map(_csv_text, header))]
    for row in rows:
        lines.append(",".join(_fmt(v) if isinstance(v, (float, np.floating)) else _csv_text(v) for v in row))
    atomic_write_text(path, "\n".join(lines) + "\n")


def _csv_text(v) -> str:
    """A text field, quoted as RFC 4180 does when it holds a separator, a quote or a line break."""
    s = str(v)
    return '"' + s.replace('"', '""') + '"' if any(c in s for c in ',"\r\n') else s


def _write_into(ds: Dataset, directory: Path) -> None:
    meta = {
        "format": FORMAT,
        "robot": ds.robot,
        **({"chain": dict(ds.chain)} if ds.chain else {}),
        "tool": {"radius": float(ds.tooling.radius),
                 "balls": {k: [float(c) for c in v] for k, v in ds.tooling.balls.items()}},
        "noise": ds.noise.items(),
        "provenance": ds.provenance,
        **SetupSpec({n: f for n, f in ds.setup.fixtures.items() if f.type not in ("station", "camera", "target")},
                    ds.setup.distances).to_dict(),
        **stations_dict(ds),
        **cameras_dict(ds),
    }
    atomic_write_text(directory / "dataset.yaml", dump_yaml(meta))
    if ds.stations is None:
        write_csv(directory / "joints.csv", joint_columns(ds.joints_deg.shape[1]),
                  ([int(p), *map(float, q)] for p, q in zip(ds.pose_ids, ds.joints_deg)))
    else:
        write_csv(directory / "joints.csv", joint_columns(ds.joints_deg.shape[1]) + ["station"],
                  ([int(p), *map(float, q), st] for p, q, st in zip(ds.pose_ids, ds.joints_deg, ds.stations)))
    if ds.probes is not None:
        write_csv(directory / "probes.csv", POINT_COLUMNS, POINT.rows(ds.probes))
    files: dict = {}
    for kind in kinematic_types():
        obs = getattr(ds, kind.level, None)
        if obs is not None:  # types sharing a file (contacts) write its rows in file order
            files.setdefault(kind.file, (kind.columns, []))[1].extend(zip(obs.line.tolist(), kind.rows(obs)))
    for name, (columns, rows) in files.items():
        write_csv(directory / name, columns, (r for _, r in sorted(rows, key=lambda lr: lr[0])))
    if ds.truth is not None:
        truth: dict[str, Any] = {"parameters": {k: float(v) for k, v in ds.truth.items()}}
        if ds.truth_outliers:
            truth["outliers"] = [[int(p), str(b), int(i)] for p, b, i in ds.truth_outliers]
        atomic_write_text(directory / "truth.yaml", dump_yaml(truth))


def save_dataset(ds: Dataset, directory, overwrite: bool = False, extra_files=None) -> Path:
    """Write ``ds`` as a dataset directory, all at once (a temporary directory is renamed).

    ``extra_files`` maps further file names to their text (for example ``quality.csv``).

    Raises
    ------
    FgcalError
        If ``directory`` exists and ``overwrite`` is false.
    """
    directory = Path(directory)
    if directory.exists() and not overwrite:
        raise FgcalError(f"{directory}: already exists (use --force to replace it)")
    directory.parent.mkdir(parents=True, exist_ok=True)
    tmp = make_dir(directory)
    try:
        _write_into(ds, tmp)
        for name, text in (extra_files or {}).items():
            atomic_write_text(tmp / name, text)
        if directory.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{directory.name}.old.", dir=directory.parent))
            old.rmdir()
            directory.rename(old)
            tmp.rename(directory)
            shutil.rmtree(old, ignore_errors=True)
        else:
            tmp.rename(directory)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return directory
