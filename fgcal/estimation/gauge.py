"""The gauges (world frame, tool frame, scale) and the size of the set-up blocks a dataset's levels
use (DESIGN.md 8.1).

Where nothing in the data fixes the world frame (contacts with unknown fixtures only), the
calibration holds the base at nominal and says so (:data:`GAUGE_REASON`); where nothing fixes a
length either (no known distance between the fixtures), it holds the robot's longest link length
at nominal (:data:`SCALE_REASON`): such data are unchanged but for a common factor on every
residual when the robot, the fixtures and the planes are scaled together, so a least squares with
the scale free would shrink the robot toward the base. :func:`gauge_holds` applies all three. No I/O here.
"""
from __future__ import annotations

import logging

from fgcal.measurements.dataset import Dataset
from fgcal.measurements.setup import BLOCK_KINDS
from fgcal.measurements.types import BY_LEVEL

__all__ = ["GAUGE_REASON", "SCALE_REASON", "TOOL_GAUGE_REASON", "gauge_holds", "scale_is_fixed", "scale_length",
           "setup_size", "tool_is_free", "used_blocks", "world_is_fixed"]

log = logging.getLogger(__name__)


GAUGE_REASON = ("the world frame: nothing in these data fixes it (contacts with unknown fixtures only), "
                "so the base is held at nominal and the fixtures are in its frame")


def world_is_fixed(ds: Dataset, levels) -> bool:
    """Whether the data fix the world frame: an instrument level, or a set-up block that is known
    or has a prior (contacts with unknown fixtures alone leave the base free)."""
    setup_levels = [lv for lv in levels if getattr(BY_LEVEL.get(lv), "uses_setup", False)]
    if len(setup_levels) < len(levels):
        return True
    used = used_blocks(ds, setup_levels)
    return any(ds.setup.fixtures[f].value is not None for f in used)


TOOL_GAUGE_REASON = ("the tool frame: the cameras see the tool only through an unknown pose on it (a target's or "
                     "a camera's), so the tool is held at nominal and that pose is in its frame")


def tool_is_free(ds: Dataset, levels) -> bool:
    """Whether nothing fixes the tool frame: every level is a camera's (a type with ``tool_blocks``)
    and every block mounted on the tool that it uses is unknown (no value, no prior)."""
    kinds = [BY_LEVEL[lv] for lv in levels if lv in BY_LEVEL]
    if not kinds or len(kinds) < len(levels) or not all(hasattr(k, "tool_blocks") for k in kinds):
        return False
    on_tool = set()
    for lv, k in zip(levels, kinds, strict=True):
        on_tool |= set(k.tool_blocks(getattr(ds, lv)))
    return bool(on_tool) and all(ds.setup.fixtures[n].value is None for n in on_tool)


def used_blocks(ds: Dataset, levels) -> set:
    """The names of the set-up blocks the measurements at ``levels`` use."""
    used = set()
    for lv in levels:
        kind = BY_LEVEL.get(lv)
        if kind is not None and getattr(kind, "uses_setup", False):
            obs = getattr(ds, lv)
            used |= set(kind.all_blocks(obs) if hasattr(kind, "all_blocks") else kind.blocks_of(obs).tolist())
    return used


def setup_size(ds: Dataset, levels) -> int:
    """Free set-up parameters the levels use, less the known distances between them."""
    spec = ds.setup.subset(used_blocks(ds, levels))
    return sum(sum(f.entries_free(BLOCK_KINDS[f.type].size)) for f in spec.fixtures.values()) - len(spec.distances)


SCALE_REASON = ("the scale: nothing in these data fixes a length (contacts with unknown fixtures and no known "
                "distance between them), so the robot's longest link length is held at nominal and every other "
                "length is in its unit")


def scale_is_fixed(ds: Dataset, levels) -> bool:
    """Whether the data fix the scale: the world frame is fixed (:func:`world_is_fixed`), a level's
    type measures a length (every type but contacts, whose ``measures_length`` is False), or a
    known distance joins two of the fixtures used. Contacts at unknown points and planes alone
    are unchanged but for a common factor on every residual when the robot's lengths, the
    fixture points and the planes' offsets (about the held base) are scaled together."""
    if world_is_fixed(ds, levels):
        return True
    if any(getattr(BY_LEVEL.get(lv), "measures_length", True) for lv in levels):
        return True
    return bool(ds.setup.subset(used_blocks(ds, levels)).distances)


def scale_length(model, names) -> str | None:
    """The length among ``names`` that fixes the scale: the robot's longest link length (the one whose
    typical deviation is the smallest share of it); a base or tool length only when there is no link's;
    None when every length is zero at nominal (holding a zero length fixes no scale)."""
    slots = set(model.slot_names)
    lengths = [n for n in names if n in slots and not model.slot_is_angle[model.slot(n)]]
    links = [n for n in lengths if not n.startswith(("base.", "tool."))] or lengths
    if not links:
        return None
    best = max(links, key=lambda n: abs(float(model.nominal[model.slot(n)])))
    return best if abs(float(model.nominal[model.slot(best)])) > 1e-9 else None


def gauge_holds(ds: Dataset, model, names, levels, scale: bool = True, tool: bool = True) -> tuple[list, list]:
    """``(names, held)``: ``names`` less the gauges' parameters, and ``held`` (``{"name", "value"``
    (file units), ``"reason"}`` each): the base where nothing fixes the world frame, (``tool``) the
    tool where the cameras see it only through an unknown pose on it, and (``scale``) the longest
    link length where nothing fixes the scale (:func:`scale_is_fixed`)."""
    nominal = model.slots_to_file_units(model.nominal)
    held: list[dict] = []

    def hold(chosen, reason):
        held.extend({"name": n, "value": float(nominal[model.slot(n)]), "reason": reason} for n in chosen)
        return [n for n in names if n not in chosen]

    if not world_is_fixed(ds, levels):
        names = hold([n for n in names if n.startswith("base.")], GAUGE_REASON)
        if held:
            log.info("the world frame: %s", GAUGE_REASON)
    if tool and tool_is_free(ds, levels):
        names = hold([n for n in names if n.startswith("tool.")], TOOL_GAUGE_REASON)
        log.info("%s", TOOL_GAUGE_REASON)
    if scale and not scale_is_fixed(ds, levels):
        chosen = scale_length(model, names)
        if chosen is not None:
            names = hold([chosen], SCALE_REASON)
            log.info("%s is held at %g: %s", chosen, held[-1]["value"], SCALE_REASON)
    return list(names), held
