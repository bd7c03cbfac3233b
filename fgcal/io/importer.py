"""From measurements of a robot (joints + a measured point or pose per row) to fgcal datasets.

The instrument's frame and the tool are not known when data arrive from a tracker or a camera:
the base (instrument to robot) and the tool (flange to the measured point or frame) are fitted to
the data (:func:`fgcal.measurements.handeye.fit_base_and_tool`, :func:`fgcal.measurements.handeye.fit_base_and_point`) and
written, with the robot's nominal links, as the dataset's own model file ``robot.yaml``. The
measured thing becomes a tool with one ball ``P`` of radius 0 at the tool frame's origin: full
poses go to ``poses.csv``, points to ``centres.csv``. A held-out fraction (whole groups of repeated
measurements) goes to a second dataset for verification. In five lines::

    from fgcal.io.importer import import_table
    from fgcal.io.table_io import ColumnSpec
    spec = ColumnSpec(joints=("q1", "q2", "q3", "q4", "q5", "q6"), joint_unit="rad", length_unit="m",
                      pose=("x", "y", "z", "qx", "qy", "qz", "qw"))
    import_table("export.csv", "ur10", spec, holdout=0.2).save("my-dataset")
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fgcal.errors import DatasetError, FgcalError
from fgcal.io.import_checks import check_fit
from fgcal.io.skipped import skipped_summary
from fgcal.io.table_io import ColumnSpec, Measurements, read_measurements
from fgcal.measurements.dataset import Dataset, Noise, PointObservations, PoseObservations
from fgcal.measurements.handeye import fit_base_and_point, fit_base_and_tool
from fgcal.robots.model import Tooling
from fgcal.robots.robot_file import load_model, model_to_dict
from fgcal.robots.transforms import matrix_to_quaternion
from fgcal.util.yamlio import dump_yaml

__all__ = ["DEFAULT_ORIENTATION_SIGMA", "DEFAULT_POSITION_SIGMA", "ImportResult", "import_table", "to_datasets"]

log = logging.getLogger(__name__)

DEFAULT_POSITION_SIGMA = 0.02  # mm: a laser tracker at a few metres
DEFAULT_ORIENTATION_SIGMA = 0.01  # deg: a 6-DoF probe
PROBE = "P"
MIN_ROWS = 4
MAX_FIT_ROWS = 20_000  # rows the base and tool start fit uses (evenly spread over the file)


@dataclass
class ImportResult:
    """Datasets made from measurements.

    Attributes
    ----------
    calibration : Dataset
    holdout : Dataset or None
    robot : dict
        The dataset's own robot model file (``robot.yaml``): nominal links, fitted base and tool.
    rms : float
        RMS distance (mm) between measured and modelled points after the base and tool fit.
    skipped : list of str
        Rows of the source left out, ``"line L: reason"``.
    rotation_rms_deg : float or None
        RMS angle (deg) between modelled and measured orientations after the fit (pose data).
    """

    calibration: Dataset
    holdout: Dataset | None
    robot: dict
    rms: float
    skipped: list
    rotation_rms_deg: float | None = None

    def save(self, out, overwrite: bool = False) -> list[Path]:
        """Write the calibration dataset to ``out`` and the held-out one to ``out-holdout``."""
        from fgcal.io.dataset_io import save_dataset

        out = Path(out)
        held_dir = out.with_name(out.name + "-holdout")
        if self.holdout is not None and held_dir.exists() and not overwrite:
            raise FgcalError(f"{held_dir}: already exists (use --force to replace it)")
        extra = {"robot.yaml": dump_yaml(self.robot)}
        written = [save_dataset(self.calibration, out, overwrite=overwrite, extra_files=extra)]
        if self.holdout is not None:
            written.append(save_dataset(self.holdout, held_dir, overwrite=overwrite, extra_files=extra))
        return written


def _noise(m: Measurements, position_sigma, orientation_sigma, joint_resolution) -> Noise:
    def pick(given, column, default):
        if given is not None:
            return float(given)
        return float(np.median(column)) if column is not None else default

    sp = pick(position_sigma, m.position_std, DEFAULT_POSITION_SIGMA)
    so = pick(orientation_sigma, m.rotation_std_deg, DEFAULT_ORIENTATION_SIGMA) if m.R is not None else None
    return Noise(cmm_sigma=sp, joint_resolution=float(joint_resolution), pose_position_sigma=sp if so is not None else None,
                 pose_orientation_sigma=so)


def to_datasets(m: Measurements, robot: str = "ur10", position_only: bool = False, holdout: float = 0.0,
                rng: np.random.Generator | None = None, position_sigma: float | None = None,
                orientation_sigma: float | None = None, joint_resolution: float = 0.0, name: str | None = None,
                provenance: dict | None = None, chain: dict | None = None,
                accept_fit: bool = False) -> ImportResult:
    """Calibration (and held-out) datasets with base and tool fitted to the measurements.

    Parameters
    ----------
    m : Measurements
    robot : str
        Built-in model name or model file of the measured robot (its nominal links are kept).
    position_only : bool
        Keep only the measured positions of pose data (``centres.csv``); base and tool are still
        fitted to the full poses.
    holdout : float
        Fraction of the groups (repeated measurements) written to the held-out dataset, in [0, 1).
    position_sigma, orientation_sigma : float, optional
        Measurement noise (mm per axis, deg); the median of the file's standard deviation columns
        when it has them, else :data:`DEFAULT_POSITION_SIGMA` and :data:`DEFAULT_ORIENTATION_SIGMA`.
    joint_resolution : float
        Resolution of the joint readings (deg); 0 for exact readings.
    name : str, optional
        Name of the written robot model (default ``ROBOT-imported``).
    provenance : dict, optional
        Added to each dataset's provenance.
    chain : dict, optional
        ``{"base": LINK, "tip": LINK}``: the chain of a URDF with more than one leaf.
    accept_fit : bool
        Import even when the nominal model's fit looks like a unit or convention mistake
        (:func:`fgcal.io.import_checks.check_fit`); the findings are logged as warnings.

    Raises
    ------
    DatasetError
        When the fit looks like such a mistake (and ``accept_fit`` is false): the message names
        the likely cause and the option that fixes it.
    """
    if not 0 <= holdout < 1:
        raise FgcalError("--holdout is a fraction from 0 to below 1")
    model = load_model(robot, chain=chain)
    n_joints = model.joint_limits.shape[0]
    if m.joints_rad.shape[1] != n_joints:
        raise DatasetError(f"{m.source}: {m.joints_rad.shape[1]} joint columns, robot {model.name} has {n_joints} joints")
    points = m.R is None or position_only
    ids = m.line.astype(int)
    groups = m.groups()
    hold = np.zeros(len(ids), dtype=bool)
    if holdout > 0:
        rng = rng or np.random.default_rng(0)
        unique = np.unique(groups)
        n_held = int(round(holdout * len(unique)))
        if n_held == 0:
            raise FgcalError(f"--holdout {holdout:g} of {len(unique)} row group(s) holds out none; give at least "
                             f"{0.5 / len(unique):.3g} (or 0 for no hold-out set)")
        hold = np.isin(groups, rng.choice(unique, size=n_held, replace=False))
    if (~hold).sum() < MIN_ROWS:
        raise DatasetError(f"{m.source}: {(~hold).sum()} rows to calibrate from; the base and tool fit needs at least "
                           f"{MIN_ROWS}")
    # Fitted on the calibration rows only, so the held-out rows stay unseen; measured orientations
    # are used for the start even when only positions are kept.
    rows_fit = np.flatnonzero(~hold)
    if len(rows_fit) > MAX_FIT_ROWS:  # 12 parameters: evenly spread rows fit them as well, in bounded memory
        rows_fit = rows_fit[np.linspace(0, len(rows_fit) - 1, MAX_FIT_ROWS).round().astype(int)]
    if m.R is None:
        slots, rms = fit_base_and_point(model, m.joints_rad[rows_fit], m.xyz[rows_fit])
    else:  # poses of the fit's rows only ((N, 4, 4) of every row is 128 bytes a row)
        slots, rms = fit_base_and_tool(model, m.joints_rad[rows_fit], m.subset(rows_fit).T)
    fit = check_fit(model, slots, m.joints_rad[rows_fit], m.xyz[rows_fit], None if m.R is None else m.R[rows_fit])
    log.info("base and tool fitted to %d rows: RMS %.3g mm%s", len(rows_fit), rms,
             "" if fit.rotation_rms_deg is None else f", {fit.rotation_rms_deg:.3g} deg")
    if not fit.ok:
        if not accept_fit:
            raise DatasetError(f"{m.source}: " + "; ".join(fit.problems)
                               + " (--accept-fit imports it anyway)")
        for problem in fit.problems:
            log.warning("%s: %s (imported: --accept-fit)", m.source, problem)
    model_dict = model_to_dict(model, slots)
    model_dict["name"] = name or f"{model.name}-imported"
    model_dict["description"] = (f"{model.name} nominal links; base (instrument to robot) and tool (flange to the "
                                 f"measured {'point' if m.R is None else 'frame'}) fitted to {len(rows_fit)} rows of "
                                 f"{Path(m.source).name} (RMS {rms:.3g} mm before calibration)")
    model_dict.pop("volume", None)
    model_dict["tooling"] = {"radius": 0.0, "balls": {PROBE: [0.0, 0.0, 0.0]}}
    tooling = Tooling(0.0, {PROBE: np.zeros(3)})
    noise = _noise(m, position_sigma, orientation_sigma, joint_resolution)
    if points:
        noise = Noise(noise.cmm_sigma, noise.joint_resolution)

    def make(mask, part):
        prov = {"source": m.source, "part": part, "rows": int(mask.sum()), "skipped": skipped_summary(m.skipped),
                "note": "pose id = line in the source file", **(provenance or {})}
        ds = Dataset(robot="robot.yaml", tooling=tooling, noise=noise, provenance=prov, pose_ids=ids[mask],
                     joints_deg=np.degrees(m.joints_rad[mask]))
        if points:
            ds.centres = PointObservations(ids[mask], np.full(int(mask.sum()), PROBE), m.xyz[mask])
        else:
            ds.poses = PoseObservations(ids[mask], m.xyz[mask], matrix_to_quaternion(m.R[mask]))
        return ds

    return ImportResult(make(~hold, "calibration"), make(hold, "holdout") if hold.any() else None, model_dict, rms,
                        list(m.skipped), fit.rotation_rms_deg)


def import_table(path, robot: str, spec: ColumnSpec, **options) -> ImportResult:
    """:func:`read_measurements` then :func:`to_datasets` (``options`` are the latter's)."""
    m = read_measurements(path, spec)
    prov = {"importer": "fgcal import csv", "columns": spec.describe(), **options.pop("provenance", {})}
    return to_datasets(m, robot, provenance=prov, **options)
