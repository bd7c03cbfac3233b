"""The two-stage measurement: probe points -> ball centres -> tool poses, with quality checks.

This is the paper's path (sections 2.3 and 4). Each ball's probe points are fitted with a
sphere; fits whose residual is too large for the CMM's noise are flagged and left out; a pose is
computed from the good balls (least-squares rigid fit, or the paper's ``T = P' P^-1``) and
rejected, with the reason, when it fails its checks. Nothing is dropped without a line in the
quality table. No I/O here (see :func:`quality_csv` for the table's text).
"""
from __future__ import annotations

import io
import logging
from dataclasses import dataclass, field, replace

import numpy as np

from fgcal.errors import FgcalError
from fgcal.measurements.dataset import Dataset, PointObservations, PoseObservations
from fgcal.measurements.posefit import check_homogeneous, nearest_rotation, paper_pose, rigid_fit
from fgcal.measurements.spherefit import fit_sphere, fit_spheres_checked
from fgcal.robots.transforms import matrix_to_quaternion

__all__ = ["Measurement", "QualityRow", "derived_dataset", "measure_probes", "quality_csv"]

log = logging.getLogger(__name__)

POSE_ROW = "*"  # the ball column of a pose's own quality row


@dataclass(frozen=True)
class QualityRow:
    """One line of ``quality.csv``: a ball's sphere fit, or (``ball == "*"``) a pose."""

    pose: int
    ball: str
    rms_residual_mm: float
    status: str


@dataclass
class Measurement:
    """Ball centres and poses derived from probe points.

    Attributes
    ----------
    centres : PointObservations
        Centres of the balls whose fit passed.
    centre_covariance : ndarray, shape (M, 3, 3)
    poses : PoseObservations
        Accepted poses.
    pose_covariance : ndarray, shape (K, 6, 6)
        Of ``[w, v]`` (world rotation vector, rad; tool origin, mm).
    quality : list of QualityRow
    method : str
    """

    centres: PointObservations
    centre_covariance: np.ndarray
    poses: PoseObservations
    pose_covariance: np.ndarray
    quality: list[QualityRow] = field(default_factory=list)
    method: str = "svd"

    def flagged(self) -> list[QualityRow]:
        return [q for q in self.quality if q.status != "ok"]


def measure_probes(ds: Dataset, method: str = "svd", free_radius: bool = False, threshold: float | None = None,
                   tolerance: float | None = None, min_balls: int = 3) -> Measurement:
    """Fit every ball of ``ds.probes`` and compute a pose per pose id.

    Parameters
    ----------
    ds : Dataset
        Must have probe points.
    method : {"svd", "paper"}
        Least-squares rigid fit of all good balls, or the paper's ``P' P^-1`` on three.
    free_radius : bool
        Fit each ball's radius too (default: the tool's known radius).
    threshold : float, optional
        RMS residual (mm) that flags a sphere fit; by default the chi-square bound for the
        dataset's CMM noise at 0.1% false alarm (the paper used 0.001 mm with its CMM).
    tolerance : float, optional
        For the paper's method: the largest allowed error of eqs. 19-21; by default ten times
        the centres' noise over the smallest ball spacing.
    """
    if ds.probes is None:
        raise FgcalError(f"{ds.path or 'dataset'}: no probes.csv to measure")
    if method not in ("svd", "paper"):
        raise FgcalError(f"unknown pose method {method!r} (svd, paper)")
    sigma = ds.noise.cmm_sigma
    radius = None if free_radius else ds.tooling.radius
    probes = ds.probes
    quality: list[QualityRow] = []
    c_pose, c_ball, c_xyz, c_cov, c_line = [], [], [], [], []
    good: dict[int, list[tuple[str, np.ndarray, np.ndarray]]] = {}
    order = np.lexsort((probes.ball, probes.pose))  # stable: a ball's points keep their file order
    sp, sb = probes.pose[order], probes.ball[order]
    starts = np.flatnonzero(np.r_[True, (sp[1:] != sp[:-1]) | (sb[1:] != sb[:-1])]) if len(order) else np.zeros(0, int)
    bounds = np.r_[starts, len(order)]
    keys = [(int(sp[i]), str(sb[i])) for i in starts]
    n_probed_of: dict[int, int] = {}
    for pose, _ in keys:
        n_probed_of[pose] = n_probed_of.get(pose, 0) + 1
    need = 4 if free_radius else 3
    fits = {}
    if radius is not None:  # all balls at once (vectorised by point count), same checks
        fittable = [k for k in range(len(keys)) if bounds[k + 1] - bounds[k] >= need]
        fits = dict(zip(fittable, fit_spheres_checked([probes.xyz[order[bounds[k]:bounds[k + 1]]] for k in fittable],
                                                      radius, sigma, threshold)))
    for k, (pose, ball) in enumerate(keys):
        sel = order[bounds[k]:bounds[k + 1]]
        pts = probes.xyz[sel]
        if len(pts) < need:
            quality.append(QualityRow(pose, ball, float("nan"), f"too few probe points ({len(pts)}; need {need})"))
            continue
        fit = fits.get(k) or fit_sphere(pts, radius=radius, sigma=sigma, threshold=threshold)
        status = fit.status
        assert probes.line is not None
        lines = probes.line[sel]
        if fit.suspect is not None and fit.ok is False and "outlier: point" in status:
            status += f" [probes.csv line {lines[fit.suspect]}]"
        elif not fit.ok and lines.any():
            status += f" [probes.csv lines {', '.join(map(str, lines))}]"
        quality.append(QualityRow(pose, ball, fit.rms, status))
        if fit.ok:
            c_pose.append(pose)
            c_ball.append(ball)
            c_xyz.append(fit.centre)
            c_cov.append(fit.covariance)
            c_line.append(int(probes.line[sel][0]))
            good.setdefault(pose, []).append((ball, fit.centre, fit.covariance))

    p_pose, p_xyz, p_quat, p_cov = [], [], [], []
    for pose in sorted(set(probes.pose.tolist())):
        balls = good.get(pose, [])
        n_probed = n_probed_of.get(pose, 0)
        if len(balls) < min_balls:
            quality.append(QualityRow(pose, POSE_ROW, float("nan"),
                                      f"rejected: {len(balls)} good ball(s) of {n_probed}; a pose needs {min_balls}"))
            continue
        tool = np.array([ds.tooling.balls[b] for b, _, _ in balls])
        world = np.array([c for _, c, _ in balls])
        centre_sigma = float(np.sqrt(np.mean([np.trace(cv) / 3 for _, _, cv in balls])))
        fit = rigid_fit(tool, world, sigma=centre_sigma)
        if method == "paper":
            T = paper_pose(tool[:3], world[:3])
            spacing = min(np.linalg.norm(tool[i] - tool[j]) for i in range(3) for j in range(i + 1, 3))
            tol = tolerance if tolerance is not None else max(1e-9, 10.0 * centre_sigma / float(spacing))
            status = check_homogeneous(T, tol)
            T = T.copy()
            T[:3, :3] = nearest_rotation(T[:3, :3])
            rms = float(np.sqrt(np.mean(np.sum((world[:3] - (tool[:3] @ T[:3, :3].T + T[:3, 3])) ** 2, axis=1))))
        else:
            T, status, rms = fit.T, fit.status, fit.rms
        if status != "ok":
            quality.append(QualityRow(pose, POSE_ROW, rms, f"rejected: {status}"))
            continue
        quality.append(QualityRow(pose, POSE_ROW, rms, "ok"))
        p_pose.append(pose)
        p_xyz.append(T[:3, 3])
        p_quat.append(matrix_to_quaternion(T[:3, :3]))
        p_cov.append(fit.covariance)

    centres = PointObservations(np.array(c_pose, dtype=int), np.array(c_ball, dtype=str),
                                np.array(c_xyz).reshape(-1, 3), np.array(c_line, dtype=int))
    poses = PoseObservations(np.array(p_pose, dtype=int), np.array(p_xyz).reshape(-1, 3), np.array(p_quat).reshape(-1, 4))
    return Measurement(centres, np.array(c_cov).reshape(-1, 3, 3), poses, np.array(p_cov).reshape(-1, 6, 6),
                       quality, method)


def derived_dataset(ds: Dataset, m: Measurement) -> Dataset:
    """A dataset of ``ds``'s joints with ``m``'s centres and poses in place of the probe points.

    The noise entries say how noisy the derived centres and poses are (RMS of their propagated
    standard deviations), so a calibration from them weighs them correctly.
    """
    def rms_sigma(cov, sl):
        return float(np.sqrt(np.mean(np.trace(cov[:, sl, sl], axis1=1, axis2=2) / 3))) if len(cov) else None

    noise = replace(ds.noise, centre_sigma=rms_sigma(m.centre_covariance, slice(0, 3)),
                    pose_position_sigma=rms_sigma(m.pose_covariance, slice(3, 6)),
                    pose_orientation_sigma=(None if not len(m.pose_covariance) else
                                            float(np.degrees(rms_sigma(m.pose_covariance, slice(0, 3))))))
    provenance = {"derived_by": f"fgcal measure (method {m.method})", "from": str(ds.path) if ds.path else None,
                  "source_provenance": ds.provenance}
    return Dataset(robot=ds.robot, tooling=ds.tooling, noise=noise, provenance=provenance, pose_ids=ds.pose_ids,
                   joints_deg=ds.joints_deg, probes=None, centres=m.centres, poses=m.poses, truth=ds.truth,
                   truth_outliers=ds.truth_outliers, path=None)


def quality_csv(rows: list[QualityRow]) -> str:
    """The text of ``quality.csv``: ``pose,ball,rms_residual_mm,status``."""
    import csv

    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["pose", "ball", "rms_residual_mm", "status"])
    for r in rows:
        writer.writerow([r.pose, r.ball, "" if not np.isfinite(r.rms_residual_mm) else repr(r.rms_residual_mm), r.status])
    return buf.getvalue()
