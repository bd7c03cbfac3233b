"""Contact consistency: how well a model puts a fixture's ball centres at one point (or plane).

For each fixture of a contacts dataset the predicted ball centres (the model's forward kinematics
at the readings) are refitted to a common point (their mean) or plane (least squares); the
consistency is the RMS and max distance of the centres from it, and each known distance
between two fixture points is compared with the distance of their refitted points. The metric
needs no instrument and no world frame: a new placement of a fixture is refitted (DESIGN.md
8.2). No I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgcal.robots.kinematics import tool_points

__all__ = ["ContactConsistency", "DistanceCheck", "FixtureConsistency", "contact_consistency"]


@dataclass
class FixtureConsistency:
    """One fixture: ``n`` contacts, RMS and max distance (mm) of their centres from the refitted point or plane."""

    name: str
    type: str
    n: int
    rms_mm: float
    max_mm: float


@dataclass
class DistanceCheck:
    """A known distance between two fixture points against the refitted points' distance (mm)."""

    a: str
    b: str
    known_mm: float
    model_mm: float

    @property
    def error_mm(self) -> float:
        return self.model_mm - self.known_mm


@dataclass
class ContactConsistency:
    """Per fixture and per known distance; ``pose_ids``/``distance_mm``: each contact's distance
    from its fixture's refitted point or plane (mm), in the order of the contacts."""

    fixtures: list
    distances: list
    pose_ids: np.ndarray
    distance_mm: np.ndarray

    def summary(self) -> dict:
        fx = [vars(f) for f in self.fixtures]
        dist = [{"a": d.a, "b": d.b, "known_mm": d.known_mm, "model_mm": d.model_mm, "error_mm": d.error_mm}
                for d in self.distances]
        both = np.array([f.rms_mm for f in self.fixtures])
        n = np.array([f.n for f in self.fixtures])
        errs = np.abs([d.error_mm for d in self.distances])
        return {"consistency_mm": {"rms": float(np.sqrt(np.sum(n * both**2) / n.sum())) if n.sum() else float("nan"),
                                   "max": float(max((f.max_mm for f in self.fixtures), default=float("nan"))),
                                   "per_fixture": fx},
                "distance_mm": {"mean_abs": float(errs.mean()) if errs.size else None,
                                "max_abs": float(errs.max()) if errs.size else None, "per_distance": dist}}


def contact_consistency(model, slots, q, pose_ids, balls, fixtures, offsets_of, spec, radius=0.0) -> ContactConsistency:
    """The consistency of ``model`` at ``slots`` (S,) for contacts at readings ``q`` (M, n) (internal
    units), one per row: ``pose_ids`` (M,), ``balls`` (M,), ``fixtures`` (M,) names; ``offsets_of(balls)``
    gives the tool-frame centres (M, 3); ``spec`` the dataset's :class:`~fgcal.measurements.setup.SetupSpec`."""
    fixtures = np.asarray(fixtures, dtype=str)
    T = model.forward(slots, q)
    c = tool_points(T, offsets_of(balls)[:, None, :])[:, 0]
    dist = np.zeros(len(c))
    points, out = {}, []
    for name in dict.fromkeys(fixtures.tolist()):
        sel = fixtures == name
        pts = c[sel]
        kind = spec.fixtures[name].type if name in spec.fixtures else "point"
        if kind == "point":
            centre = pts.mean(axis=0)
            points[name] = centre
            d = np.linalg.norm(pts - centre, axis=1)
        else:
            centre = pts.mean(axis=0)
            n = np.linalg.svd(pts - centre)[2][2] if len(pts) >= 3 else np.array([0.0, 0.0, 1.0])
            d = np.abs((pts - centre) @ n)
        dist[sel] = d
        out.append(FixtureConsistency(name, kind, int(sel.sum()), float(np.sqrt(np.mean(d**2))), float(d.max())))
    checks = [DistanceCheck(k.a, k.b, k.distance, float(np.linalg.norm(points[k.a] - points[k.b])))
              for k in spec.distances if k.a in points and k.b in points]
    return ContactConsistency(out, checks, np.asarray(pose_ids, dtype=int), dist)
