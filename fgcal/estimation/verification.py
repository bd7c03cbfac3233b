"""The paper's VERIFY: position and orientation errors of a calibrated model at other poses.

At each pose of a verification dataset the calibrated (and, for comparison, the nominal) model's
tool pose is compared with the measured pose, and with the true robot's where a simulated
dataset has ``truth.yaml``, through the differential displacement and orientation of eq. (17).
No I/O here.
"""
from __future__ import annotations

import logging

import numpy as np

from fgcal.errors import FgcalError
from fgcal.estimation.joint_errors import corrected_joints, outside_region
from fgcal.estimation.result import CalibrationResult
from fgcal.estimation.verification_checks import check_same_robot, check_verification
from fgcal.estimation.verification_result import Comparison, ErrorStats, ToolPointErrors, Verification, error_stats
from fgcal.estimation.verify_pixels import verify_pixels
from fgcal.measurements.dataset import Dataset
from fgcal.measurements.measure import measure_probes
from fgcal.measurements.posefit import rigid_fits_at_pooled_noise
from fgcal.measurements.types import kinematic_levels
from fgcal.robots.kinematics import tool_points
from fgcal.robots.model import RobotModel
from fgcal.robots.transforms import pose_difference

log = logging.getLogger(__name__)

__all__ = [
    "Comparison",
    "ErrorStats",
    "ToolPointErrors",
    "Verification",
    "check_same_robot",
    "check_verification",
    "compare_points",
    "compare_poses",
    "error_stats",
    "measured_points",
    "measured_poses",
    "verify",
]


def measured_poses(ds: Dataset):
    """Measured tool poses ``(pose_ids, T (K, 4, 4), skipped)`` from the richest level present.

    ``poses.csv`` as it is; otherwise a rigid fit of three or more ball centres (from
    ``centres.csv``, or fitted to ``probes.csv`` with the quality checks of ``fgcal measure``).
    """
    skipped: list = []
    if ds.poses is not None:
        return ds.poses.pose.copy(), ds.poses.matrices(), skipped
    if ds.centres is not None:
        ids, Ts = [], []
        sigma = ds.noise.centre_sigma if ds.noise.centre_sigma is not None else ds.noise.cmm_sigma
        poses, pairs = [], []
        for p in ds.pose_ids:
            sel = ds.centres.pose == p
            if sel.sum() < 3:
                skipped.append(f"pose {p}: {int(sel.sum())} centre(s), a pose needs 3")
                continue
            poses.append(p)
            pairs.append((ds.tooling.offsets(ds.centres.ball[sel]), ds.centres.xyz[sel]))
        # Each pose's ball triangle judged at the noise the other poses' fits show (the declared
        # sigma can understate the tracker's: a valid pose was skipped at 0.049 mm against 0.047).
        fits, pooled = rigid_fits_at_pooled_noise(pairs, sigma)
        if pooled is not None and sigma and abs(pooled / sigma - 1) > 0.2:
            log.info("%s: the ball triangles fit at %.3g mm per coordinate (declared %.3g mm): each pose is "
                     "judged at the other poses' noise", ds.path or "dataset", pooled, sigma)
        for p, fit in zip(poses, fits):
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


def compare_points(T_model, offsets_by_pose, points_by_pose) -> Comparison:
    """Point errors: per pose, the RMS distance (mm) of its measured points from the model's."""
    d = [w - tool_points(T[None], o)[0] for T, o, w in zip(T_model, offsets_by_pose, points_by_pose)]
    err = np.array([np.sqrt(np.mean(np.sum(e**2, axis=1))) for e in d])
    return Comparison(err, None, np.array([e.mean(axis=0) for e in d]).reshape(-1, 3))


def measured_points(ds: Dataset):
    """Measured points per pose: ``(pose_ids, offsets [(B, 3)], world [(B, 3)], skipped)``.

    Ball centres from ``centres.csv``, or fitted to ``probes.csv`` (with ``fgcal measure``'s
    quality checks) when there are no centres.
    """
    skipped = []
    if ds.centres is not None:
        centres = ds.centres
    elif ds.probes is not None:
        m = measure_probes(ds)
        skipped += [f"pose {q.pose} ball {q.ball}: {q.status}" for q in m.quality if q.status != "ok"]
        centres = m.centres
    else:
        raise FgcalError(f"{ds.path or 'dataset'}: no measured points to verify against")
    ids, offs, pts = [], [], []
    for p in ds.pose_ids:
        sel = centres.pose == p
        if not sel.any():
            continue
        ids.append(p)
        offs.append(ds.tooling.offsets(centres.ball[sel]))
        pts.append(centres.xyz[sel])
    return np.array(ids, dtype=int), offs, pts, skipped


def _full_pose_data(ds: Dataset) -> bool:
    """Every measured pose has a full pose (poses.csv, or three or more balls)."""
    if ds.poses is not None:
        return True
    obs = ds.centres if ds.centres is not None else ds.probes
    if obs is None:
        return False
    balls: dict[int, set] = {}
    for p, b in zip(obs.pose.tolist(), obs.ball.tolist()):
        balls.setdefault(p, set()).add(b)
    return bool(balls) and min(len(v) for v in balls.values()) >= 3


def verify(result: CalibrationResult, ds: Dataset, model: RobotModel) -> Verification:
    """Compare the calibrated and nominal models with ``ds``'s measurements (and truth).

    Full poses are compared where every pose has one (poses.csv, or three or more balls);
    otherwise the measured points (ball centres, reflector positions) are.
    """
    slots = result.slot_vector(model)
    truth = None
    if ds.truth is not None:
        missing = [n for n in model.slot_names if n not in ds.truth]
        if missing:
            raise FgcalError(f"{ds.path or 'dataset'}: truth.yaml has no value for {', '.join(missing[:5])}")
        truth = model.slots_from_file_units(np.array([ds.truth[n] for n in model.slot_names]))
    if ds.station_centres is not None:
        ds = _stations_to_world(result, ds)
    if ds.levels() and set(ds.levels()) <= {"contacts", "plane_contacts"}:
        return _verify_contacts(result, ds, model, slots)
    if ds.levels() == ["pixels"]:  # camera data: the reprojection error of held-out images (px)

        return verify_pixels(result, ds, model, slots)
    if not ({"probes", "centres", "poses"} & set(ds.levels())):  # another type: verified by its own metric
        kinds = kinematic_levels(ds.levels())
        if kinds:
            return _verify_kind(kinds[0], ds, model, slots, truth)
    if _full_pose_data(ds):
        ids, T_meas, skipped = measured_poses(ds)
        reference = "measured poses"
    else:
        ids, offs, pts, skipped = measured_points(ds)
        reference = "measured points"
    named = {s.split(":", 1)[0].split(" ball ")[0] for s in skipped}
    have = set(np.asarray(ids).tolist())
    skipped += [f"pose {p}: no measurement of this pose" for p in ds.pose_ids.tolist()
                if p not in have and f"pose {p}" not in named]
    if not len(ids):
        raise FgcalError(f"{ds.path or 'dataset'}: no pose could be measured to verify against")
    q = model.joints_to_internal(ds.joints_deg[ds.row_of(ids)])
    for message in outside_region(result, q):
        log.warning("%s: %s", ds.path or "dataset", message)
    T_cal = model.forward(slots, corrected_joints(result, q, model))  # joint-error block, if any
    T_nom = model.forward(model.nominal, q)
    if reference == "measured poses":
        out = Verification(ids, compare_poses(T_cal, T_meas), compare_poses(T_nom, T_meas), skipped=skipped,
                           xyz_mm=T_meas[:, :3, 3])
    else:
        out = Verification(ids, compare_points(T_cal, offs, pts), compare_points(T_nom, offs, pts),
                           reference=reference, skipped=skipped,
                           xyz_mm=np.array([w.mean(axis=0) for w in pts]).reshape(-1, 3))
    out.robot = result.model().name
    out.joints_deg = np.asarray(ds.joints_deg[ds.row_of(ids)], dtype=float)
    if truth is not None:
        T_true = model.forward(truth, q)
        if reference == "measured poses":
            out.truth_after, out.truth_before = compare_poses(T_cal, T_true), compare_poses(T_nom, T_true)
        else:  # position-only data say nothing of what they cannot see: compare the measured points
            true_pts = [tool_points(T[None], o)[0] for T, o in zip(T_true, offs)]
            out.truth_after = compare_points(T_cal, offs, true_pts)
            out.truth_before = compare_points(T_nom, offs, true_pts)
    return out


def _stations_to_world(result: CalibrationResult, ds: Dataset) -> Dataset:
    """A copy of ``ds`` whose centres measured from other stations are in the world frame, by the
    stations the calibration found (``result.setup``)."""
    from dataclasses import replace as _replace

    from fgcal.measurements.point import PointObservations
    from fgcal.robots.transforms import euler_zyx_trans

    found = (result.setup or {}).get("estimated", {})
    sc = ds.station_centres
    if sc is None:
        return ds
    xyz = sc.xyz.copy()
    for name in dict.fromkeys(sc.station.tolist()):
        pose = found.get(name, {}).get("pose") if found.get(name, {}).get("type") == "station" else None
        if pose is None:
            known = ", ".join(n for n, v in found.items() if v.get("type") == "station") or "none"
            raise FgcalError(f"{ds.path or 'dataset'}: station {name} is not a station of the calibration "
                             f"(its stations: {known}); verify from stations it found")
        T = euler_zyx_trans(*np.radians(pose[:3]), *pose[3:])
        sel = sc.station == name
        xyz[sel] = xyz[sel] @ T[:3, :3].T + T[:3, 3]
    parts = [o for o in (ds.centres,) if o is not None]
    whole = PointObservations(np.concatenate([*(o.pose for o in parts), sc.pose]),
                              np.concatenate([*(o.ball for o in parts), sc.ball]),
                              np.vstack([*(o.xyz for o in parts), xyz]),
                              np.concatenate([*(o.line for o in parts), sc.line]))
    return _replace(ds, centres=whole, station_centres=None)


def _verify_contacts(result: CalibrationResult, ds: Dataset, model: RobotModel, slots) -> Verification:
    """Contacts: per contact, its ball centre's distance from its fixture's refitted point or plane
    (the pose's position error), and per fixture and known distance the consistency
    (:mod:`fgcal.estimation.consistency`), at the calibrated and nominal models."""
    from fgcal.estimation.consistency import contact_consistency

    parts = [getattr(ds, lv) for lv in ("contacts", "plane_contacts") if getattr(ds, lv) is not None]
    pose = np.concatenate([p.pose for p in parts])
    ball = np.concatenate([p.ball for p in parts])
    fixture = np.concatenate([p.fixture for p in parts])
    q = model.joints_to_internal(ds.joints_deg[ds.row_of(pose)])
    for message in outside_region(result, q):
        log.warning("%s: %s", ds.path or "dataset", message)

    def check(x, joints):
        return contact_consistency(model, x, joints, pose, ball, fixture, ds.tooling.offsets, ds.setup,
                                   ds.tooling.radius)

    after, before = check(slots, corrected_joints(result, q, model)), check(model.nominal, q)
    out = Verification(pose, Comparison(after.distance_mm, None), Comparison(before.distance_mm, None),
                       reference="contacts (consistency at each fixture)", robot=result.model().name,
                       joints_deg=np.asarray(ds.joints_deg[ds.row_of(pose)], dtype=float))
    out.contacts = {"after": after.summary(), "before": before.summary()}
    return out


def _verify_kind(kind, ds: Dataset, model: RobotModel, slots, truth) -> Verification:
    """Verification by a measurement type's own metric (:meth:`KinematicMeasurement.metric`): per
    pose, the RMS over its measurements of the type's error at the calibrated and nominal models
    (for a ballbar: ``|model ball - pivot| - measured length``, mm)."""
    obs = getattr(ds, kind.level)
    ids = np.array([p for p in ds.pose_ids if np.any(obs.pose == p)], dtype=int)
    q = model.joints_to_internal(ds.joints_deg[ds.row_of(ids)])
    terms = kind.terms(obs, ds.tooling, {int(p): i for i, p in enumerate(ids)})
    everything = np.arange(len(model.slot_names))

    count = np.bincount(terms.pose, minlength=len(ids))

    def rms_per_pose(values):
        return np.sqrt(np.bincount(terms.pose, weights=values**2, minlength=len(ids)) / count)

    def errors(x, data):
        distance, angle = kind.metric(kind.error(x, q[terms.pose], data, everything, x, model.chain)[0])
        return Comparison(rms_per_pose(distance), None if angle is None else rms_per_pose(angle))

    out = Verification(ids, errors(slots, terms.data), errors(model.nominal, terms.data),
                       reference=f"measured {kind.title}", robot=model.name,
                       joints_deg=np.asarray(ds.joints_deg[ds.row_of(ids)], dtype=float))
    if truth is not None:  # the true robot's noiseless measurement as the reference
        true_data = kind.design_data(model.forward(truth, q[terms.pose]), terms.data[0] if kind.per_ball
                                     else np.zeros((len(terms), 3)))
        out.truth_after, out.truth_before = errors(slots, true_data), errors(model.nominal, true_data)
    return out
