"""What a plan cannot remove, and where a dataset's own poses show it: the design's floor.

A calibration from any plan verifies at new poses no better than the geometric model fits the
robot: on real data the error that no geometric calibration removes (compliance, gear errors,
drift; on the Landgraf UR10 about 0.40 mm mean) adds to the plan's estimation error. Two
consequences for a design from a dataset (:func:`fgcal.studies.design_dataset.design_from_dataset`):

* **The floor.** ``floor_mm``, the RMS position error at the dataset's own poses after calibrating
  all of them, is what no plan beats; the predicted error at new poses is
  ``sqrt(floor^2 + pred^2)``, and the gain over random plans is stated on that scale
  (:func:`with_floor`), not on ``pred`` alone (a plan that halves ``pred`` may gain a few percent).
* **Where the floor is large.** The unmodelled error is not the same at every pose: a pose where
  the calibrated model misfits much more than the average pulls a small plan's fit towards that
  pose's local error, the more the larger its leverage. The design weighs each candidate's
  contribution to the sandwich's middle by its misfit ratio (:func:`pose_misfit`: observed over
  expected squared whitened residual at the calibration of all poses), as its nearest other poses
  in joint space predict it: never from the pose's own residual, which a design would otherwise
  choose for its luck (noise, joint rounding) that a new measurement does not repeat, and shrunk
  towards 1 by how much a pose's misfit follows its neighbours' (the regression slope: 0 where the
  misfit is chance at each pose, as for a random joint error; towards 1 where the robot repeats it).
  The DETMAX exchange then prefers the poses where the geometric model holds.

No I/O here.
"""
from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from fgcal.errors import FgcalError
from fgcal.estimation.graph import Sigmas
from fgcal.measurements.dataset import Dataset
from fgcal.measurements.types import kinematic_levels
from fgcal.robots.model import RobotModel
from fgcal.studies.design import Candidates

__all__ = ["MIN_RATIO", "NEIGHBOURS", "floor_of", "pose_misfit", "weigh_by_misfit", "with_floor"]

log = logging.getLogger(__name__)

# The nearest other poses whose misfit predicts a pose's: few, to follow where the model fails.
NEIGHBOURS = 3
# No pose is taken to be better than a tenth of the average: the instrument's noise stays.
MIN_RATIO = 0.1


def pose_misfit(ds: Dataset, model: RobotModel, slots, sigmas: Sigmas, neighbours: int = NEIGHBOURS,
                actual: Sigmas | None = None, joint_error: float = 0.0) -> dict[int, float]:
    """Each pose's misfit ratio at ``slots`` (observed over expected mean squared whitened residual,
    over the dataset's), as its ``neighbours`` nearest other poses in joint space predict it.

    The prediction is ``1 + b (m - 1)``, ``m`` the neighbours' mean ratio and ``b`` the regression
    slope (clipped to 0-1) of the poses' own ratios on their neighbours': the part of the misfit
    that the robot repeats where it is (an unmodelled error is a smooth function of the
    configuration); what is chance at one pose (the noise, the joint rounding, a random joint
    error) has ``b`` near 0. A pose's own residual is not used: a design would choose poses for
    their luck, which a new measurement does not repeat. At least ``MIN_RATIO``.

    Parameters
    ----------
    ds : Dataset
        Its measurement types without set-up blocks are used (probe points, which need the ball
        centres solved, and contacts are not: their poses get 1; a dataset with stations gets none).
    slots : ndarray, shape (S,)
        The calibrated geometry (internal units).
    sigmas : Sigmas
        The estimator's noise (the weights), estimated per level.
    neighbours : int
        Other poses that predict a pose's ratio; 0: each pose's own ratio (not shrunk).
    actual, joint_error : Sigmas, float
        The error the design already expects at every pose (the data's noise, a random joint-space
        error in rad; :class:`fgcal.studies.design_dataset.DesignNoise`): the misfit is measured
        against it (a pose with long lever arms is expected to misfit more), so that the ratio
        says what the sandwich does not already know. Default: the weights' noise alone.

    Returns
    -------
    dict of int to float
        Pose id to its misfit ratio (observed over expected squared residual, 1: as the design
        expects on average); empty when no type applies.
    """
    if ds.stations is not None:  # centres from several stations: their frames are estimated, not known here
        return {}
    x = np.asarray(slots, dtype=float)
    q = model.joints_to_internal(ds.joints_deg)
    row = {int(p): i for i, p in enumerate(ds.pose_ids.tolist())}
    everything = np.arange(len(model.slot_names))
    ss, rows = np.zeros(ds.n_poses), np.zeros(ds.n_poses)  # observed and expected squared whitened residuals
    for kind in kinematic_levels(ds.levels()):
        obs = getattr(ds, kind.level, None)
        if obs is None or not len(obs) or getattr(kind, "uses_setup", False):
            continue
        terms = kind.terms(obs, ds.tooling, row)
        e, _, J_q = kind.error(x, q[terms.pose], terms.data, everything, x, model.chain)
        weight = kind.sigma(sigmas)[None, :]
        ss += np.bincount(terms.pose, weights=np.square(e / weight).sum(axis=1), minlength=ds.n_poses)
        ratio = np.square(kind.sigma(actual if actual is not None else sigmas)[None, :] / weight)
        expected = np.broadcast_to(ratio, e.shape).sum(axis=1)
        if joint_error > 0:
            expected = expected + joint_error**2 * np.square(J_q / weight[:, :, None]).sum(axis=(1, 2))
        rows += np.bincount(terms.pose, weights=expected, minlength=ds.n_poses)
    seen = rows > 0
    if not seen.any() or not ss[seen].sum() > 0:
        return {}
    where = np.nonzero(seen)[0]
    own = (ss[where] / rows[where]) / (ss[where].sum() / rows[where].sum())
    if neighbours < 1 or len(where) < neighbours + 3:
        ratio = own
    else:  # the repeatable part of the misfit, predicted from the nearest other poses
        from scipy.spatial import cKDTree

        features = _joint_features(q[where], model)
        _, near = cKDTree(features).query(features, k=int(neighbours) + 1)
        near = np.asarray(near).reshape(len(where), -1)[:, 1:]  # the nearest is the pose itself
        around = own[near].mean(axis=1)
        # How much of the neighbours' misfit a pose shares: the regression slope of its own misfit
        # on theirs (0 for a misfit that is chance at each pose, towards 1 where the robot repeats it).
        spread = float(np.var(around))
        slope = float(np.clip(np.cov(own, around)[0, 1] / spread, 0.0, 1.0)) if spread > 0 else 0.0
        ratio = np.maximum(1.0 + slope * (around - 1.0), MIN_RATIO)
        log.info("design: pose misfit from %d neighbours, slope %.2f", neighbours, slope)
    return {int(p): float(r) for p, r in zip(ds.pose_ids[where], ratio, strict=True)}


def _joint_features(q, model: RobotModel) -> np.ndarray:
    """Joint sets as points where nearness is nearness of configuration: a revolute joint as the
    point (cos, sin) of its angle (a turn apart is the same place), a prismatic one in metres."""
    q = np.asarray(q, dtype=float)
    ang = np.asarray(model.joint_is_angle, dtype=bool)
    return np.column_stack([np.cos(q[:, ang]), np.sin(q[:, ang]), q[:, ~ang] / 1000.0])


def with_floor(pred_mm: float, floor_mm: float) -> float:
    """The predicted position error RMS at new poses (mm) of a plan whose estimation error is
    ``pred_mm``, on a robot whose geometric model leaves ``floor_mm`` unexplained."""
    return float(np.hypot(pred_mm, floor_mm))


def floor_of(result, ds: Dataset, model: RobotModel) -> float:
    """RMS position error (mm) at ``ds``'s poses of the calibration ``result`` of all of them."""
    from fgcal.estimation.verification import verify

    try:
        err = np.asarray(verify(result, ds, model).after.position_mm, dtype=float)
    except (FgcalError, ValueError) as exc:  # a type verify does not compare: no floor stated
        log.info("design: no floor from %s (%s)", ds.path or "the dataset", exc)
        return 0.0
    err = err[np.isfinite(err)]
    return float(np.sqrt(np.mean(err**2))) if len(err) else 0.0


def weigh_by_misfit(prep: Candidates, ratio) -> Candidates:
    """``prep`` with each candidate's sandwich middle scaled by its misfit ratio (N,): its own share
    of what the geometric model does not explain (without a middle: its information so scaled, the
    estimator's weights being the estimated average noise)."""
    ratio = np.asarray(ratio, dtype=float)[:, None, None]
    middle = prep.info * ratio if prep.middle is None else prep.middle * ratio
    return replace(prep, middle=middle)
