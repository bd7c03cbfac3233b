"""The world frame's gauge and the size of the set-up blocks a dataset's levels use (DESIGN.md 8.1).

Where nothing in the data fixes the world frame (contacts with unknown fixtures only), the
calibration holds the base at nominal and says so (:data:`GAUGE_REASON`). No I/O here.
"""
from __future__ import annotations

from fgcal.measurements.dataset import Dataset
from fgcal.measurements.setup import BLOCK_KINDS
from fgcal.measurements.types import BY_LEVEL

__all__ = ["GAUGE_REASON", "TOOL_GAUGE_REASON", "setup_size", "tool_is_free", "used_blocks", "world_is_fixed"]


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
