"""Cross-validation of the models beyond geometry on the training poses (No I/O here).

:func:`cv_problem` linearises the training data once at the geometric solution over the geometry
and every candidate joint-error parameter (:class:`CVProblem`); :func:`cross_validate` deals the
poses into folds (repeated configurations kept in one fold, :class:`FoldOrder`) and predicts each
fold by every candidate model fitted to the others, over a grid of error maps (number of harmonics
x prior strength). :func:`fgcal.estimation.model_select.compare_models` chooses among them.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from enum import Enum

import numpy as np

from fgcal.estimation.build import build_graph
from fgcal.estimation.joint_errors import JointErrorSpec, ModelKind
from fgcal.estimation.options import CalibrationOptions
from fgcal.estimation.time_validation import FoldSums, harmonic
from fgcal.measurements.dataset import Dataset
from fgcal.robots.model import RobotModel

__all__ = ["HARMONICS_GRID", "SIGMA_GRID", "CVProblem", "FoldOrder", "cross_validate", "cv_problem"]

HARMONICS_GRID = (1, 2, 3, 4, 6, 8, 10, 12, 15, 18, 22, 26, 30)
MAX_GRID_GROWTH = 6  # steps the map prior's grid grows by while the optimum is on its edge
SIGMA_GRID = tuple(float(s) for s in np.geomspace(1e-6, 3e-4, 8))  # rad


@dataclass
class CVProblem:
    """The linearised training problem, per pose.

    Attributes
    ----------
    r : ndarray, shape (N, m)
        Whitened residuals at the geometric solution.
    J : ndarray, shape (N, m, P)
        Whitened Jacobian w.r.t. the geometry and every candidate joint-error parameter.
    metric_rows : ndarray of int, shape (N, 3)
        Rows holding each pose's measured position; ``metric_scale`` turns them into mm.
    names : list of str
        Column names: the geometry's (``n_geometric``) then the block's.
    groups : ndarray of int, shape (N,)
        Repeated configurations share a group.
    """

    r: np.ndarray
    J: np.ndarray
    metric_rows: np.ndarray
    metric_scale: float
    names: list
    n_geometric: int
    groups: np.ndarray
    unit: str = "mm"
    pose_ids: np.ndarray | None = None  # (N,) the rows' poses; their order is time order


def _groups(q_rad, resolution_deg: float = 0.1) -> np.ndarray:
    keys: dict[tuple, int] = {}
    return np.array([keys.setdefault(tuple(k), len(keys)) for k in np.round(np.degrees(q_rad) / resolution_deg)])


def cv_problem(ds: Dataset, model: RobotModel, geometric_result, spec_max: JointErrorSpec,
               options: CalibrationOptions = CalibrationOptions()) -> CVProblem:
    """Linearise the training data at ``geometric_result`` over the geometry and ``spec_max``'s block."""
    geo_names = list(geometric_result.names)
    names = geo_names + spec_max.names(model.n_joints)
    opts = replace(options, joint_noise=False, robust=None, prior="none", joint_errors=spec_max)
    scale = {k: float(v) for k, v in (geometric_result.options.get("noise_scale") or {}).items()}
    graph, state, pose_ids = build_graph(ds, model, names, opts, scale=scale)
    graph.held = geometric_result.slot_vector(model)
    state.theta = graph.params.take(graph.held)
    lin = graph.linearise(state)
    r, J = lin.r, lin.J_theta
    if J.shape[1] < r.shape[1]:  # J_theta holds each pose's first rows; the later ones (probes) do not see theta
        J = np.concatenate([J, np.zeros((J.shape[0], r.shape[1] - J.shape[1], J.shape[2]))], axis=1)
    if graph.nz:  # project out per-pose variables (ball centres): what remains sees theta only
        Q, _ = np.linalg.qr(lin.J_local)
        r = r - np.einsum("nmz,nz->nm", Q, np.einsum("nmz,nm->nz", Q, r))
        J = J - np.einsum("nmz,nzp->nmp", Q, np.einsum("nmz,nmp->nzp", Q, J))
    if "poses" in graph.row:
        start, unit_scale, pose = graph.row["poses"] + 3, graph.sigmas.pose_position, graph.measurements["poses"].pose
    elif "centres" in graph.row:
        start, unit_scale, pose = graph.row["centres"], graph.sigmas.centre, graph.measurements["centres"].pose
    else:
        start, unit_scale, pose = None, 1.0, None
    if start is None:
        rows = np.tile(np.arange(3), (graph.n_poses, 1))
        unit = "sigma"
    else:
        first = np.full(graph.n_poses, -1)
        first[pose[::-1]] = start[::-1]  # the first measured position of each pose
        rows = first[:, None] + np.arange(3)
        unit = "mm"
    return CVProblem(r, J, rows, float(unit_scale), names, len(geo_names), _groups(graph.readings), unit,
                     np.asarray(pose_ids))


class FoldOrder(str, Enum):
    """How poses are dealt into folds: at random, or in contiguous blocks of the poses' order
    (pose ids in time order: each fold is then a stretch of the session, which tests the models
    against drift, as a later verification set would)."""

    RANDOM = "random"
    BLOCKED = "blocked"


def _folds(groups, k: int, rng, order: FoldOrder = FoldOrder.RANDOM) -> np.ndarray:
    unique = np.unique(groups)  # group ids number the groups in order of first appearance
    fold_of_group = np.empty(unique.max() + 1, dtype=int)
    if FoldOrder(order) is FoldOrder.BLOCKED:
        fold_of_group[unique] = np.arange(len(unique)) * k // len(unique)
    else:
        fold_of_group[rng.permutation(unique)] = np.arange(len(unique)) % k
    return fold_of_group[groups]


def cross_validate(prob: CVProblem, folds: int, rng, harmonics_grid=HARMONICS_GRID, sigma_grid=SIGMA_GRID,
                   order: FoldOrder = FoldOrder.RANDOM):
    """Per-pose cross-validated errors of the candidate models.

    Returns
    -------
    dict
        ``{"geometric": (err (N,), spec_kw), "compliance": ..., "compliance+map": ...}``; ``spec_kw``
        holds the chosen ``harmonics`` and ``map_sigma`` for the map, and ``at_edge``: sentences
        naming where the optimum stopped at the edge of the grid. The prior's grid grows (x3 a step,
        at most :data:`MAX_GRID_GROWTH` steps) while its optimum is on the upper edge; the harmonics'
        cannot (the linearisation holds the largest only) and ``at_edge`` says so.
    """
    fold = _folds(prob.groups, folds, rng, order)
    sums = FoldSums(prob, fold, folds)
    geo = list(range(prob.n_geometric))
    comp = [i for i, n in enumerate(prob.names) if n.endswith(".compliance")]
    inf = [np.inf] * len(geo)
    comp_sigma = [JointErrorSpec().compliance_sigma] * len(comp)
    e_geo, e_comp = sums.held_out_errors_many([(geo, inf), (geo + comp, inf + comp_sigma)])
    out: dict[str, tuple[np.ndarray, dict]] = {ModelKind.GEOMETRIC.value: (e_geo, {}),
                                                ModelKind.COMPLIANCE.value: (e_comp, {})}
    best = None
    maps = {}
    for h in harmonics_grid:
        mp = [i for i, n in enumerate(prob.names) if n.startswith("map.") and harmonic(n) <= h]
        if mp:
            maps[int(h)] = mp
    sigmas = sorted(float(s) for s in sigma_grid)
    tried: set = set()
    for _ in range(MAX_GRID_GROWTH + 1):
        new = [(h, s) for h, mp in maps.items() for s in sigmas if (h, s) not in tried]
        tried.update(new)
        # a round's candidates in one pass over the Jacobian, then judged in the grid's order
        errors = sums.held_out_errors_many([(geo + comp + maps[h], inf + comp_sigma + [s] * len(maps[h]))
                                            for h, s in new]) if new else []
        for (h, s), e in zip(new, errors):
            if best is None or e.mean() < best[0].mean():
                best = (e, {"harmonics": h, "map_sigma": s})
        # The prior's grid grows (x3 a step) while the optimum sits on its upper edge (on the lower
        # one the map is shrunk away: the compliance model, an optimum inside what the grid means).
        if best is None or len(sigmas) < 2 or best[1]["map_sigma"] != sigmas[-1]:
            break
        sigmas.append(sigmas[-1] * 3.0)
    if best is not None:
        edge = []
        if len(sigmas) > 1 and best[1]["map_sigma"] == sigmas[-1]:
            edge.append(f"the map's prior at the edge of its grid ({best[1]['map_sigma'] * 1e6:.3g} urad after "
                        f"{MAX_GRID_GROWTH} steps of growth)")
        if len(maps) > 1 and best[1]["harmonics"] == max(maps):
            edge.append(f"the map's size at the largest number of harmonics tried ({max(maps)}): the optimum may "
                        "lie beyond it")
        out[ModelKind.COMPLIANCE_MAP.value] = (best[0], {**best[1], "at_edge": edge})
    return out
