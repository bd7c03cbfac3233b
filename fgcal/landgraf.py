"""Import of the Landgraf et al. (2021) UR10 laser-tracker series into an fgcal dataset.

The series file (``;``-separated, decimal comma) holds per row six joint readings (rad) and the
6-D probe pose measured by the tracker: position (mm) and intrinsic X-Y-Z Euler angles (deg),
with per-axis standard deviations. The probe frame is the tool. The tracker-to-robot (base) and
flange-to-probe (tool) transforms are not given: they are fitted to the data
(:func:`fgcal.initial.fit_base_and_tool`) and written, with the nominal UR10 links, as the
dataset's own robot model file. Rows with a missing or unreadable value are reported and skipped;
repeated configurations (the same commanded goal) are kept as repeated measurements, and a
held-out split keeps them together.
"""
from __future__ import annotations

import csv
import io
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .dataset import Dataset, Noise, PointObservations, PoseObservations
from .errors import DatasetError
from .initial import fit_base_and_tool
from .model import Tooling
from .robot_file import load_model, model_to_dict
from .transforms import matrix_to_quaternion, rot

__all__ = ["LandgrafSeries", "read_series", "series_to_datasets"]

log = logging.getLogger(__name__)

JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]
POSITION = ["measurement_x", "measurement_y", "measurement_z"]
ROTATION = ["measurement_rx", "measurement_ry", "measurement_rz"]
POS_STD = ["measurement_std_x", "measurement_std_y", "measurement_std_z"]
ROT_STD = ["measurement_std_rx", "measurement_std_ry", "measurement_std_rz"]
GOAL = ["Goal x", "Goal y", "Goal z", "Goal roll", "Goal pitch", "Goal yaw"]
REQUIRED = JOINTS + POSITION + ROTATION + POS_STD + ROT_STD + GOAL


@dataclass
class LandgrafSeries:
    """The usable rows of a series file.

    Attributes
    ----------
    line : ndarray of int, shape (N,)
        Line of each row in the file (header = 1); also the pose id.
    joints_rad : ndarray, shape (N, 6)
    T : ndarray, shape (N, 4, 4)
        Measured probe poses (tracker frame, mm).
    position_std : ndarray, shape (N, 3)
        Per-axis standard deviation (mm).
    rotation_std_deg : ndarray, shape (N, 3)
    goal : ndarray, shape (N, 6)
        Commanded goal (m, rad): rows with the same goal are repeated measurements.
    skipped : list of str
    """

    line: np.ndarray
    joints_rad: np.ndarray
    T: np.ndarray
    position_std: np.ndarray
    rotation_std_deg: np.ndarray
    goal: np.ndarray
    temperature: np.ndarray
    skipped: list[str] = field(default_factory=list)

    def groups(self) -> np.ndarray:
        """Group id per row: rows with the same commanded goal (rounded to 1e-6) share one."""
        keys = {}
        return np.array([keys.setdefault(tuple(np.round(g, 6)), len(keys)) for g in self.goal], dtype=int)


def _value(text: str):
    t = text.strip().replace(",", ".")
    if not t or t.lower() in ("nan", "na", "none", "null"):
        return None
    v = float(t)
    return v if math.isfinite(v) else None


def read_series(path) -> LandgrafSeries:
    """Read a series file; raises :class:`DatasetError` naming the file for a wrong format."""
    from .yamlio import read_text_file

    path = Path(path)
    text = read_text_file(path, DatasetError).removeprefix("\ufeff")
    reader = csv.reader(io.StringIO(text, newline=""), delimiter=";")
    try:
        return _parse_series(path, reader)
    except csv.Error as exc:
        raise DatasetError(f"{path}: line {reader.line_num}: {exc}") from None


def _parse_series(path: Path, reader) -> LandgrafSeries:
    header = next(reader, None)
    if header is None:
        raise DatasetError(f"{path}: empty file")
    header = [h.strip() for h in header]
    missing = [c for c in REQUIRED if c not in header]
    if missing:
        raise DatasetError(f"{path}: line 1: not a Landgraf series file: missing column(s) {', '.join(missing)}")
    col = {h: i for i, h in enumerate(header)}
    out = {k: [] for k in ("line", "q", "T", "ps", "rs", "goal", "temp")}
    skipped = []
    for record in reader:
        line = reader.line_num
        if not record or all(not c.strip() for c in record):
            continue
        if len(record) < len(header):
            skipped.append(f"line {line}: {len(record)} fields, expected {len(header)}")
            continue
        values, bad = {}, []
        for name in REQUIRED:
            try:
                v = _value(record[col[name]])
            except ValueError:
                v = None
            if v is None:
                bad.append(name)
            values[name] = v
        if bad:
            skipped.append(f"line {line}: missing or unreadable {', '.join(bad)}")
            continue
        R = (rot(0, math.radians(values["measurement_rx"])) @ rot(1, math.radians(values["measurement_ry"]))
             @ rot(2, math.radians(values["measurement_rz"])))  # intrinsic X-Y-Z
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = [values[c] for c in POSITION]
        out["line"].append(line)
        out["q"].append([values[c] for c in JOINTS])
        out["T"].append(T)
        out["ps"].append([values[c] for c in POS_STD])
        out["rs"].append([values[c] for c in ROT_STD])
        out["goal"].append([values[c] for c in GOAL])
        temp = _value(record[col["measurement_temperature"]]) if "measurement_temperature" in col else None
        out["temp"].append(np.nan if temp is None else temp)
    if not out["line"]:
        raise DatasetError(f"{path}: no usable rows ({len(skipped)} skipped)")
    return LandgrafSeries(np.array(out["line"]), np.array(out["q"]), np.array(out["T"]), np.array(out["ps"]),
                          np.array(out["rs"]), np.array(out["goal"]), np.array(out["temp"]), skipped)


def series_to_datasets(series: LandgrafSeries, source: str, position_only: bool = False, holdout: float = 0.0,
                       rng: np.random.Generator | None = None):
    """Datasets from a series: ``(calibration, holdout or None, robot model dict, fit rms)``.

    The held-out fraction is drawn by groups of repeated goals, so no configuration is on both
    sides. With ``position_only`` the probe's position alone is written, as ``centres.csv`` of a
    single ball ``P`` at the probe origin.
    """
    ids = series.line.astype(int)
    groups = series.groups()
    hold = np.zeros(len(ids), dtype=bool)
    if holdout > 0:
        rng = rng or np.random.default_rng(0)
        unique = np.unique(groups)
        chosen = rng.choice(unique, size=int(round(holdout * len(unique))), replace=False)
        hold = np.isin(groups, chosen)
    model = load_model("ur10")
    # Fitted on the calibration rows only, so the held-out rows stay unseen.
    slots, rms = fit_base_and_tool(model, series.joints_rad[~hold], series.T[~hold])
    model_dict = model_to_dict(model, slots)
    model_dict["name"] = "ur10-landgraf"
    model_dict["description"] = ("UR10 nominal links; base (tracker to robot) and tool (flange to probe) fitted "
                                 f"to {int((~hold).sum())} measured poses of {Path(source).name} "
                                 f"(RMS {rms:.3g} mm before calibration)")
    model_dict.pop("tooling", None)
    model_dict.pop("volume", None)
    model_dict["tooling"] = {"radius": 0.0, "balls": {"P": [0.0, 0.0, 0.0]}}
    noise = Noise(cmm_sigma=float(np.median(series.position_std)), joint_resolution=0.0,
                  pose_position_sigma=float(np.median(series.position_std)),
                  pose_orientation_sigma=float(np.median(series.rotation_std_deg)))
    tooling = Tooling(0.0, {"P": np.zeros(3)})

    def make(mask, part):
        prov = {"source": str(source), "importer": "fgcal import landgraf", "part": part,
                "rows": int(mask.sum()), "skipped": series.skipped,
                "note": "pose id = line in the source file; rotations intrinsic X-Y-Z Euler (deg) in the file",
                "citation": "Landgraf, Ernst, Schleth, Fabritius, Huber (2021), IEEE CASE, pp. 468-474"}
        T = series.T[mask]
        ds = Dataset(robot="robot.yaml", tooling=tooling, noise=noise, provenance=prov, pose_ids=ids[mask],
                     joints_deg=np.degrees(series.joints_rad[mask]))
        if position_only:
            ds.centres = PointObservations(ids[mask], np.array(["P"] * int(mask.sum())), T[:, :3, 3])
        else:
            ds.poses = PoseObservations(ids[mask], T[:, :3, 3], matrix_to_quaternion(T[:, :3, :3]))
        return ds

    calib = make(~hold, "calibration")
    held = make(hold, "holdout") if hold.any() else None
    return calib, held, model_dict, rms
