"""Reading dataset directories (DESIGN.md section 3) with validation: ``dataset.yaml`` (the tool,
noise, robot, set-up), the truth, and the robot model a dataset names; the tables are read by
:mod:`fgcal.io.dataset_tables` and written by :mod:`fgcal.io.dataset_write` (both re-exported here).

Every problem ends in a :class:`~fgcal.errors.DatasetError` whose one-line message names the file
and the line (the header is line 1) or the pose.
"""
from __future__ import annotations

import logging
import os
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from fgcal.errors import DatasetError, FgcalError
from fgcal.io.dataset_tables import (
    MAX_JOINTS,
    POINT_COLUMNS,
    _contact_tables,
    _measurement_table,
    _pixel_table,
    _point_table,
    joint_columns,
    read_joints,
    read_joints_and_stations,
)
from fgcal.io.dataset_write import save_dataset, write_csv
from fgcal.io.setup_io import read_cameras, read_fixtures, read_stations, read_targets
from fgcal.measurements.contact import CONTACT_FILE
from fgcal.measurements.dataset import FORMAT, Dataset, Noise
from fgcal.measurements.pixels import PIXEL_FILE
from fgcal.measurements.setup import SetupSpec
from fgcal.measurements.types import kinematic_types, noise_keys
from fgcal.robots.model import EULER_FIELDS, LINK_FIELDS, RobotModel, Tooling
from fgcal.robots.robot_file import load_model
from fgcal.util.numbers import finite_number
from fgcal.util.yamlio import read_yaml, short_repr

__all__ = ["MAX_JOINTS", "POINT_COLUMNS", "dataset_model", "joint_columns", "load_dataset", "load_dataset_meta",
           "load_truth", "read_joints", "read_joints_and_stations", "robot_path", "save_dataset", "write_csv"]

log = logging.getLogger(__name__)

_SLOT_FIELDS = set(EULER_FIELDS) | set(LINK_FIELDS)

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
        if not finite_number(value):
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
        if not finite_number(value):
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
