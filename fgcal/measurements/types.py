"""The registry of kinematic measurement types, in the order the graph lays out their rows.

Adding a type: write its module (a :class:`fgcal.measurements.base.KinematicMeasurement`) and call
:func:`register` (or add it to the built-ins here). Probe points (:mod:`fgcal.measurements.probe`)
have variables of their own and come first. Several types may share a file (``contacts.csv``
holds the contacts at points and on planes): the dataset keeps one level per type.
"""
from __future__ import annotations

from typing import Any

from fgcal.measurements.contact import CONTACT, PLANE_CONTACT
from fgcal.measurements.distance import DISTANCE
from fgcal.measurements.pixels import PIXELS
from fgcal.measurements.point import POINT
from fgcal.measurements.pose import POSE
from fgcal.measurements.station import STATION_POINT

__all__ = [
    "BY_LEVEL",
    "KINEMATIC_TYPES",
    "LEVELS",
    "all_levels",
    "kinematic_levels",
    "kinematic_types",
    "noise_keys",
    "register",
    "unregister",
]

# Plug-ins: a KinematicMeasurement, or a SetupMeasurement (with uses_setup): duck-typed, hence Any.
KINEMATIC_TYPES: tuple[Any, ...] = (POINT, POSE, DISTANCE, CONTACT, PLANE_CONTACT, STATION_POINT, PIXELS)
BY_LEVEL: dict[str, Any] = {t.level: t for t in KINEMATIC_TYPES}
LEVELS = ("probes",) + tuple(BY_LEVEL)  # the dataset's measurement levels, richest first


def register(kind) -> None:
    """Add a measurement type to the registry (every consumer reads it at call time).

    Raises
    ------
    ValueError
        If a type of the same level is registered already.
    """
    global KINEMATIC_TYPES
    if kind.level in BY_LEVEL or kind.level == "probes":
        raise ValueError(f"a measurement type of level {kind.level!r} is registered already")
    KINEMATIC_TYPES = KINEMATIC_TYPES + (kind,)
    BY_LEVEL[kind.level] = kind


def unregister(kind) -> None:
    """Remove a type added by :func:`register`."""
    global KINEMATIC_TYPES
    KINEMATIC_TYPES = tuple(t for t in KINEMATIC_TYPES if t is not kind)
    BY_LEVEL.pop(kind.level, None)


def kinematic_types() -> tuple:
    """The registered kinematic types (read at call time: a test may register one more)."""
    return KINEMATIC_TYPES


def all_levels() -> tuple:
    """Every measurement level: probes, then the registered kinematic types."""
    return ("probes",) + tuple(t.level for t in KINEMATIC_TYPES)


def kinematic_levels(levels) -> list:
    """The kinematic types among ``levels``, in registry order."""
    return [t for t in KINEMATIC_TYPES if t.level in levels]


def noise_keys() -> tuple:
    """The ``noise:`` keys the registered types declare beyond the built-in ones."""
    return tuple(dict.fromkeys(k for t in KINEMATIC_TYPES if (k := getattr(t, "noise_key", None))))
