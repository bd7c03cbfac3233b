"""The registry of kinematic measurement types, in the order the graph lays out their rows.

Adding a type: write its module (a :class:`fgcal.measurements.base.KinematicMeasurement`) and add
it here. Probe points (:mod:`fgcal.measurements.probe`) have variables of their own and come first.
"""
from __future__ import annotations

from fgcal.measurements.distance import DISTANCE
from fgcal.measurements.point import POINT
from fgcal.measurements.pose import POSE

__all__ = ["KINEMATIC_TYPES", "BY_LEVEL", "LEVELS", "kinematic_levels", "all_levels", "kinematic_types"]

KINEMATIC_TYPES = (POINT, POSE, DISTANCE)
BY_LEVEL = {t.level: t for t in KINEMATIC_TYPES}
LEVELS = ("probes",) + tuple(BY_LEVEL)  # the dataset's measurement levels, richest first


def kinematic_types() -> tuple:
    """The registered kinematic types (read at call time: a test may register one more)."""
    return KINEMATIC_TYPES


def all_levels() -> tuple:
    """Every measurement level: probes, then the registered kinematic types."""
    return ("probes",) + tuple(t.level for t in KINEMATIC_TYPES)


def kinematic_levels(levels) -> list:
    """The kinematic types among ``levels``, in registry order."""
    return [t for t in KINEMATIC_TYPES if t.level in levels]
