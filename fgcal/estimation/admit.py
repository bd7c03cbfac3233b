"""Rows a measurement type refuses before the solve (a camera's corners behind it, at a grazing
angle or off the image: :meth:`fgcal.measurements.pixels.Pixels.admit`), named in the result.
No I/O here."""
from __future__ import annotations

import copy

from fgcal.measurements.dataset import Dataset
from fgcal.measurements.types import BY_LEVEL
from fgcal.robots.model import RobotModel

__all__ = ["admit_rows"]


def admit_rows(ds: Dataset, model: RobotModel, levels) -> tuple[Dataset, list]:
    """``ds`` without the rows its types refuse at the nominal geometry, and the refused rows
    (``{"level", "pose", ..., "reason"}``); ``ds`` itself when nothing is refused."""
    refused: list = []
    for lv in levels:
        kind = BY_LEVEL.get(lv)
        obs = getattr(ds, lv, None)
        if kind is None or obs is None or not hasattr(kind, "admit"):
            continue
        q = model.joints_to_internal(ds.joints_deg[ds.row_of(obs.pose)])
        keep, out = kind.admit(obs, model.forward(model.nominal, q))
        if out:
            ds = copy.copy(ds)
            setattr(ds, lv, obs.subset(keep))
            refused += [{"level": lv, **r} for r in out]
    return ds, refused
