"""How every written file spells a number: no negative zero, no float noise, still exact.

``format_number(-0.0)`` is ``"0"``, ``format_number(0.00731 * 1000)`` is ``"7.31"`` (not
``7.3100000000000005``), and every other value keeps its round-trip ``repr``: a value is shortened
only when the short form is within two units in the last place of it (noise of a unit conversion
or a subtraction, never a digit of data).
"""
from __future__ import annotations

import math
import sys

__all__ = ["clean_number", "finite_number", "format_number"]

SHORT_DIGITS = 10  # significant digits of the short form tried first


def finite_number(value) -> bool:
    """Whether a value read from JSON or YAML is a finite number: a float that is finite, or an int a
    float can hold (their integers are unbounded: ``math.isfinite(10**400)`` raises OverflowError);
    never a bool."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    return math.isfinite(value) if isinstance(value, float) else abs(value) <= sys.float_info.max


def clean_number(value: float) -> float:
    """``value`` without negative zero, snapped to its short decimal form when that is within 2 ulp."""
    v = float(value)
    if v == 0.0:
        return 0.0
    if not math.isfinite(v):
        return v
    short = float(f"{v:.{SHORT_DIGITS}g}")
    return short if abs(short - v) <= 2 * math.ulp(v) else v


def format_number(value: float) -> str:
    """The text of ``value`` in a written file (CSV cell, URDF attribute): ``repr`` of :func:`clean_number`."""
    return repr(clean_number(value))
