"""Does a designed plan calibrate better than random plans? Measured on held-out poses.

A plan of n of a dataset's poses (:func:`fgcal.studies.design_dataset.design_from_dataset`) and random
plans of n poses from the same usable candidates are each calibrated on their own poses, and
each calibration's position error is measured at the held-out dataset's poses
(:func:`fgcal.estimation.verification.verify`). On real data this includes what no geometric model explains, so
it is the test a user cares about. No I/O here.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from fgcal.errors import FgcalError
from fgcal.estimation.calibrate import calibrate
from fgcal.estimation.noise import NoiseMode
from fgcal.estimation.options import CalibrationOptions
from fgcal.estimation.verification import verify
from fgcal.measurements.dataset import Dataset
from fgcal.robots.model import RobotModel
from fgcal.studies.design_dataset import DATASET_INDEX, DesignNoise, dataset_layout, design_from_dataset
from fgcal.studies.design_dataset_plan import DatasetDesign

__all__ = ["HeldOutComparison", "compare_on_held_out"]

log = logging.getLogger(__name__)


@dataclass
class HeldOutComparison:
    """Held-out position error (mm) of a designed plan and of random plans of the same size.

    Attributes
    ----------
    plan : DatasetDesign
    plan_mean, plan_rms : float
        Mean and RMS position error at the held-out poses after calibrating on the plan.
    random_mean, random_rms : ndarray, shape (k,)
        The same for ``k`` random plans; ``inf`` for a random plan that did not calibrate (an
        ill-posed set).
    """

    plan: DatasetDesign
    plan_mean: float
    plan_rms: float
    random_mean: np.ndarray
    random_rms: np.ndarray

    def beaten(self) -> float:
        """Fraction of random plans whose mean held-out error is larger than the plan's."""
        return float(np.mean(self.random_mean > self.plan_mean))

    def failed(self) -> int:
        """Random plans that did not calibrate."""
        return int(np.sum(~np.isfinite(self.random_mean)))


def _held_out_error(ds: Dataset, ids, held: Dataset, model: RobotModel, options: CalibrationOptions):
    v = verify(calibrate(ds.select(ids), model, options), held, model).to_dict()["position_mm"]
    return v["mean"], v["rms"]


def compare_on_held_out(ds: Dataset, held: Dataset, model: RobotModel, n_poses: int, random_sets: int = 20,
                        rng: np.random.Generator | None = None, index: str = DATASET_INDEX,
                        options: CalibrationOptions = CalibrationOptions(),
                        noise: NoiseMode | DesignNoise = NoiseMode.ESTIMATED,
                        misfit_weights: bool = True) -> HeldOutComparison:
    """Design ``n_poses`` of ``ds``'s poses (for ``noise``, see
    :func:`fgcal.design_dataset.design_from_dataset`), calibrate on them and on ``random_sets``
    random plans of the same usable poses, and verify each at ``held``'s poses (``misfit_weights``:
    see :func:`~fgcal.studies.design_dataset.design_from_dataset`)."""
    rng = rng if rng is not None else np.random.default_rng(0)
    plan = design_from_dataset(ds, model, n_poses, index=index, rng=rng, noise=noise, misfit_weights=misfit_weights)
    plan_mean, plan_rms = _held_out_error(ds, plan.pose_ids, held, model, options)
    usable = ds.pose_ids[dataset_layout(ds, model).usable()]
    errors: list[tuple[float, float]] = []
    for k in range(random_sets):
        try:
            errors.append(_held_out_error(ds, rng.choice(usable, size=n_poses, replace=False), held, model, options))
        except (FgcalError, RuntimeError) as exc:  # an ill-posed random set: worse than any that calibrates
            log.warning("random set %d of %d did not calibrate: %s", k + 1, random_sets, str(exc).strip().split("\n")[0])
            errors.append((np.inf, np.inf))
        log.info("random set %d of %d: held-out mean %.4f mm", k + 1, random_sets, errors[-1][0])
    table = np.array(errors).reshape(-1, 2)
    return HeldOutComparison(plan, plan_mean, plan_rms, table[:, 0], table[:, 1])
