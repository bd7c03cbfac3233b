"""Import of the Landgraf et al. (2021) UR10 laser-tracker series: a preset of the generic importer.

A series file (``;``-separated, decimal comma) holds per row six joint readings (rad) and the
6-D probe pose measured by the tracker: position (mm) and intrinsic X-Y-Z Euler angles (deg),
in some series with per-axis standard deviations (used for the noise when present). The probe
frame is the tool. Base and tool are fitted to the data and written with the nominal UR10 links
as the dataset's own model file (:func:`fgcal.io.importer.to_datasets`). Rows with a missing or
unreadable value are reported and skipped; repeated configurations (the same commanded goal)
are kept as repeated measurements, and a held-out split keeps them together.
"""
from __future__ import annotations

import numpy as np

from fgcal.io.importer import to_datasets
from fgcal.io.table_io import AngleUnit, ColumnSpec, LengthUnit, Measurements, read_measurements

__all__ = ["LANDGRAF", "LandgrafSeries", "read_series", "series_to_datasets"]

JOINTS = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint")
POSITION = ("measurement_x", "measurement_y", "measurement_z")
ROTATION = ("measurement_rx", "measurement_ry", "measurement_rz")
POS_STD = ("measurement_std_x", "measurement_std_y", "measurement_std_z")
ROT_STD = ("measurement_std_rx", "measurement_std_ry", "measurement_std_rz")
GOAL = ("Goal x", "Goal y", "Goal z", "Goal roll", "Goal pitch", "Goal yaw")
CITATION = "Landgraf, Ernst, Schleth, Fabritius, Huber (2021), IEEE CASE, pp. 468-474"

#: The series' columns: standard deviations and goals are used when the file has them.
LANDGRAF = ColumnSpec(joints=JOINTS, joint_unit=AngleUnit.RAD, pose=POSITION + ROTATION, euler_convention="XYZ",
                      rotation_unit=AngleUnit.DEG, length_unit=LengthUnit.MM, position_std=POS_STD,
                      rotation_std=ROT_STD, group=GOAL, delimiter=";", decimal_comma=True, label="Landgraf series")

LandgrafSeries = Measurements


def read_series(path) -> Measurements:
    """Read a series file; raises :class:`DatasetError` naming the file for a wrong format."""
    return read_measurements(path, LANDGRAF)


def series_to_datasets(series: Measurements, source: str, position_only: bool = False, holdout: float = 0.0,
                       rng: np.random.Generator | None = None):
    """Datasets from a series: ``(calibration, holdout or None, robot model dict, fit rms)``.

    The held-out fraction is drawn by groups of repeated goals, so no configuration is on both
    sides. With ``position_only`` the probe's position alone is written, as ``centres.csv`` of a
    single ball ``P`` at the probe origin.
    """
    series.source = str(source)
    prov = {"importer": "fgcal import landgraf", "citation": CITATION,
            "note": "pose id = line in the source file; rotations intrinsic X-Y-Z Euler (deg) in the file"}
    r = to_datasets(series, "ur10", position_only=position_only, holdout=holdout, rng=rng, name="ur10-landgraf",
                    provenance=prov)
    return r.calibration, r.holdout, r.robot, r.rms
