"""Reading the small comma lists options and API arguments take: finite numbers of a given count,
and the ``BASE,TIP`` pair of links of a chain. One reader each, for every caller."""
from __future__ import annotations

import numpy as np

from fgcal.errors import FgcalError

__all__ = ["chain_links", "finite_floats"]


def finite_floats(value, sizes) -> np.ndarray | None:
    """``"a,b,c"`` or a sequence as finite floats ``(k,)`` when their count ``k`` is one of ``sizes``;
    None otherwise (not numbers, not finite, another count): the caller names the option."""
    try:
        v = np.array([float(t) for t in (value.split(",") if isinstance(value, str) else value)], dtype=float)
    except (TypeError, ValueError):
        return None
    return v if len(v) in tuple(sizes) and bool(np.all(np.isfinite(v))) else None


def chain_links(text, option: str = "--chain") -> dict | None:
    """``"BASE,TIP"`` (or such a dict) as the ``{"base": .., "tip": ..}`` of
    :func:`fgcal.robots.robot_file.load_model`; None for None.

    Raises
    ------
    FgcalError
        Unless it is two non-empty link names.
    """
    if text is None:
        return None
    if isinstance(text, dict):
        return text
    parts = [p.strip() for p in str(text).split(",")]
    if len(parts) != 2 or not all(parts):
        raise FgcalError(f"{option} {text!r}: expected BASE,TIP (two URDF link names)")
    return {"base": parts[0], "tip": parts[1]}
