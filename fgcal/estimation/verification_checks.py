"""Checks of what verification compares: the same robot as the result's, and the shape of a loaded
``fgcal-verify/1`` mapping. No I/O here."""
from __future__ import annotations

import numpy as np

from fgcal.errors import FgcalError
from fgcal.estimation.result import CalibrationResult
from fgcal.robots.model import RobotModel

__all__ = ["check_same_robot", "check_verification"]


def check_same_robot(result: CalibrationResult, model: RobotModel, where="dataset",
                     length_tol_mm: float = 1.0, angle_tol_deg: float = 0.5) -> None:
    """Raise ``FgcalError`` unless ``result`` was computed for a robot with ``model``'s link geometry.

    Base and tool may differ (they are refitted per set-up); the joints' nominal geometry (the
    ``j*`` slots) must agree within the tolerances.
    """
    mine = result.model()
    a, b = np.asarray(mine.nominal, dtype=float), np.asarray(model.nominal, dtype=float)
    names = list(model.slot_names)
    if a.shape != b.shape or list(mine.slot_names) != names:
        raise FgcalError(f"{where}: robot {model.name} ({model.n_joints} joints, {len(b)} geometric slots) is not "
                         f"the robot of the result ({mine.name}, {mine.n_joints} joints, {len(a)} slots)")
    angle = np.asarray(model.slot_is_angle, dtype=bool)
    link = np.array([not n.startswith(("base.", "tool.")) for n in names])
    tol = np.where(angle, np.radians(angle_tol_deg), length_tol_mm)
    off = link & (np.abs(a - b) > tol)
    if off.any():
        i = int(np.argmax(np.where(off, np.abs(a - b) / tol, 0)))
        scale, unit = (np.degrees(1.0), "deg") if angle[i] else (1.0, "mm")
        raise FgcalError(f"{where}: robot {model.name} is not the robot of the result ({mine.name}): "
                         f"{names[i]} is {b[i] * scale:.6g} {unit} here and {a[i] * scale:.6g} {unit} in the result")


def check_verification(d, where="verification") -> dict:
    """Raise ``FgcalError`` unless ``d`` has the shape of an ``fgcal-verify/1`` mapping; returns it."""
    def number(v):
        return isinstance(v, (int, float)) and not isinstance(v, bool)

    def summary(s, label):
        for key in ("position_mm", "orientation_deg"):
            part = s.get(key) if isinstance(s, dict) else None
            if key == "orientation_deg" and part is None:  # position-only data
                continue
            if not isinstance(part, dict) or not all(number(part.get(k)) for k in ("mean", "rms", "max")):
                raise FgcalError(f"{where}: {label}{key} must hold numbers mean, rms and max")

    if not isinstance(d, dict) or d.get("format") != "fgcal-verify/1":
        raise FgcalError(f"{where}: not an fgcal-verify/1 file")
    summary(d, "")
    summary(d.get("before"), "before.")
    if "truth" in d:
        summary(d["truth"], "truth.")
        summary(d["truth"].get("before"), "truth.before.")
    poses = d.get("poses", [])
    keys = ("position_mm", "orientation_deg", "before_position_mm", "before_orientation_deg")
    if not isinstance(poses, list):
        raise FgcalError(f"{where}: poses must be a list")
    for i, p in enumerate(poses):
        if not isinstance(p, dict) or not all(number(p.get(k)) or (k.endswith("orientation_deg") and p.get(k) is None)
                                              for k in ("pose", *keys)):
            raise FgcalError(f"{where}: poses[{i}] must hold numbers pose, {', '.join(keys)}")
    return d
