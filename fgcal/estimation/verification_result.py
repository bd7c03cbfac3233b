"""The records of a verification: errors of a model against a reference, per pose and summarised.

:class:`Verification` holds a model's calibrated and nominal errors (:class:`Comparison`, and a
camera's :class:`ToolPointErrors`) and writes them as ``verify.json``. These are what
:func:`~fgcal.estimation.verification.verify` and
:func:`~fgcal.estimation.verify_pixels.verify_pixels` return. No computation of errors here.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["Comparison", "ErrorStats", "ToolPointErrors", "Verification", "error_stats"]


@dataclass
class ErrorStats:
    mean: float
    rms: float
    max: float


def error_stats(values) -> ErrorStats:
    v = np.asarray(values, dtype=float)
    if not v.size:
        return ErrorStats(float("nan"), float("nan"), float("nan"))
    return ErrorStats(float(v.mean()), float(np.sqrt(np.mean(v**2))), float(v.max()))


@dataclass
class Comparison:
    """Errors of one model against one reference, per pose (mm, deg) and summarised.

    ``orientation_deg`` is None for position-only data (a reflector, one or two balls).
    """

    position_mm: np.ndarray
    orientation_deg: np.ndarray | None
    error_xyz_mm: np.ndarray | None = None  # (K, 3) reference - model (mean over a pose's points), world frame

    def summary(self) -> dict:
        return {"position_mm": vars(error_stats(self.position_mm)),
                "orientation_deg": None if self.orientation_deg is None else vars(error_stats(self.orientation_deg))}


@dataclass
class ToolPointErrors:
    """A camera's tool-point error implied at each pose (mm, :func:`~fgcal.estimation.verify_pixels.tool_point_errors`):
    ``what`` it measures (the target's points on the tool, or the camera's centre), calibrated and nominal (K,)."""

    what: str
    after: np.ndarray
    before: np.ndarray

    def summary(self, values) -> dict:
        v = np.asarray(values, dtype=float)
        return {"tool_point_mm": vars(error_stats(v[np.isfinite(v)])), "tool_point": self.what}


@dataclass
class Verification:
    """Calibrated and nominal errors against the measurements, and against the truth if known.

    ``reference`` says what was compared: ``"measured poses"`` (full pose errors) or
    ``"measured points"`` (ball centres or reflector positions: the error of each pose is the RMS
    distance of its points, and there is no orientation error).
    """

    pose_ids: np.ndarray
    after: Comparison
    before: Comparison
    truth_after: Comparison | None = None
    truth_before: Comparison | None = None
    reference: str = "measured poses"
    skipped: list[str] = field(default_factory=list)
    robot: str | None = None
    xyz_mm: np.ndarray | None = None  # (K, 3) measured tool positions (mean of a pose's points), world frame
    joints_deg: np.ndarray | None = None  # (K, n) joint readings in file units (deg; mm for prismatic)
    contacts: dict | None = None  # contacts: {"after": ..., "before": ...} of ContactConsistency.summary()
    tool_points: ToolPointErrors | None = None  # a camera's: the tool-point error implied (mm)

    def save(self, path) -> None:
        """Write :meth:`to_dict` as ``verify.json`` (``fgcal-verify/1``), atomically."""
        import json

        from fgcal.util.yamlio import atomic_write_text

        atomic_write_text(path, json.dumps(self.to_dict(), indent=1) + "\n")

    def to_dict(self) -> dict:
        d: dict[str, Any] = {"format": "fgcal-verify/1", "n_poses": int(len(self.pose_ids)), "reference": self.reference}
        if self.robot is not None:
            d["robot"] = self.robot
        d.update(self.after.summary())
        d["before"] = self.before.summary()
        if self.truth_after is not None:
            d["truth"] = self.truth_after.summary()
            if self.truth_before is not None:
                d["truth"]["before"] = self.truth_before.summary()
        n = len(self.pose_ids)
        none = [None] * n

        def values(v):
            return none if v is None else [float(x) for x in v]

        d["poses"] = [
            {"pose": int(p), "position_mm": a, "orientation_deg": o, "before_position_mm": bp,
             "before_orientation_deg": bo}
            for p, a, o, bp, bo in zip(self.pose_ids, values(self.after.position_mm), values(self.after.orientation_deg),
                                       values(self.before.position_mm), values(self.before.orientation_deg))]
        for k, pose in enumerate(d["poses"]):  # additions of fgcal-verify/1 (readers may ignore them)
            if self.xyz_mm is not None:
                pose["xyz_mm"] = [float(v) for v in self.xyz_mm[k]]
            if self.after.error_xyz_mm is not None and self.before.error_xyz_mm is not None:
                pose["error_xyz_mm"] = [float(v) for v in self.after.error_xyz_mm[k]]
                pose["before_error_xyz_mm"] = [float(v) for v in self.before.error_xyz_mm[k]]
            if self.joints_deg is not None:
                pose["joints_deg"] = [float(v) for v in self.joints_deg[k]]
            if self.truth_after is not None:
                pose["truth_position_mm"] = float(self.truth_after.position_mm[k])
            if self.tool_points is not None:
                pose["tool_point_mm"] = _finite_or_none(self.tool_points.after[k])
                pose["before_tool_point_mm"] = _finite_or_none(self.tool_points.before[k])
        d["skipped"] = self.skipped
        if self.tool_points is not None:
            d.update(self.tool_points.summary(self.tool_points.after))
            d["before"].update(self.tool_points.summary(self.tool_points.before))
        if self.contacts is not None:
            d.update(self.contacts["after"])
            d["before"].update(self.contacts["before"])
        return d


def _finite_or_none(v) -> float | None:
    return float(v) if np.isfinite(v) else None
