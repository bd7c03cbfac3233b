"""``fgcal.design``: which poses to measure, an optimal plan from a candidate pool (``fgcal design``)."""
from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fgcal.api.selection import MAX_POSES, as_dataset
from fgcal.errors import FgcalError

__all__ = ["Plan", "design", "progress_printer"]

INDICES = ("O1", "O2", "O3", "O4", "O5", "pred")


@dataclass
class Plan:
    """A designed set of poses.

    Attributes
    ----------
    pose_ids : ndarray of int, shape (n,)
        The candidates' pose ids (1..n for random candidates).
    joints_deg : ndarray, shape (n, joints)
        Joint readings of the poses to measure (deg; mm for prismatic joints).
    values : dict of str to float
        O1-O5 and ``pred`` (predicted position error RMS at new poses, mm).
    lines : list of str
        What ``fgcal design`` prints.
    design : object
        The designer's own record (:class:`~fgcal.studies.design_dataset_plan.DatasetDesign` or the
        random-candidates design).
    """

    pose_ids: np.ndarray
    joints_deg: np.ndarray
    values: dict
    lines: list[str] = field(default_factory=list)
    design: Any = None  # a DatasetDesign or the random-candidates design

    def save(self, path) -> None:
        """Write the plan as a ``joints.csv``-like file ``pose,q1..qn`` (deg), atomically."""
        from fgcal.io.dataset_io import joint_columns, write_csv

        if getattr(self.design, "stations", None) is not None:  # each pose's station too (DESIGN.md 8.3)
            from fgcal.studies.design_dataset_plan import save_plan

            save_plan(self.design, path)
            return
        write_csv(path, joint_columns(self.joints_deg.shape[1]),
                  [[int(i), *map(float, q)] for i, q in zip(self.pose_ids, self.joints_deg, strict=True)])


def progress_printer(every: float = 2.0) -> Callable[[str], None]:
    """A progress reporter for long runs: a line on standard error at most every ``every`` s."""
    t0 = time.perf_counter()
    last = [t0]

    def say(text: str) -> None:
        now = time.perf_counter()
        if now - last[0] >= every:
            print(f"design: {text} ({now - t0:.0f} s)", file=sys.stderr, flush=True)
            last[0] = now
    return say


def design(robot="puma560", *, dataset=None, poses: int = 12, candidates=None, index: str | None = None,
           level: str = "probes", seed: int = 0, noise: str = "estimated", per_placement: bool = False,
           cmm_sigma: float = 0.01, joint_resolution: float = 0.01, repeatability: float = 0.0,
           progress: Callable[[str], None] | None = None) -> Plan:
    """Choose ``poses`` poses to measure that identify the robot best.

    Parameters
    ----------
    robot : str or path
        Without ``dataset``: the robot to plan for (built-in name, model file or URDF).
    dataset : path or Dataset, optional
        Design for this dataset's robot, tool, measurement type and noise; its poses are the
        candidates unless ``candidates`` is a file.
    poses : int
        Number of poses to plan (at least 5 without a dataset).
    candidates : int or path, optional
        Without ``dataset``: the number of random reachable candidates (default 2000); with it: a
        ``joints.csv``-like file of candidate poses.
    index : {"O1", ..., "O5", "pred"}, optional
        Criterion: an observability index, or the predicted accuracy (default).
    level : {"probes", "centres", "poses"}
        Without ``dataset``: what is measured at a pose.
    seed : int
        Random seed of the candidates.
    noise : {"estimated", "declared"}
        With ``dataset``: design for the noise a calibration of it estimates, or its declared noise.
    per_placement : bool
        With a dataset of contacts: ``poses`` at each placement.
    cmm_sigma, joint_resolution, repeatability : float
        Without ``dataset``: instrument noise (mm), reading resolution (deg), repeatability (deg).
    progress : callable, optional
        Called with a line of progress now and then.

    Returns
    -------
    Plan
        ``.save(path)`` writes ``pose,q1..qn``.
    """
    if index is not None and index not in INDICES:
        raise FgcalError(f"--index {index!r}: one of {', '.join(INDICES)}")
    if dataset is not None:
        return _from_dataset(dataset, poses, candidates, index, seed, noise, per_placement, progress)
    return _from_robot(robot, poses, candidates, index, level, seed, (cmm_sigma, joint_resolution, repeatability),
                       progress)


def _from_dataset(dataset, poses, candidates, index, seed, noise, per_placement, progress) -> Plan:
    from fgcal.io.dataset_io import dataset_model
    from fgcal.studies.design_dataset import DATASET_INDEX, design_from_dataset
    from fgcal.studies.design_dataset_plan import load_plan

    ds = as_dataset(dataset)
    pool = None
    if candidates is not None:
        if isinstance(candidates, int) or str(candidates).isdigit():
            raise FgcalError("with --dataset, --candidates is a joints.csv-like file (pose,q1..qn deg), "
                             f"not a count: {candidates}")
        pool = load_plan(Path(candidates))
        n = dataset_model(ds).n_joints
        if pool[1].shape[1] != n:
            raise FgcalError(f"--candidates {candidates}: {pool[1].shape[1]} joint columns, but the dataset's "
                             f"robot has {n} joints")
    plan = design_from_dataset(ds, dataset_model(ds), poses, pool, index=index or DATASET_INDEX,
                               rng=np.random.default_rng(seed), progress=progress, noise=noise,
                               per_placement=per_placement)
    return Plan(np.asarray(plan.pose_ids, dtype=int), np.asarray(plan.joints_deg, dtype=float), dict(plan.values),
                plan.summary(), plan)


def _from_robot(robot, poses, candidates, index, level, seed, noise_values, progress) -> Plan:
    from fgcal.measurements.dataset import Noise
    from fgcal.robots.robot_file import load_model
    from fgcal.studies.design import INDICES as ALL
    from fgcal.studies.design import Candidates, candidate_pool, design_plan, random_design_values
    from fgcal.studies.design_info import layout_from_access
    from fgcal.studies.design_predict import quantiles
    from fgcal.studies.plans import random_plan

    if poses < 5:
        raise FgcalError("--poses must be at least 5 (30 parameters, 6 equations per pose)")
    if candidates is not None and not (isinstance(candidates, int) or str(candidates).isdigit()):
        raise FgcalError(f"--candidates {candidates}: a file of candidate poses needs --dataset (for the "
                         "robot, tool, measurement type and noise); without it, give a number of random poses")
    n_candidates = 2000 if candidates is None else int(candidates)
    if not 1 <= n_candidates <= MAX_POSES:
        raise FgcalError(f"--candidates: from 1 to {MAX_POSES} random poses")
    model = load_model(str(robot))
    if model.tooling is None:
        raise FgcalError(f"robot model {model.name} has no tooling (balls) to plan for")
    rng = np.random.default_rng(seed)
    noise = Noise(*noise_values)
    levels = (level,)
    pool = candidate_pool(model, n_candidates, rng, levels=levels)
    q_verify = pool if model.volume is None else random_plan(
        model, model.nominal, 1000, rng, model.tooling, model.volume, min(3, len(model.tooling.balls)))
    prepared = Candidates.build(model, pool, noise, q_verify, layout=layout_from_access(model, pool, levels))
    d = design_plan(model, poses, pool, noise, index=index or "pred", prepared=prepared, progress=progress)
    random_pred = [random_design_values(prepared, poses, np.random.default_rng([seed, k]))[1]["pred"]
                   for k in range(200)]
    q25, med, q75 = quantiles(random_pred, [25, 50, 75])  # inf: a random set that cannot predict
    lines = [f"designed {poses} poses from {len(pool)} candidates by {d.index} ({d.iterations} DETMAX steps)",
             "  " + ", ".join(f"{k} {d.values[k]:.4g}" for k in ALL if k != "pred"),
             f"  predicted position error RMS at new poses: {d.values['pred']:.4g} mm "
             f"(random {poses}-pose sets from the same candidates: median {med:.4g}, quartiles {q25:.4g}-{q75:.4g} mm)",
             "  the estimation error alone: the robot's error that no geometric model describes (compliance, gear "
             "errors) adds to it at every pose; design --dataset of a measured series states that floor"]
    if prepared.dropped:
        lines.append(f"  not identifiable from these candidates, not designed for: {', '.join(prepared.dropped)}")
    joints = np.array([model.joints_to_file_units(q) for q in d.q], dtype=float)
    return Plan(np.arange(1, len(joints) + 1), joints, dict(d.values), lines, d)
