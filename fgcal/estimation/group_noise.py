"""Noise groups within one variance component: each camera's pixel noise (DESIGN.md 8.4).

A measurement type whose rows fall into groups of their own noise (a camera's corners: each camera
its own ``pixel_sigma``) names them (``noise_groups(terms, layout) -> {name: rows (M,) bool}``)
and weights each row in its payload (``group_weight(terms) -> (M,)``, the component's sigma over
the row's). The component's sigma is estimated as any other's (:mod:`fgcal.estimation.noise`);
here each group's share of it: Foerstner's variance factor of the group's rows (squared whitened
residuals over their redundancy) relative to the component's pooled factor rescales the group's
weights, until every group's factor is the component's. Reported per group with the group's own
declared sigma, the one used and the one estimated. No I/O here.
"""
from __future__ import annotations

import logging

import numpy as np

from fgcal.estimation.noise import MIN_REDUNDANCY, LevelNoise, NoiseMode, component_table, noise_row
from fgcal.measurements.types import BY_LEVEL

__all__ = ["group_noise", "update_groups"]

log = logging.getLogger(__name__)

GROUP_LIMITS = (0.1, 10.0)  # a group's sigma relative to its declared one stays within these


def _groups(graph):
    """``(level, kind, terms, {name: rows}, component name)`` of each type with noise groups."""
    comps = {lv: name for name, (lv, *_rest) in component_table().items()}
    for level, terms in graph.measurements.items():
        kind = BY_LEVEL[level]
        if not hasattr(kind, "noise_groups") or level not in comps:
            continue
        groups = kind.noise_groups(terms, graph.setup)
        if groups:
            yield level, kind, terms, groups, comps[level]


def _weights(graph, level, kind, terms) -> tuple[np.ndarray, np.ndarray]:
    """The rows' weights in the payload (M,) (rescaled in place) and those they had at the start
    (kept on the graph: ``graph.declared_weights[level]``)."""
    weight = kind.group_weight(terms)
    if not hasattr(graph, "declared_weights"):
        graph.declared_weights = {}
    return weight, graph.declared_weights.setdefault(level, weight.copy())


def _factors(graph, lin, h, level, groups):
    """Per group: (sum of squared whitened residuals, redundancy) of its kept rows."""
    pose, rows = graph.factor_rows(level)
    kept = ~graph.excluded.get(level, np.zeros(len(pose), dtype=bool))
    r2 = lin.r[pose[:, None], rows] ** 2
    red = 1.0 - h[pose[:, None], rows]
    return {name: (float(r2[mask & kept].sum()), float(red[mask & kept].sum())) for name, mask in groups.items()}


def update_groups(graph, lin, h, tolerance: float = 0.01) -> bool:
    """Rescale each noise group's weights by the square root of its variance factor relative to
    its component's (groups with too little redundancy keep theirs; a group's sigma stays within
    :data:`GROUP_LIMITS` of its declared one); True if any moved by more than ``tolerance``."""
    changed = False
    for level, kind, terms, groups, _ in _groups(graph):
        weight, declared = _weights(graph, level, kind, terms)
        if len(groups) < 2:
            continue
        f = _factors(graph, lin, h, level, groups)
        ssq, red = sum(v[0] for v in f.values()), sum(v[1] for v in f.values())
        if not red > 0 or not ssq > 0:
            continue
        for name, mask in groups.items():
            s, r = f[name]
            if r < MIN_REDUNDANCY or not s > 0:
                continue
            rel = (s / r) / (ssq / red)
            if abs(rel - 1.0) < tolerance:
                continue
            new = np.clip(weight[mask] / np.sqrt(rel), declared[mask] / GROUP_LIMITS[1],
                          declared[mask] / GROUP_LIMITS[0])  # the group's sigma up by sqrt(rel)
            if np.any(np.abs(new - weight[mask]) > 1e-12 * np.abs(weight[mask])):
                weight[mask] = new
                changed = True
                log.debug("noise group %s: variance factor %.3g of the component's", name, rel)
    if changed:  # the weights are the payload's, not the graph's sigmas: its remembered linearisation is stale
        graph._last = None
    return changed


def group_noise(graph, lin, h, declared_sigmas, mode: NoiseMode) -> dict[str, LevelNoise]:
    """The noise table of each group (``{component.group: LevelNoise}``, in the component's unit) at
    the finished solve: the group's declared sigma (the component's declared one over the group's
    declared weight), the one used (the component's used one over its weight now) and the one its
    residuals give (Foerstner's, as :func:`fgcal.estimation.noise.level_noise`)."""
    out = {}
    for level, kind, terms, groups, comp in _groups(graph):
        _, _, field, unit, k = component_table()[comp]
        used_c = float(np.max(getattr(graph.sigmas, field)))
        decl_c = float(np.max(getattr(declared_sigmas, field)))
        weight, declared = _weights(graph, level, kind, terms)
        for name, (ssq, red) in _factors(graph, lin, h, level, groups).items():
            row = int(np.argmax(groups[name]))
            used, decl = used_c / float(weight[row]), decl_c / float(declared[row])
            out[f"{comp}.{name}"] = noise_row(unit, k, used, decl, ssq, red, mode)
    return out
