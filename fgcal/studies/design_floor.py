"""What a plan cannot remove, and where a dataset's own poses show it: the design's floor.

A calibration from any plan verifies at new poses no better than the geometric model fits the
robot: on real data the error that no geometric calibration removes (compliance, gear errors,
drift; on the Landgraf UR10 about 0.40 mm mean) adds to the plan's estimation error. Two
consequences for a design from a dataset (:func:`fgcal.studies.design_dataset.design_from_dataset`):

* **The floor.** ``floor_mm``, the RMS position error at the dataset's own poses after calibrating
  all of them, is what no plan beats; the predicted error at new poses is
  ``sqrt(floor^2 + pred^2)``, and the gain over random plans is stated on that scale
  (:func:`with_floor`), not on ``pred`` alone (a plan that halves ``pred`` may gain a few percent).
* **Where the floor is large.** The unmodelled error is not the same at every pose: a pose whose
  measurements the calibrated model misfits by much more than the average pulls a small plan's
  fit towards that pose's local error, the more the larger its leverage. The design weighs each
  candidate's contribution to the sandwich's middle by its own misfit at the full calibration
  (:func:`pose_misfit`: its mean squared whitened residual over the average), a heteroscedastic
  sandwich; the DETMAX exchange then prefers the poses that show the geometry, not the exceptions.

No I/O here.
"""
from __future__ import annotations

import numpy as np

from fgcal.estimation.graph import Sigmas
from fgcal.measurements.dataset import Dataset
from fgcal.measurements.types import kinematic_levels
from fgcal.robots.model import RobotModel

__all__ = ["pose_misfit", "with_floor"]


def pose_misfit(ds: Dataset, model: RobotModel, slots, sigmas: Sigmas) -> dict[int, float]:
    """Each pose's mean squared whitened residual at ``slots`` over the dataset's mean.

    Parameters
    ----------
    ds : Dataset
        Its measurement types without set-up blocks are used (probe points, which need the ball
        centres solved, and contacts are not: their poses get 1).
    slots : ndarray, shape (S,)
        The calibrated geometry (internal units).
    sigmas : Sigmas
        The estimator's noise (the weights), estimated per level.

    Returns
    -------
    dict of int to float
        Pose id to its misfit ratio (1: an average pose); empty when no type applies.
    """
    x = np.asarray(slots, dtype=float)
    q = model.joints_to_internal(ds.joints_deg)
    row = {int(p): i for i, p in enumerate(ds.pose_ids.tolist())}
    everything = np.arange(len(model.slot_names))
    ss, rows = np.zeros(ds.n_poses), np.zeros(ds.n_poses)
    for kind in kinematic_levels(ds.levels()):
        obs = getattr(ds, kind.level, None)
        if obs is None or not len(obs) or getattr(kind, "uses_setup", False):
            continue
        terms = kind.terms(obs, ds.tooling, row)
        e = kind.error(x, q[terms.pose], terms.data, everything, x, model.chain)[0]
        w = np.square(e / kind.sigma(sigmas)[None, :])
        ss += np.bincount(terms.pose, weights=w.sum(axis=1), minlength=ds.n_poses)
        rows += np.bincount(terms.pose, minlength=ds.n_poses) * e.shape[1]
    seen = rows > 0
    if not seen.any() or not ss[seen].sum() > 0:
        return {}
    per_row = ss[seen] / rows[seen]
    ratio = per_row / (ss[seen].sum() / rows[seen].sum())
    return {int(p): float(r) for p, r in zip(ds.pose_ids[seen], ratio, strict=True)}


def with_floor(pred_mm: float, floor_mm: float) -> float:
    """The predicted position error RMS at new poses (mm) of a plan whose estimation error is
    ``pred_mm``, on a robot whose geometric model leaves ``floor_mm`` unexplained."""
    return float(np.hypot(pred_mm, floor_mm))
