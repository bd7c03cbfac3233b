"""``fgcal.simulate``: the paper's POSE program, a measured robot with known deviations, as ``fgcal simulate``."""
from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from fgcal.api.notes import note
from fgcal.api.selection import MAX_POSES
from fgcal.errors import FgcalError
from fgcal.util.parsing import chain_links, finite_floats

if TYPE_CHECKING:
    from fgcal.measurements.dataset import Dataset

__all__ = ["simulate"]


def simulate(robot="puma560", rng=None, settings=None, *, poses: int | None = None, seed: int = 0,
             plan: str = "random", cmm_sigma: float = 0.01, joint_resolution: float = 0.01,
             repeatability: float = 0.0, outliers: float = 0.0, outlier_size: float = 0.5, balls: int | None = None,
             probes_per_ball: int = 4, levels: str | tuple | None = None, length_sigma: float = 0.5,
             angle_sigma: float = 0.05, base_length_sigma: float = 5.0, base_angle_sigma: float = 0.5,
             chain: str | dict | None = None, reflector=None, truth=None, out=None, force: bool = False,
             robot_ref: str | None = None, tool_ball=None, setup=None):
    """Simulate a robot measured by a CMM (or a tracker): the dataset ``fgcal simulate`` writes.

    Parameters
    ----------
    robot : str, path or RobotModel
        Built-in model name (``puma560``, ``ur10``, ``ur5``), model file or URDF, or a model.
    rng, settings : numpy.random.Generator, SimulationSettings
        The simulator itself, for old scripts: ``simulate(model, rng, settings, robot_ref=None,
        seed=None, truth=None)`` returns ``(dataset, notes)`` as
        :func:`fgcal.studies.simulate.simulate` does (``truth`` then is the slot vector, mm and
        rad); the other arguments are then ignored.
    poses : int, optional
        Number of poses of the random plan (default 21).
    seed : int
        Random seed (the truth, the plan, the noise).
    plan : {"random", "paper"}
        Random reachable joint sets, or the paper's 48-pose experiment.
    cmm_sigma : float
        Instrument noise per coordinate, mm.
    joint_resolution : float
        Joint readings rounded to this, deg (0: exact).
    repeatability : float
        Joints land off the readings by N(0, this), deg.
    outliers : float
        Fraction of probe points with a gross error, from 0 to below 1; ``outlier_size`` its size, mm.
    balls, probes_per_ball : int
        Balls measured per pose (default 3, or all the tool has if fewer), probe points per ball.
    levels : str or tuple of str, optional
        Files to write: ``probes``, ``centres``, ``poses`` (default probes; centres with ``reflector``).
    length_sigma, angle_sigma, base_length_sigma, base_angle_sigma : float
        The robot's deviations from its nominal model: links (mm, deg) and base (mm, deg).
    chain : str or dict, optional
        ``"BASE,TIP"`` or ``{"base": ..., "tip": ...}``: the URDF links of the chain.
    reflector : sequence of 3 float or str, optional
        Measure one tracker reflector at X,Y,Z (mm, tool frame) instead of the tooling balls.
    truth : path, optional
        ``truth.yaml`` of another simulation: the same actual robot (a verification set).
    out : path, optional
        Write the dataset there (a folder that must be new unless ``force``).
    tool_ball : sequence of 3 or 4 float or str, optional
        ``X,Y,Z[,RADIUS]`` (mm, tool frame): the one ball that touches fixtures and planes, replacing
        the model's tooling.
    setup : SetupSimulation, optional
        Contacts and stations to simulate (:class:`fgcal.studies.simulate_setup.SetupSimulation`:
        two-socket placements, a datum, a plane, several stations; DESIGN.md 8.2, 8.3). Contact
        levels are written besides ``levels`` (only them when ``levels`` is None).

    Returns
    -------
    Dataset
        With its truth (``dataset.truth``, file units); saved to ``out`` when given.

    Warns
    -----
    FgcalNote
        Poses the instrument could not reach.
    """
    from fgcal.studies.simulate import simulate as simulator

    if rng is not None or settings is not None:  # the simulator's own signature
        from fgcal.studies.simulate import SimulationSettings

        return simulator(robot, rng if rng is not None else np.random.default_rng(seed),
                         settings if settings is not None else SimulationSettings(), robot_ref=robot_ref,
                         seed=seed or None, truth=None if truth is None else np.asarray(truth, dtype=float))
    ds = _simulate(robot, poses, seed, plan, cmm_sigma, joint_resolution, repeatability, outliers, outlier_size,
                   balls, probes_per_ball, levels, (length_sigma, angle_sigma, base_length_sigma, base_angle_sigma),
                   chain, reflector, truth, out, force, tool_ball, setup)
    return ds


def _simulate(robot, poses, seed, plan, cmm_sigma, joint_resolution, repeatability, outliers, outlier_size, balls,
              probes_per_ball, levels, deviations, chain, reflector, truth, out, force, tool_ball=None,
              setup=None) -> Dataset:
    from dataclasses import replace

    from fgcal.io.dataset_io import save_dataset
    from fgcal.measurements.dataset import Noise
    from fgcal.robots.deviations import Deviations
    from fgcal.robots.model import RobotModel, Tooling
    from fgcal.robots.robot_file import load_model
    from fgcal.studies.simulate import SimulationSettings
    from fgcal.studies.simulate import simulate as simulator

    if cmm_sigma < 0 or joint_resolution < 0 or repeatability < 0:
        raise FgcalError("--cmm-sigma, --joint-resolution and --repeatability must not be negative")
    if not 0 <= outliers < 1:
        raise FgcalError("--outliers is a fraction of probe points, from 0 to below 1")
    if (poses or 0) > MAX_POSES or probes_per_ball > 1000:
        raise FgcalError(f"--poses at most {MAX_POSES} and --probes-per-ball at most 1000 (a dataset that large "
                         "would not fit in memory)")
    chain = chain_links(chain)
    model = robot if isinstance(robot, RobotModel) else load_model(str(robot), chain=chain)
    if reflector is not None and tool_ball is not None:
        raise FgcalError("--reflector and --tool-ball: give one tool (a reflector, or a ball that touches)")
    if reflector is not None:
        model = replace(model, tooling=Tooling(0.0, {"R": _floats(reflector, 3, "--reflector")}))
        levels = levels or "centres"
    if tool_ball is not None:
        model = replace(model, tooling=_tool_ball(tool_ball))
    contact_levels = () if setup is None else tuple(
        lv for lv, on in (("contacts", setup.placements or setup.datum), ("plane_contacts", setup.plane)) if on)
    robot_ref = model.name if isinstance(robot, RobotModel) else str(robot)
    if out is not None and not isinstance(robot, RobotModel) and (Path(robot_ref).suffix or "/" in robot_ref):
        robot_ref = os.path.relpath(Path(robot_ref).resolve(), Path(out).resolve())  # relative to the dataset
    levels = tuple(levels.split(",")) if isinstance(levels, str) else tuple(levels or ())
    levels = (levels or (() if contact_levels else ("probes",))) + contact_levels
    settings = SimulationSettings(
        n_poses=poses, plan=plan, noise=Noise(cmm_sigma, joint_resolution, repeatability),
        deviations=Deviations(*deviations),
        n_balls=balls if balls is not None else min(3, len(model.tooling.balls) if model.tooling else 3),
        probes_per_ball=probes_per_ball, outlier_fraction=outliers, outlier_size=outlier_size, levels=levels,
        **({} if setup is None else {"setup": setup}))
    truth_slots = None
    if truth is not None:
        from fgcal.io.dataset_io import load_truth

        values, _ = load_truth(truth)
        missing = [n for n in model.slot_names if n not in values]
        if missing:
            raise FgcalError(f"{truth}: lacks {', '.join(missing[:5])}{' ...' if len(missing) > 5 else ''}")
        truth_slots = model.slots_from_file_units(np.array([values[n] for n in model.slot_names]))
    ds, notes = simulator(model, np.random.default_rng(seed), settings, robot_ref=robot_ref, seed=seed,
                          truth=truth_slots)
    ds.chain = chain
    for message in notes:
        note(message)
    if out is not None:
        save_dataset(ds, out, overwrite=force)
    return ds


def _floats(value, n: int, option: str) -> np.ndarray:
    values = finite_floats(value, (n,))
    if values is None:
        raise FgcalError(f"{option}: expected {n} comma-separated numbers, got {value!r}")
    return values


def _tool_ball(value):
    """The tooling of one touching ball from ``X,Y,Z[,RADIUS]`` (mm)."""
    from fgcal.robots.model import Tooling

    parts = value.split(",") if isinstance(value, str) else list(value)
    values = _floats(value, len(parts) if len(parts) in (3, 4) else 3, "--tool-ball")
    radius = float(values[3]) if len(values) == 4 else 0.0
    if radius < 0:
        raise FgcalError(f"--tool-ball: the radius must not be negative, got {radius!r}")
    return Tooling(radius, {"B": values[:3]})
