"""What a calibration result keeps of its solution besides the estimates: each level's residual
summary (RMS, sigma, variance factor, redundancy), the set-up unknowns' record and the joint-error
block's. No I/O here.
"""
from __future__ import annotations

import numpy as np

from fgcal.estimation.gauge import GAUGE_REASON
from fgcal.estimation.graph import Graph, State
from fgcal.estimation.options import CalibrationOptions
from fgcal.estimation.result import LevelSummary
from fgcal.measurements.types import BY_LEVEL

__all__ = ["joint_error_info", "level_summaries", "setup_info"]


def level_summaries(graph: Graph, state: State, lin=None) -> dict[str, LevelSummary]:
    """Each level's :class:`LevelSummary` at ``state`` (its linearisation ``lin``); the redundancy from
    the leverage at the information's inverse the noise rounds took
    (:meth:`~fgcal.estimation.graph.Graph.information_inverse`)."""
    lin = graph.linearise(state) if lin is None else lin
    # the information's inverse the noise rounds took at this linearisation (their leverage is kept on it)
    red = graph.leverage_by_level(state, graph.information_inverse(state, lin), lin)
    out = {}
    units = {"probes": "mm", "kinematic": "mm", "joints": "deg", "prior": "-", "constraints": "mm"}
    sig = graph.sigmas
    for level, (e, s, w) in lin.raw.items():
        n_rows, h = red.get(level, (0, 0.0))
        if level in graph.excluded:
            e = e[~graph.excluded[level]]
        redundancy = n_rows - h
        vf = float(np.sum(w * s**2) / redundancy) if redundancy > 1e-9 else float("nan")
        if level in BY_LEVEL:
            kind = BY_LEVEL[level]
            dist, angle = kind.metric(e)
            sigma, sigma_angle = kind.reported_sigma(sig)
            out[level] = LevelSummary(len(e), _rms(dist), getattr(kind, "unit", "mm"), sigma, vf, redundancy,
                                      None if angle is None else _rms(angle), sigma_angle)
            continue
        norms = np.linalg.norm(np.reshape(e, (len(e), -1)), axis=1)
        scale = np.degrees(1.0) if level == "joints" else 1.0
        sigma = {"probes": sig.probe, "kinematic": sig.kinematic,
                 "joints": _joint_sigma_file_units(graph), "prior": float("nan"),
                 "constraints": float("nan")}[level]
        out[level] = LevelSummary(len(e), float(np.sqrt(np.mean(norms**2)) * scale), units[level], float(sigma),
                                  vf, redundancy)
    return out


def _rms(values) -> float:
    return float(np.sqrt(np.mean(np.asarray(values) ** 2)))


def _joint_sigma_file_units(graph: Graph) -> float:
    """The largest joint reading sigma in file units (deg; mm for prismatic joints)."""
    model = graph.params.model
    sig = np.broadcast_to(np.asarray(graph.sigmas.joint, dtype=float), (model.n_joints,))
    return float(np.max(model.joints_to_file_units(sig)))


def setup_info(graph: Graph, state: State, held_info, refused=()) -> dict:
    """What a result keeps of the set-up unknowns (see :class:`CalibrationResult`); with cameras
    also their start and the refused corners."""
    if graph.setup is None:
        return {}
    out = {**graph.setup.spec.to_dict(), "estimated": graph.setup.describe(graph.setup_values(state.theta))}
    if any(f.type == "camera" for f in graph.setup.spec.fixtures.values()):
        out["start"] = graph.setup.describe(graph.setup.start)
    if refused:
        out["refused"] = list(refused)
    if any(h["reason"] == GAUGE_REASON for h in held_info):
        out["gauge"] = GAUGE_REASON
    return out


def joint_error_info(params, options: CalibrationOptions, qd) -> dict:
    """What a result keeps of its joint-error block: the spec, the names, the joint region (file units)."""
    if getattr(params, "block", None) is None:  # BlockParameters, or set-up parameters around them
        return {}
    names = list(params.block.names)
    assert options.joint_errors is not None  # a block is built only from a spec
    return {"spec": options.joint_errors.to_dict(), "names": names,
            "map_terms": sum(n.startswith("map.") for n in names),
            "joint_ranges_deg": [[float(lo), float(hi)] for lo, hi in zip(qd.min(axis=0), qd.max(axis=0))],
            "validity": "the joint error map holds only inside these joint ranges and in the set-up it was "
                        "fitted on (tool, payload, mounting)" if any(n.startswith("map.") for n in names) else ""}
