"""How far an actual robot typically deviates from its nominal model: a domain constant.

The simulator draws its robots with these deviations, the weak prior and the cost of holding a
parameter at nominal are stated in them, and the report compares with them. No I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Deviations"]


@dataclass(frozen=True)
class Deviations:
    """Standard deviations of the actual robot from nominal (DESIGN.md's typical values).

    Attributes
    ----------
    length : float
        Link and tool lengths (mm).
    angle : float
        Link and tool angles (deg).
    base_length : float
        Base placement (mm).
    base_angle : float
        Base orientation (deg).
    """

    length: float = 0.5
    angle: float = 0.05
    base_length: float = 5.0
    base_angle: float = 0.5

    def sigmas(self, names) -> np.ndarray:
        """Per-parameter standard deviations (mm, rad) for the parameter ``names``."""
        out = []
        for name in names:
            block, field = name.rsplit(".", 1)
            is_angle = field in ("phi", "theta", "psi", "alpha", "beta")
            if block == "base":
                out.append(np.radians(self.base_angle) if is_angle else self.base_length)
            else:
                out.append(np.radians(self.angle) if is_angle else self.length)
        return np.array(out)
