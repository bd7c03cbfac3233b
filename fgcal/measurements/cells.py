"""Checked conversion of one text cell of a measurement file to a number (pure; raises ``DatasetError``)."""
from __future__ import annotations

import math

from fgcal.errors import DatasetError
from fgcal.util.yamlio import short_repr

__all__ = ["MAX_DEG", "MAX_MM", "ball_name", "integer", "number", "pose_id"]

# Bounds beyond which a value is a mistake, not a measurement: 1000 km, or a million degrees.
MAX_MM = 1e9
MAX_DEG = 1e6


def number(text: str, where: str, what: str, limit: float = MAX_MM) -> float:
    """``text`` as a finite float of magnitude at most ``limit``; ``where`` names the file and line."""
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise DatasetError(f"{where}: {what} is not a number: {short_repr(text)}") from None
    if not math.isfinite(value):
        raise DatasetError(f"{where}: {what} is not finite: {short_repr(text)}")
    if abs(value) > limit:
        raise DatasetError(f"{where}: {what} = {text} is absurdly large (beyond {limit:g}; a unit mistake?)")
    return value


def integer(text: str, where: str, what: str) -> int:
    try:
        return int(text)
    except (TypeError, ValueError):
        raise DatasetError(f"{where}: {what} must be an integer id, got {short_repr(text)}") from None


def pose_id(text: str, where: str, known_poses) -> int:
    """A pose id that has joint readings."""
    pid = integer(text, where, "pose")
    if pid not in known_poses:
        raise DatasetError(f"{where}: pose {pid} has no joint readings in joints.csv")
    return pid


def ball_name(text: str, where: str, balls) -> str:
    """A ball the dataset's tool has."""
    if text not in balls:
        raise DatasetError(f"{where}: unknown ball {short_repr(text)} (dataset.yaml tool.balls has {', '.join(balls)})")
    return text
