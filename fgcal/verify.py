"""The paper's VERIFY: position and orientation errors of a calibrated model at other poses.

At each pose of a verification dataset the calibrated (and, for comparison, the nominal) model's
tool pose is compared with the measured pose, and with the true robot's where a simulated
dataset has ``truth.yaml``, through the differential displacement and orientation of eq. (17).
No I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .dataset import Dataset
from .errors import FgcalError
from .kinematics import forward
from .measure import measure_probes
from .model import SLOT_NAMES, RobotModel, slots_from_file_units
from .posefit import rigid_fit
from .result import CalibrationResult
from .transforms import pose_difference

__all__ = ["ErrorStats", "Comparison", "Verification", "measured_poses", "verify", "error_stats", "compare_poses"]


@dataclass
class ErrorStats:
    mean: float
    rms: float
    max: float


def error_stats(values) -> ErrorStats:
    v = np.asarray(values, dtype=float)
    if not v.size:
        return ErrorStats(float("nan"), float("nan"), float("nan"))
    return ErrorStats(float(v.mean()), float(np.sqrt(np.mean(v**2))), float(v.max()))


@dataclass
class Comparison:
    """Errors of one model against one reference, per pose (mm, deg) and summarised."""

    position_mm: np.ndarray
    orientation_deg: np.ndarray
    error_xyz_mm: np.ndarray | None = None  # (K, 3) reference - model, world frame

    def summary(self) -> dict:
        has_orientation = bool(np.isfinite(self.orientation_deg).any())  # not for position-only data
        return {"position_mm": vars(error_stats(self.position_mm)),
                "orientation_deg": vars(error_stats(self.orientation_deg)) if has_orientation else None}


@dataclass
class Verification:
    """Calibrated and nominal errors against the measurements, and against the truth if known."""

    pose_ids: np.ndarray
    after: Comparison
    before: Comparison
    truth_after: Comparison | None = None
    truth_before: Comparison | None = None
    reference: str = "measured poses"
    skipped: list[str] = field(default_factory=list)
    xyz_mm: np.ndarray | None = None  # (K, 3) reference tool positions, world frame
    joints_deg: np.ndarray | None = None  # (K, n_joints) joint readings

    def to_dict(self) -> dict:
        d = {"format": "fgcal-verify/1", "n_poses": int(len(self.pose_ids)), "reference": self.reference}
        d.update(self.after.summary())
        d["before"] = self.before.summary()
        if self.truth_after is not None:
            d["truth"] = self.truth_after.summary()
            d["truth"]["before"] = self.truth_before.summary()
        d["poses"] = [
            {"pose": int(p), "position_mm": float(a), "orientation_deg": float(o) if np.isfinite(o) else None,
             "before_position_mm": float(bp), "before_orientation_deg": float(bo) if np.isfinite(bo) else None}
            for p, a, o, bp, bo in zip(self.pose_ids, self.after.position_mm, self.after.orientation_deg,
                                       self.before.position_mm, self.before.orientation_deg)]
        for k, pose in enumerate(d["poses"]):  # additions of fgcal-verify/1 (readers may ignore them)
            if self.xyz_mm is not None:
                pose["xyz_mm"] = [float(v) for v in self.xyz_mm[k]]
            if self.after.error_xyz_mm is not None:
                pose["error_xyz_mm"] = [float(v) for v in self.after.error_xyz_mm[k]]
                pose["before_error_xyz_mm"] = [float(v) for v in self.before.error_xyz_mm[k]]
            if self.joints_deg is not None:
                pose["joints_deg"] = [float(v) for v in self.joints_deg[k]]
            if self.truth_after is not None:
                pose["truth_position_mm"] = float(self.truth_after.position_mm[k])
        d["skipped"] = self.skipped
        return d


def measured_poses(ds: Dataset):
    """Measured tool poses ``(pose_ids, T (K, 4, 4), skipped)`` from the richest level present.

    ``poses.csv`` as it is; otherwise a rigid fit of three or more ball centres (from
    ``centres.csv``, or fitted to ``probes.csv`` with the quality checks of ``fgcal measure``).
    """
    skipped = []
    if ds.poses is not None:
        return ds.poses.pose.copy(), ds.poses.matrices(), skipped
    if ds.centres is not None:
        ids, Ts = [], []
        sigma = ds.noise.centre_sigma if ds.noise.centre_sigma is not None else ds.noise.cmm_sigma
        for p in ds.pose_ids:
            sel = ds.centres.pose == p
            if sel.sum() < 3:
                skipped.append(f"pose {p}: {int(sel.sum())} centre(s), a pose needs 3")
                continue
            fit = rigid_fit(ds.tooling.offsets(ds.centres.ball[sel]), ds.centres.xyz[sel], sigma=sigma)
            if not fit.ok:
                skipped.append(f"pose {p}: {fit.status}")
                continue
            ids.append(p)
            Ts.append(fit.T)
        return np.array(ids, dtype=int), np.array(Ts).reshape(-1, 4, 4), skipped
    if ds.probes is not None:
        m = measure_probes(ds)
        skipped += [f"pose {q.pose}: {q.status}" for q in m.quality if q.ball == "*" and q.status != "ok"]
        return m.poses.pose.copy(), m.poses.matrices(), skipped
    raise FgcalError(f"{ds.path or 'dataset'}: no measurements to verify against")


def compare_poses(T_model, T_ref) -> Comparison:
    d, delta = pose_difference(T_ref, T_model)
    return Comparison(np.linalg.norm(d, axis=1), np.degrees(np.linalg.norm(delta, axis=1)), d)


def _compare_points(x_model, q, offsets, points, pose_of, ids) -> Comparison:
    """Per pose: RMS length of the point errors (measured - model), their mean vector; no orientation."""
    T = forward(x_model, q)
    d = points - (np.einsum("kij,kj->ki", T[:, :3, :3], offsets) + T[:, :3, 3])
    rows = [pose_of == p for p in ids]
    return Comparison(np.array([np.sqrt(np.mean(np.sum(d[r] ** 2, axis=1))) for r in rows]),
                      np.full(len(ids), np.nan), np.array([d[r].mean(axis=0) for r in rows]))


def _verify_points(result: CalibrationResult, ds: Dataset, model: RobotModel) -> Verification:
    """Position-only data (fewer than 3 balls, e.g. a tracker reflector): compare the points."""
    c = ds.centres
    ids = np.array([p for p in ds.pose_ids if np.any(c.pose == p)], dtype=int)
    q = ds.joints_rad[ds.row_of(c.pose)]
    off = ds.tooling.offsets(c.ball)
    after = _compare_points(result.slot_vector(), q, off, c.xyz, c.pose, ids)
    before = _compare_points(model.nominal, q, off, c.xyz, c.pose, ids)
    xyz = np.array([c.xyz[c.pose == p].mean(axis=0) for p in ids]).reshape(-1, 3)
    out = Verification(ids, after, before, reference="measured points", xyz_mm=xyz,
                       joints_deg=np.degrees(ds.joints_rad[ds.row_of(ids)]))
    if ds.truth is not None:
        truth = slots_from_file_units(np.array([ds.truth[n] for n in SLOT_NAMES]))
        T_true = forward(truth, q)
        p_true = np.einsum("kij,kj->ki", T_true[:, :3, :3], off) + T_true[:, :3, 3]
        out.truth_after = _compare_points(result.slot_vector(), q, off, p_true, c.pose, ids)
        out.truth_before = _compare_points(model.nominal, q, off, p_true, c.pose, ids)
    return out


def verify(result: CalibrationResult, ds: Dataset, model: RobotModel) -> Verification:
    """Compare the calibrated and nominal models with ``ds``'s measurements (and truth)."""
    if ds.poses is None and ds.centres is not None and len(ds.tooling.names) < 3:
        return _verify_points(result, ds, model)
    ids, T_meas, skipped = measured_poses(ds)
    if not len(ids):
        raise FgcalError(f"{ds.path or 'dataset'}: no pose could be measured to verify against")
    q = ds.joints_rad[ds.row_of(ids)]
    T_cal = forward(result.slot_vector(), q)
    T_nom = forward(model.nominal, q)
    out = Verification(ids, compare_poses(T_cal, T_meas), compare_poses(T_nom, T_meas), skipped=skipped,
                       xyz_mm=T_meas[:, :3, 3], joints_deg=np.degrees(q))
    if ds.truth is not None:
        truth = slots_from_file_units(np.array([ds.truth[n] for n in SLOT_NAMES]))
        T_true = forward(truth, q)
        out.truth_after = compare_poses(T_cal, T_true)
        out.truth_before = compare_poses(T_nom, T_true)
    return out
