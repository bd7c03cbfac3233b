"""What the online engines' final smoothing holds, by the batch's rules: the gauges (world frame,
tool frame, scale) and the parameters the poses cannot separate. No I/O here."""
from __future__ import annotations

import logging

from fgcal.estimation.holding import held_parameters
from fgcal.measurements.dataset import Dataset
from fgcal.robots.model import RobotModel

__all__ = ["batch_held", "gauge_names", "measured"]

log = logging.getLogger(__name__)


def gauge_names(ds: Dataset, model: RobotModel, names) -> dict[str, str]:
    """The gauges' parameters among ``names`` and why each is held, as the batch holds them
    (:func:`fgcal.estimation.gauge.gauge_holds`): the base where nothing in ``ds`` fixes the world
    frame (contacts with unknown fixtures only), the tool where a camera's blocks on it are of
    unknown pose, the longest link where nothing fixes a length; none for a dataset with no
    measurements yet."""
    from fgcal.estimation.gauge import gauge_holds

    levels = ds.levels()
    if not levels:
        return {}
    return {h["name"]: h["reason"] for h in gauge_holds(ds, model, names, levels)[1]}


def batch_held(engine, seen: Dataset, names, fits: dict | None = None) -> tuple[dict, dict]:
    """What the batch would hold among ``names`` on the poses ``seen`` for ``engine`` (its model,
    options and typical-deviation priors): the rule of
    :func:`fgcal.estimation.calibrate.solve_calibration` (the graph at the declared noise, no
    prior, linearised at the start) and the priors it gives the weakly identifiable ones
    (:func:`fgcal.estimation.calibrate.split_held`): ``(held, priors)``; raises
    :class:`FgcalError` when the poses are too few. ``fits``: the sphere fits kept for the
    solve's build of ``seen`` (:func:`fgcal.estimation.build.build_graph`)."""
    from dataclasses import replace

    from fgcal.estimation.build import _levels, build_graph
    from fgcal.estimation.calibrate import _check_equations, split_held
    from fgcal.estimation.gauge import setup_size
    from fgcal.estimation.holding import _unidentifiable

    options = replace(engine.options, prior="none", noise_scale=None)
    levels = _levels(seen, options)
    _check_equations(seen, levels, len(names) + setup_size(seen, levels))
    graph, state, _ = build_graph(seen, engine.model, names, options, priors=engine.typical_prior, fits=fits)
    held = held_parameters(graph, state, _unidentifiable)
    held, priors = split_held(engine.model, [n for n in names if n not in held], held, seen, options, fits=fits)
    for n, partners in held.items():
        log.info("final smoothing: %s held (cannot be separated from %s)", n, ", ".join(partners) or "nothing")
    return held, priors


def measured(ds: Dataset):
    """What ``ds`` measures, as :func:`~fgcal.estimation.holding.unseen_parameters` takes it: a
    pose (a measured pose, a camera's pixels), or the tool points of its balls; a full pose while
    nothing is known (a stream)."""
    from fgcal.measurements.types import BY_LEVEL

    levels = ds.levels()
    # a camera sees the tool's whole pose (a target on it, or the world's target from it)
    if not levels or "poses" in levels or any(hasattr(BY_LEVEL.get(lv), "tool_blocks") for lv in levels):
        return "pose"
    from fgcal.estimation.calibrate import _measured_points

    return _measured_points(ds, levels)
