"""The record of a plan chosen from a dataset's candidate poses, and its file.

:class:`DatasetDesign` is what both designers hand back (:func:`fgcal.studies.design_dataset.design_from_dataset`
for balls, ballbars and contacts; :func:`fgcal.studies.design_camera.design_cameras` for pixels): the
chosen poses, their predicted accuracy (mm) and that of random plans of the same size. :func:`save_plan`
and :func:`load_plan` write and read it as a ``joints.csv``-like file.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fgcal.estimation.noise import NoiseMode
from fgcal.io.dataset_io import joint_columns, read_joints, write_csv
from fgcal.studies.design_floor import with_floor
from fgcal.studies.design_predict import quantiles

__all__ = ["DatasetDesign", "load_plan", "save_plan"]


@dataclass
class DatasetDesign:
    """A plan chosen from candidate poses, with its predicted accuracy and that of random plans.

    Attributes
    ----------
    pose_ids : ndarray of int, shape (n,)
        The candidates' own pose ids.
    joints_deg : ndarray, shape (n, joints)
    index : str
        The criterion maximised.
    values : dict of str to float
        O1-O5 and ``pred`` (predicted position error RMS at poses like the candidates, or for contacts
        alone the consistency that the estimate adds at new placements, mm; see ``measure``).
    random_pred : ndarray, shape (k,)
        ``pred`` of ``k`` random plans of n poses from the same usable candidates (mm).
    levels : tuple of str
    n_candidates, n_usable : int
    iterations : int
        DETMAX exchanges made.
    dropped : dict of str to list of str
        Parameters no candidate can identify (not designed for), with those they are confused with.
    noise : dict of str to (float, float, str)
        Per variance component: declared and designed-for sigma and unit (see :class:`DesignNoise`).
    noise_mode : NoiseMode
    stations : ndarray of str, shape (n,), or None
        The station each pose is to be measured from (a dataset with a ``station`` column,
        DESIGN.md 8.3); None for one station.
    floor_mm : float
        What no plan removes: the RMS position error at the dataset's poses after calibrating all
        of them (mm; 0 when not known, the declared noise). The predicted error at new poses is
        ``sqrt(floor^2 + pred^2)`` (:func:`predicted_with_floor`).
    measure : str
        What ``pred`` predicts: ``position`` (the tool positions at poses like the candidates) or, for
        contacts alone, ``consistency`` (the contacts' consistency at new placements of the fixtures,
        what the estimate adds to the contacts' own scatter; :mod:`fgcal.studies.design_consistency`).
    """

    pose_ids: np.ndarray
    joints_deg: np.ndarray
    index: str
    values: dict
    random_pred: np.ndarray
    levels: tuple
    n_candidates: int
    n_usable: int
    iterations: int
    dropped: dict = field(default_factory=dict)
    noise: dict = field(default_factory=dict)
    noise_mode: NoiseMode = NoiseMode.DECLARED
    stations: np.ndarray | None = None
    floor_mm: float = 0.0
    measure: str = "position"

    def predicted_with_floor(self) -> tuple[float, float]:
        """Predicted position error RMS at new poses with the floor (mm): the plan's and the median
        random plan's."""
        return (with_floor(self.values["pred"], self.floor_mm),
                with_floor(float(np.median(self.random_pred)), self.floor_mm))

    def random_quartiles(self) -> tuple[float, float, float]:
        """25th percentile, median and 75th percentile of the random plans' ``pred`` (mm)."""
        q25, q50, q75 = quantiles(self.random_pred, [25, 50, 75])
        return q25, q50, q75

    def summary(self) -> list[str]:
        lo, med, hi = self.random_quartiles()
        n_inf = int(np.sum(~np.isfinite(self.random_pred)))
        blind = f"; {n_inf} of them inf: their poses leave undetermined what new poses see" if n_inf else ""
        what, where = (("contact consistency", "placements") if self.measure == "consistency"
                       else ("position error", "poses"))
        lines = [f"designed {len(self.pose_ids)} poses from {self.n_usable} usable of {self.n_candidates} candidates "
                 f"({', '.join(self.levels)}) by {self.index} ({self.iterations} DETMAX steps)",
                 "  " + ", ".join(f"{k} {self.values[k]:.4g}" for k in ("O1", "O2", "O3", "O4", "O5")
                                  if k in self.values),
                 f"  predicted {what} RMS at new {where}: {self.values['pred']:.4g} mm (random "
                 f"{len(self.pose_ids)}-pose sets from the same candidates: median {med:.4g}, quartiles "
                 f"{lo:.4g}-{hi:.4g} mm over {len(self.random_pred)} sets{blind})"]
        if self.floor_mm > 0:
            mine, theirs = self.predicted_with_floor()
            # a gain over random sets most of which cannot predict (inf) is not stated
            gain = (f", a gain of {100 * (1 - mine / theirs):.0f}% (of {100 * (1 - self.values['pred'] / med):.0f}% on "
                    "the estimation error alone)") if np.isfinite(med) else ""
            lines.append(f"  with the error no geometric calibration removes ({self.floor_mm:.4g} mm RMS at the dataset's "
                         f"poses after calibrating all of them): {mine:.4g} mm at new {where} against {theirs:.4g} mm for "
                         f"the median random set{gain}")
        if self.noise:
            lines.append(f"  noise designed for ({self.noise_mode.value}): " + ", ".join(
                f"{k} {used:.3g} {unit} (declared {decl:.3g})" for k, (decl, used, unit) in self.noise.items()))
        if self.dropped:
            lines.append(f"  not identifiable from these candidates, not designed for: {', '.join(self.dropped)}")
        if self.stations is not None:
            names, counts = np.unique(self.stations, return_counts=True)
            lines.append("  poses from each station: " + ", ".join(f"{n} {c}" for n, c in zip(names, counts, strict=True)))
        return lines


def save_plan(plan: DatasetDesign, path) -> None:
    """Write the plan as a ``joints.csv``-like file: ``pose,q1..`` (deg), the candidates' ids, and the
    ``station`` each pose is to be measured from when the dataset has several."""
    if plan.stations is None:
        write_csv(path, joint_columns(plan.joints_deg.shape[1]),
                  [[int(i), *map(float, q)] for i, q in zip(plan.pose_ids, plan.joints_deg, strict=True)])
        return
    write_csv(path, [*joint_columns(plan.joints_deg.shape[1]), "station"],
              [[int(i), *map(float, q), str(st)]
               for i, q, st in zip(plan.pose_ids, plan.joints_deg, plan.stations, strict=True)])


def load_plan(path) -> tuple[np.ndarray, np.ndarray]:
    """A plan (or any candidates file): ``(pose ids (n,), joints (n, joints) deg)``."""
    return read_joints(path)
