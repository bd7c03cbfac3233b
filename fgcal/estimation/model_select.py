"""Choosing a model beyond geometry by cross-validation on the training poses.

For each candidate model (:class:`~fgcal.estimation.joint_errors.ModelKind`) the training poses are split
into K folds (repeated configurations kept in one fold); each fold is predicted by the model fitted
to the others. The fits are linear least squares on the problem linearised at the geometric
solution, with the readings taken as exact, so that a whole grid of error maps (number of
harmonics x prior strength) costs one linearisation. The map's size and prior are chosen by the
cross-validated error; the recommended model is the simplest whose cross-validated error is within
noise (two standard errors of the per-pose difference) of the best, among those whose largest
error is no worse than a simpler model's, on the later poses predicted from the earlier ones where
the data drift (:mod:`fgcal.estimation.time_validation`). The chosen models are then
calibrated with the full factor graph (:func:`fgcal.estimation.calibrate.calibrate`). No I/O here.
"""
from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, field, replace
from enum import Enum

import numpy as np

from fgcal.estimation.build import build_graph
from fgcal.estimation.calibrate import calibrate
from fgcal.estimation.joint_errors import COMPLIANCE_MIN_NM, JointErrorSpec, ModelKind, compliance_joints
from fgcal.estimation.model_noise import REUSED, REUSED_NOTE, fit_model
from fgcal.estimation.options import CalibrationOptions
from fgcal.estimation.time_validation import (
    FoldSums,
    drift_sentences,
    forward_errors,
    forward_sums,
    harmonic,
    later_poses,
    model_columns,
    recommend,
)
from fgcal.measurements.dataset import Dataset
from fgcal.robots.gravity import Payload, gravity_torques, model_inertials
from fgcal.robots.model import RobotModel

__all__ = [
    "HARMONICS_GRID",
    "REUSED",
    "REUSED_NOTE",
    "SIGMA_GRID",
    "CVProblem",
    "FoldOrder",
    "ModelScore",
    "ModelSelection",
    "compare_models",
    "cross_validate",
    "cv_problem",
]

log = logging.getLogger(__name__)

HARMONICS_GRID = (1, 2, 3, 4, 6, 8, 10, 12, 15, 18, 22, 26, 30)
MAX_GRID_GROWTH = 6  # steps the map prior's grid grows by while the optimum is on its edge
CORRELATION_LIMIT = 0.9
COMPLIANCE_RESOLUTION = 1.0  # urad/Nm: a compliance known no better than this is not identified (arms: ~5-20)
SIGMA_GRID = tuple(float(s) for s in np.geomspace(1e-6, 3e-4, 8))  # rad


@dataclass
class ModelScore:
    """One model's scores (errors in ``unit``; the mean over poses of the position error norm)."""

    model: str
    spec: dict
    n_parameters: int
    cv_error: float
    cv_standard_error: float
    heldout_error: float | None = None
    unit: str = "mm"
    condition_number: float | None = None
    correlations: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    cv_max: float | None = None  # the largest cross-validated error
    forward_error: float | None = None  # later poses predicted from earlier ones (fgcal.estimation.time_validation)
    forward_max: float | None = None


@dataclass
class ModelSelection:
    """The candidates' scores and the recommendation."""

    scores: list
    recommended: str
    folds: int
    reason: str = ""
    drift: list = field(default_factory=list)  # sentences: the data drift, and by how much

    def to_dict(self) -> dict:
        return {"scores": [asdict(s) for s in self.scores], "recommended": self.recommended, "folds": self.folds,
                "reason": self.reason, "drift": list(self.drift)}

    @classmethod
    def from_dict(cls, d: dict) -> ModelSelection:
        return cls([ModelScore(**s) for s in d["scores"]], d["recommended"], int(d["folds"]), d.get("reason", ""),
                   list(d.get("drift", [])))

    def score(self, model) -> ModelScore:
        return next(s for s in self.scores if s.model == ModelKind(model).value)


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
    out: dict[str, tuple[np.ndarray, dict]] = {ModelKind.GEOMETRIC.value: (sums.held_out_errors(geo, inf), {}),
           ModelKind.COMPLIANCE.value: (sums.held_out_errors(geo + comp, inf + comp_sigma), {})}
    best = None
    maps = {}
    for h in harmonics_grid:
        mp = [i for i, n in enumerate(prob.names) if n.startswith("map.") and harmonic(n) <= h]
        if mp:
            maps[int(h)] = mp
    sigmas = sorted(float(s) for s in sigma_grid)
    tried: set = set()
    for _ in range(MAX_GRID_GROWTH + 1):
        for h, mp in maps.items():
            for s in sigmas:
                if (h, s) in tried:
                    continue
                tried.add((h, s))
                e = sums.held_out_errors(geo + comp + mp, inf + comp_sigma + [s] * len(mp))
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


def _identifiability(result, torques, q_deg) -> tuple[dict, list]:
    """Strongest correlation of each added parameter, and warnings for weakly identified compliances."""
    names = result.names
    corr = result.correlation()
    out, warnings = {}, []
    for i, n in enumerate(names):
        if not (n.endswith(".compliance") or n.startswith("map.")):
            continue
        c = np.abs(corr[i].copy())
        c[i] = 0.0
        j = int(np.nanargmax(c))
        out[n] = {"partner": names[j], "correlation": float(corr[i, j])}
        if n.endswith(".compliance"):
            jn = int(n[1:].split(".")[0]) - 1
            p = result.parameters[i]
            span, tspan = float(np.ptp(q_deg[:, jn])), float(np.ptp(torques[:, jn]))
            if abs(c[j]) > CORRELATION_LIMIT or p.sigma > COMPLIANCE_RESOLUTION:
                warnings.append(f"{n}: joint {jn + 1} spans only {span:.1f} deg (gravity torque spread "
                                f"{tspan:.0f} N m) in these poses: too narrow to identify its compliance "
                                f"({p.estimate:.3g} +/- {p.sigma:.2g} urad/Nm, correlation {corr[i, j]:+.2f} "
                                f"with {names[j]})")
    return out, warnings


def compare_models(ds: Dataset, model: RobotModel, options: CalibrationOptions = CalibrationOptions(),
                   up_to: ModelKind = ModelKind.COMPLIANCE_MAP, verification: Dataset | None = None,
                   folds: int = 5, rng=None, payload: Payload = Payload(), harmonics_grid=HARMONICS_GRID,
                   sigma_grid=SIGMA_GRID, fold_order: FoldOrder = FoldOrder.RANDOM):
    """Calibrate the models up to ``up_to``, score them, and recommend one.

    Parameters
    ----------
    ds : Dataset
        Training poses (cross-validation never sees ``verification``).
    model : RobotModel
        Needs ``inertials`` for the compliance models.
    options : CalibrationOptions
        For every final calibration (its ``joint_errors`` is replaced per model).
    up_to : ModelKind
    verification : Dataset, optional
        Held-out poses: each model's mean position error there is reported.
    folds : int
    rng : numpy.random.Generator
        Draws the folds.
    fold_order : FoldOrder
        ``random`` (default) or ``blocked`` (contiguous stretches of the poses in id order).
    payload : Payload
        Load on the tool (kg, mm), for the gravity torques.

    Returns
    -------
    results : dict of str to CalibrationResult
        One per model; each result's ``joint_errors["selection"]`` holds the comparison.
    selection : ModelSelection
    """
    from fgcal.estimation.verification import verify

    up_to = ModelKind(up_to)
    at_edge: list = []
    rng = np.random.default_rng(0) if rng is None else rng
    if folds < 2 or folds > ds.n_poses:
        from fgcal.errors import FgcalError

        raise FgcalError(f"{ds.path or 'dataset'}: {folds} cross-validation folds for {ds.n_poses} poses "
                         "(need 2 <= folds <= poses)")
    base = replace(options, joint_errors=None)
    results = {ModelKind.GEOMETRIC.value: calibrate(ds, model, base)}
    geo = results[ModelKind.GEOMETRIC.value]
    specs: dict[str, JointErrorSpec | None] = {ModelKind.GEOMETRIC.value: None}
    q = model.joints_to_internal(ds.joints_deg[ds.row_of(np.array(geo.pose_ids))])
    torques = np.zeros_like(q)
    if up_to.order >= ModelKind.COMPLIANCE.order:
        inertials = model_inertials(model)
        if inertials is None:
            from fgcal.errors import ModelError

            raise ModelError(f"robot model {model.name}: the compliance models need its links' masses and centres "
                             "of mass (an 'inertials:' block in the model file)")
        torques = gravity_torques(geo.slot_vector(model), q, inertials, payload, model.chain)
        revolute = np.asarray(model.joint_is_angle, dtype=bool)
        joints = tuple(j for j in compliance_joints(torques) if revolute[j - 1])  # prismatic: no torsion
        if not joints:  # the compliance models would be the geometric one under another name
            from fgcal.errors import ModelError

            spread = float(np.ptp(torques, axis=0).max(initial=0.0)) if torques.size else 0.0
            raise ModelError(f"robot model {model.name}: no revolute joint's gravity torque varies by "
                             f"{COMPLIANCE_MIN_NM:g} N m over these poses (largest spread {spread:.3g} N m; are the "
                             "inertials' masses zero?), so there is no compliance to estimate: use --model geometric")
        map_joints = () if revolute.all() else tuple(int(j) + 1 for j in np.nonzero(revolute)[0])
        spec_max = JointErrorSpec(compliance=joints, payload=payload, map_joints=map_joints,
                                  harmonics=max(harmonics_grid) if up_to is ModelKind.COMPLIANCE_MAP else 0)
        prob = cv_problem(ds, model, geo, spec_max, options)
        cv = cross_validate(prob, folds, rng, harmonics_grid if spec_max.harmonics else (), sigma_grid, fold_order)
        log.info("cross-validation: %s", {k: round(float(v[0].mean()), 4) for k, v in cv.items()})
        specs[ModelKind.COMPLIANCE.value] = JointErrorSpec(compliance=joints, payload=payload)
        if ModelKind.COMPLIANCE_MAP.value in cv:
            kw = dict(cv[ModelKind.COMPLIANCE_MAP.value][1])
            at_edge = kw.pop("at_edge", [])
            specs[ModelKind.COMPLIANCE_MAP.value] = JointErrorSpec(compliance=joints, payload=payload,
                                                                   map_joints=map_joints, **kw)
        unit = prob.unit
    else:
        geo_names = list(geo.names)
        if not geo_names:
            raise FgcalError("model comparison: no geometric parameter is free to compare the models on")
        prob = cv_problem(ds, model, geo, JointErrorSpec(), options)
        cv = cross_validate(prob, folds, rng, (), sigma_grid, fold_order)
        unit = prob.unit
    errors = {k: v[0] for k, v in cv.items() if k in specs}
    # Later poses predicted from earlier ones: where the data drift, the models are compared on
    # those (the errors new poses will see), and a lower mean bought with a worse maximum is refused.
    later = later_poses(prob.pose_ids) if prob.pose_ids is not None else np.zeros(len(prob.r), dtype=bool)
    forward: dict[str, np.ndarray] = {}
    if 3 <= later.sum() <= len(later) - 3:
        sums = forward_sums(prob, later)  # one pass over the Jacobian for every model compared
        for k in errors:
            forward[k] = forward_errors(prob, *model_columns(prob, k, cv[k][1]), later, sums)
    drift = drift_sentences(forward, errors, later, unit) if forward else []
    del prob  # its Jacobian (poses x rows x all candidate parameters) is not needed by the fits
    # The added models: fitted as the cross-validation weighted them (the geometric fit's noise),
    # then each at its own noise with the map prior scaled alike (fgcal.estimation.model_noise).
    for kind, spec in specs.items():
        if spec is not None:
            results[kind] = fit_model(ds, model, options, spec, geo)
            log.info("calibrated %s (%d parameters)", kind, len(results[kind].parameters))
    for d in drift:
        log.warning("%s", d)
    if drift:
        recommended, reason = recommend({k: forward[k][later] for k in errors},
                                        "error at the later poses predicted from the earlier ones")
    else:
        recommended, reason = recommend(errors)
    scores = []
    for kind, res in results.items():
        e = errors[kind]
        spec = specs[kind]
        score = ModelScore(kind, spec.to_dict() if spec is not None else {}, len(res.parameters), float(e.mean()),
                           float(e.std(ddof=1) / np.sqrt(len(e))), unit=unit,
                           condition_number=float(res.condition_number), cv_max=float(e.max()))
        if kind in forward:
            score.forward_error = float(np.nanmean(forward[kind]))
            score.forward_max = float(np.nanmax(forward[kind]))
        if specs[kind] is not None:
            score.correlations, score.warnings = _identifiability(res, torques, np.degrees(q))
            if kind == ModelKind.COMPLIANCE_MAP.value:
                score.warnings += [f"cross-validation: {w}" for w in at_edge]
            for w in score.warnings:
                log.warning("%s", w)
        if verification is not None:
            score.heldout_error = float(verify(res, verification, model).after.position_mm.mean())
        scores.append(score)
    selection = ModelSelection(scores, recommended, folds, reason, drift)
    for res in results.values():
        res.joint_errors = {**res.joint_errors, "selection": selection.to_dict()}
    return results, selection
