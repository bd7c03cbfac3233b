"""Which of a dataset's poses (or of the user's candidate poses) to measure.

The robot, tool, measurement levels and noise are the dataset's; what each candidate pose would
measure is what the dataset measured there (its balls, its levels), or, for candidates given
as joints only, the balls the instrument reaches there (:func:`fgcal.studies.design_info.layout_from_access`,
as many balls per pose as the dataset usually has). The plan keeps the candidates' pose ids.
Its predicted accuracy is compared with random plans of the same size from the same candidates.

The noise designed for is, by default, the one the calibration will use: each level's noise
(variance component) estimated by calibrating the dataset once, and the information is
linearised at that calibrated geometry (:func:`dataset_noise`). On real data the estimated noise
holds the robot's unmodelled errors (on the Landgraf UR10 0.25 mm per pose against the tracker's
stated 0.011 mm), so the plan's predicted accuracy is the one a calibration from it reaches.
Where the estimator does not model joint noise, the excess of the estimated over the declared
noise is taken for a random joint-space error (it grows with the lever arms, as the robot's
unmodelled errors do) and ``pred`` is the covariance of the estimator as it weighs the data under
that error (a sandwich, :mod:`fgcal.studies.design_info`).
The plan's record and its file are :mod:`fgcal.studies.design_dataset_plan` (named here too).
No file I/O here.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import numpy as np

from fgcal.errors import FgcalError
from fgcal.estimation.build import _setup_layout
from fgcal.estimation.graph import Sigmas
from fgcal.estimation.noise import NoiseMode, component_table
from fgcal.measurements.dataset import Dataset
from fgcal.measurements.types import kinematic_levels
from fgcal.robots.model import RobotModel
from fgcal.studies.design import design_plan, random_design_values
from fgcal.studies.design_consistency import candidates_of, contacts_only
from fgcal.studies.design_dataset_plan import DatasetDesign, load_plan, save_plan
from fgcal.studies.design_floor import floor_of, pose_misfit
from fgcal.studies.design_info import Layout, joint_sensitivity, layout_from_access, sigmas_of

__all__ = [
    "DATASET_INDEX",
    "DatasetDesign",
    "DesignNoise",
    "dataset_layout",
    "dataset_noise",
    "design_from_dataset",
    "load_plan",
    "placement_of",
    "save_plan",
    "with_dataset_tooling",
]

log = logging.getLogger(__name__)

# The criterion of a design from a dataset: the predicted position error RMS at the candidates
# (I-optimality over the workspace the candidates sample), at the dataset's estimated noise.
DATASET_INDEX = "pred"


@dataclass
class DesignNoise:
    """The noise a design is for, and where its information is linearised.

    Attributes
    ----------
    sigmas : Sigmas or None
        The estimator's noise per factor kind (its weights); None: the dataset's declared noise.
    actual : Sigmas or None
        The data's instrument noise, when it differs from ``sigmas``.
    joint_error : float
        Unmodelled random joint-space error per joint and pose (rad) the data shows.
    slots : ndarray, shape (S,), or None
        Linearisation point (internal units); None: the nominal geometry.
    levels : dict of str to (float, float, str)
        Per variance component (:func:`fgcal.estimation.noise.component_table`): declared sigma, sigma designed
        for, unit.
    mode : NoiseMode
    misfit : dict of int to float
        Per pose id, its misfit at the calibration over the average (:func:`fgcal.studies.design_floor.pose_misfit`);
        empty for the declared noise.
    floor_mm : float
        RMS position error at the dataset's poses after calibrating all of them: what no plan removes (mm; 0
        for the declared noise).
    """

    sigmas: Sigmas | None
    slots: np.ndarray | None
    levels: dict
    mode: NoiseMode
    actual: Sigmas | None = None
    joint_error: float = 0.0
    misfit: dict = field(default_factory=dict)
    floor_mm: float = 0.0


def dataset_noise(ds: Dataset, model: RobotModel, mode: NoiseMode = NoiseMode.ESTIMATED, progress=None) -> DesignNoise:
    """The noise to design for: ``estimated`` (default) calibrates ``ds`` once (all its poses,
    the estimator's default options) and takes each level's noise as the calibration estimated
    it (the variance components: measurement noise plus whatever the model does not explain),
    linearised at the calibrated geometry; ``declared`` keeps dataset.yaml's noise at the
    nominal geometry. A dataset that cannot be calibrated falls back to ``declared`` (logged).
    """
    mode = NoiseMode(mode)
    model = with_dataset_tooling(ds, model)
    if mode is NoiseMode.DECLARED:
        return DesignNoise(None, _linearisation_point(ds, model), {}, mode)
    from fgcal.estimation.calibrate import calibrate

    if progress is not None:
        progress(f"calibrating {ds.path or 'the dataset'} ({ds.n_poses} poses) for its noise")
    try:
        result = calibrate(ds, model)
    except (FgcalError, RuntimeError, np.linalg.LinAlgError) as exc:
        log.warning("design: %s could not be calibrated for its noise (%s); designing for the declared noise",
                    ds.path or "the dataset", str(exc).strip().split("\n")[0])
        return DesignNoise(None, _linearisation_point(ds, model), {}, NoiseMode.DECLARED)
    sig = sigmas_of(ds.noise, model)
    scaled, levels = {}, {}
    table = component_table()
    for name, level in result.noise.items():
        if name not in table or not level.declared > 0:
            continue
        attr = table[name][2]
        scaled[attr] = getattr(sig, attr) * (level.used / level.declared)
        levels[name] = (float(level.declared), float(level.used), level.unit)
    weights, slots = sig.replaced(**scaled), result.slot_vector(model)
    floor = floor_of(result, ds, model)
    if np.any(np.asarray(sig.joint) > 0):  # the estimator models joint noise and estimated it
        return DesignNoise(weights, slots, levels, mode, misfit=_misfit(ds, model, slots, weights), floor_mm=floor)
    # The excess over the declared noise, as a joint-space error: a joint error of s rad adds
    # s^2 * sens / rows to a component's variance factor (pooled over the components).
    sens = joint_sensitivity(model, ds.joints_rad, dataset_layout(ds, model, slots=slots), sig, slots)
    excess = sum(max(levels[c][1] ** 2 / levels[c][0] ** 2 - 1.0, 0.0) * rows
                 for c, (_, rows) in sens.items() if c in levels)
    total = sum(v for c, (v, _) in sens.items() if c in levels)
    if not excess > 0 or not total > 0:
        return DesignNoise(weights, slots, levels, mode, misfit=_misfit(ds, model, slots, weights), floor_mm=floor)
    joint_error = float(np.sqrt(excess / total))
    levels["unmodelled joint error"] = (0.0, float(np.degrees(joint_error)), "deg")
    return DesignNoise(weights, slots, levels, mode, actual=sig, joint_error=joint_error,
                       misfit=_misfit(ds, model, slots, weights, sig, joint_error), floor_mm=floor)


def _misfit(ds, model, slots, weights, actual=None, joint_error=0.0) -> dict:
    from fgcal.studies import design_floor  # its NEIGHBOURS read at call time

    return pose_misfit(ds, model, slots, weights, design_floor.NEIGHBOURS, actual, joint_error)


def with_dataset_tooling(ds: Dataset, model: RobotModel) -> RobotModel:
    """``model`` carrying the dataset's own tooling (its balls or reflector, as ``dataset.yaml``
    declares them): what was measured, not the robot file's default tool (a URDF has none)."""
    mine, theirs = ds.tooling, model.tooling
    if mine is None or mine is theirs or (
            theirs is not None and mine.radius == theirs.radius and list(mine.balls) == list(theirs.balls)
            and all(np.array_equal(mine.balls[b], theirs.balls[b]) for b in mine.balls)):
        return model
    return replace(model, tooling=ds.tooling)


def dataset_layout(ds: Dataset, model: RobotModel, q=None, slots=None) -> Layout:
    """What is measured at each pose: the dataset's own measurements at its poses (``q`` None),
    or at joint sets ``q`` (N, joints) rad the balls the instrument reaches (as many as the
    dataset usually measures per pose) at the dataset's levels. The balls are the dataset's
    (:func:`with_dataset_tooling`).

    Contacts (types with set-up blocks) are at the dataset's poses only, each at its fixture;
    the blocks start as the estimator starts them, from the geometry ``slots`` (internal units;
    default the nominal): a fixture point at the mean of its predicted ball centres, a plane
    fitted to them (at the true geometry, a noiseless measurement's)."""
    model = with_dataset_tooling(ds, model)
    levels = tuple(ds.levels())  # every measurement type brings its own rows to the information
    if "pixels" in levels:  # DESIGN.md 8.4: not yet
        raise FgcalError(f"{ds.path or 'dataset'}: design for cameras (pixels.csv) is not available yet")
    if not levels:
        raise FgcalError(f"{ds.path or 'dataset'}: design needs measurements; this dataset has none")
    names = model.tooling.names if model.tooling is not None else []
    point_levels = [getattr(ds, lv) for lv in ("probes", "centres", "distances") if lv in levels]
    ppb = 4
    if ds.probes is not None and len(ds.probes):
        _, counts = np.unique([f"{p}/{b}" for p, b in zip(ds.probes.pose, ds.probes.ball)], return_counts=True)
        ppb = int(np.median(counts))
    setup_kinds = [k for k in kinematic_levels(levels) if getattr(k, "uses_setup", False)]
    if q is None:
        balls = np.zeros((ds.n_poses, len(names)), dtype=bool)
        row = {p: i for i, p in enumerate(ds.pose_ids.tolist())}
        col = {b: j for j, b in enumerate(names)}
        for obs in point_levels:
            for p, b in zip(obs.pose.tolist(), obs.ball.tolist()):
                balls[row[p], col[b]] = True
        contacts, setup = {}, None
        if setup_kinds:  # each pose touches the fixture it touched in the dataset
            for kind in setup_kinds:
                obs = getattr(ds, kind.level)
                fixtures = np.full((ds.n_poses, len(names)), "", dtype=object)
                fixtures[[row[p] for p in obs.pose.tolist()], [col[b] for b in obs.ball.tolist()]] = kind.blocks_of(obs)
                contacts[kind.level] = fixtures.astype(str)
            x = model.nominal if slots is None else np.asarray(slots, dtype=float)
            setup = _setup_layout(ds, model, setup_kinds, x, model.joints_to_internal(ds.joints_deg), row)
        return Layout(levels, balls, ppb, contacts, setup)
    if ds.stations is not None:
        raise FgcalError(f"{ds.path or 'dataset'}: centres from several stations are designed from the dataset's own "
                         "poses (each from its station); candidates given as joints name no station")
    if setup_kinds and len(setup_kinds) == len(levels):
        raise FgcalError(f"{ds.path or 'dataset'}: contacts are designed from the dataset's own poses (each at "
                         "its fixture); candidates given as joints only touch no fixture")
    per_pose = 0
    for obs in point_levels:
        if len(obs):
            _, counts = np.unique(obs.pose, return_counts=True)
            per_pose = max(per_pose, int(np.median(counts)))
    return layout_from_access(model, q, levels, max(per_pose, 1), probes_per_ball=ppb)


def _linearisation_point(ds: Dataset, model: RobotModel):
    """The nominal geometry, with a ballbar dataset's world origin moved to its pivot (fitted to the
    lengths as the estimator starts): a ballbar's information depends on where the pivot is."""
    if ds.distances is None or not len(ds.distances):
        return None
    from fgcal.estimation.build import _initial_pivot

    d = ds.distances
    q = model.joints_to_internal(ds.joints_deg[ds.row_of(d.pose)])
    return _initial_pivot(model, model.nominal, q, ds.tooling.offsets(d.ball), d.length)


def design_from_dataset(ds: Dataset, model: RobotModel, n_poses: int, candidates=None, index: str = DATASET_INDEX,
                        random_sets: int = 200, rng: np.random.Generator | None = None, progress=None,
                        max_iterations: int = 200, noise: NoiseMode | DesignNoise = NoiseMode.ESTIMATED,
                        per_placement: bool = False, misfit_weights: bool = True) -> DatasetDesign:
    """Choose ``n_poses`` of the dataset's poses (or of ``candidates``) for the dataset's robot,
    tool, measurement levels and noise.

    Parameters
    ----------
    candidates : tuple (pose ids (K,), joints (K, joints) deg), optional
        Other candidate poses (for example collision-free poses the user recorded).
    random_sets : int
        Random plans of ``n_poses`` from the same usable candidates to compare with.
    progress : callable(str), optional
        Told of each design step.
    noise : NoiseMode or DesignNoise
        The noise designed for (:func:`dataset_noise`): ``estimated`` from ``ds`` (default) or
        ``declared``; a :class:`DesignNoise` already found is reused.
    per_placement : bool
        Contacts: ``n_poses`` at each placement (fixtures linked by known distances, one plate;
        :meth:`~fgcal.measurements.setup.SetupSpec.placements`) instead of ``n_poses`` in all;
        the random plans too.
    misfit_weights : bool
        Weigh each of the dataset's poses in the sandwich's middle by its own misfit at the
        calibration of all of them (:mod:`fgcal.studies.design_floor`; default); False: every pose
        alike (the joint-space error model alone).

    Raises
    ------
    FgcalError
        One line: fewer usable candidates than poses, no measurements, or a plan of this size
        cannot identify the parameters.
    """
    if n_poses < 1:
        raise FgcalError("--poses must be at least 1")
    if "pixels" in ds.levels():  # a camera's: the target in view, varied distance and tilt (DESIGN.md 8.4)
        if len(ds.levels()) > 1 or per_placement:
            raise FgcalError(f"{ds.path or 'dataset'}: design for cameras takes pixels alone (this dataset has "
                             f"{', '.join(ds.levels())})")
        from fgcal.studies.design_camera import design_cameras

        return design_cameras(ds, model, n_poses, candidates, random_sets, rng, progress, max_iterations)
    model = with_dataset_tooling(ds, model)  # the candidates measure the dataset's balls
    rng = rng if rng is not None else np.random.default_rng(0)
    if candidates is None and ds.n_poses < n_poses and not per_placement:  # said before the long calibration
        raise FgcalError(f"{ds.path or 'the dataset'}: {ds.n_poses} candidate poses for a plan of {n_poses}: "
                         "fewer candidates than poses")
    found = noise if isinstance(noise, DesignNoise) else dataset_noise(ds, model, noise, progress)
    if candidates is None:
        ids, q_deg = ds.pose_ids, ds.joints_deg
        layout = dataset_layout(ds, model, slots=found.slots)
    else:
        ids, q_deg = (np.asarray(c) for c in candidates)
        inside = model.in_limits(model.joints_to_internal(q_deg))
        if not inside.all():
            log.warning("%d candidate pose(s) outside the joint limits of %s left out (first: pose %d)",
                        (~inside).sum(), model.name, ids[~inside][0])
            ids, q_deg = ids[inside], q_deg[inside]
        layout = dataset_layout(ds, model, model.joints_to_internal(q_deg), slots=found.slots)
    q = model.joints_to_internal(q_deg)
    where = "the candidates" if candidates is not None else f"{ds.path or 'the dataset'}"
    if len(ids) < n_poses:
        raise FgcalError(f"{where}: {len(ids)} candidate poses for a plan of {n_poses}: fewer candidates than poses")
    groups = None
    if per_placement:
        if layout.setup is None:
            raise FgcalError(f"{where}: a plan per placement needs contacts at fixtures")
        groups = placement_of(layout, layout.setup.spec)
    prep = candidates_of(ds, model, q, layout, found, misfit_weights and candidates is None)
    if progress is not None:
        progress(f"information of {len(q)} candidates ready ({int(prep.usable.sum())} usable)")
    d = design_plan(model, n_poses, q, ds.noise, index=index, prepared=prep, max_iterations=max_iterations,
                    progress=progress, groups=groups)
    rand = np.array([random_design_values(prep, n_poses, rng, groups)[1]["pred"] for _ in range(random_sets)])
    stations = ds.stations[d.chosen] if ds.stations is not None and candidates is None else None
    return DatasetDesign(ids[d.chosen], q_deg[d.chosen], index, d.values, rand, layout.levels, len(q),
                         int(prep.usable.sum()), d.iterations, prep.dropped, found.levels, found.mode, stations,
                         found.floor_mm, "consistency" if contacts_only(layout) else "position")


def placement_of(layout: Layout, spec) -> np.ndarray:
    """(N,) int: the placement (:meth:`~fgcal.measurements.setup.SetupSpec.placements`) of each
    pose's first contact, -1 for a pose that touches no fixture."""
    where = spec.placements()
    out = np.full(len(layout.balls), -1, dtype=int)
    for fixtures in layout.contacts.values():
        for i, row in enumerate(fixtures):
            touched = [f for f in row if f]
            if touched and out[i] < 0:
                out[i] = where[touched[0]]
    return out
