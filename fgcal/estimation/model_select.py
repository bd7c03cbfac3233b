"""Choosing a model beyond geometry by cross-validation on the training poses.

For each candidate model (:class:`~fgcal.estimation.joint_errors.ModelKind`) the training poses are split
into K folds (repeated configurations kept in one fold); each fold is predicted by the model fitted
to the others. The fits are linear least squares on the problem linearised at the geometric
solution, with the readings taken as exact, so that a whole grid of error maps (number of
harmonics x prior strength) costs one linearisation. The map's size and prior are chosen by the
cross-validated error; the recommended model is the simplest whose cross-validated error is within
noise (two standard errors of the per-pose difference) of the best, among those whose largest
error is no worse than a simpler model's, on the later poses predicted from the earlier ones where
the data drift (:mod:`fgcal.estimation.time_validation`; the folds in
:mod:`fgcal.estimation.cross_validation`). The chosen models are then
calibrated with the full factor graph (:func:`fgcal.estimation.calibrate.calibrate`). No I/O here.
"""
from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from fgcal.errors import FgcalError, ModelError
from fgcal.estimation.calibrate import calibrate
from fgcal.estimation.cross_validation import (
    HARMONICS_GRID,
    SIGMA_GRID,
    CVProblem,
    FoldOrder,
    _folds,  # noqa: F401 (re-exported: tests import it from here)
    _groups,  # noqa: F401
    cross_validate,
    cv_problem,
)
from fgcal.estimation.joint_errors import COMPLIANCE_MIN_NM, JointErrorSpec, ModelKind, compliance_joints
from fgcal.estimation.model_noise import REUSED, REUSED_NOTE, fit_model
from fgcal.estimation.options import CalibrationOptions
from fgcal.estimation.time_validation import (
    drift_sentences,
    forward_errors_many,
    forward_sums,
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

CORRELATION_LIMIT = 0.9
COMPLIANCE_RESOLUTION = 1.0  # urad/Nm: a compliance known no better than this is not identified (arms: ~5-20)


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
            raise ModelError(f"robot model {model.name}: the compliance models need its links' masses and centres "
                             "of mass (an 'inertials:' block in the model file)")
        torques = gravity_torques(geo.slot_vector(model), q, inertials, payload, model.chain)
        revolute = np.asarray(model.joint_is_angle, dtype=bool)
        joints = tuple(j for j in compliance_joints(torques) if revolute[j - 1])  # prismatic: no torsion
        if not joints:  # the compliance models would be the geometric one under another name
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
    sums = None
    if 3 <= later.sum() <= len(later) - 3:
        sums = forward_sums(prob, later)  # one pass over the Jacobian for every model compared
        predicted = forward_errors_many(prob, [model_columns(prob, k, cv[k][1]) for k in errors], later, sums)
        forward = dict(zip(errors, predicted))
    drift = drift_sentences(forward, errors, later, unit) if forward else []
    # Its Jacobian (poses x rows x all candidate parameters: 158 MB on 8,400 poses) is not needed by the
    # fits; the fold sums hold the problem too.
    del prob, sums
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
