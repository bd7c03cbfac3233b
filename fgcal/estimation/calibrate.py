"""Batch calibration (the paper's ID6, as one factor graph) with honest covariances.

:func:`calibrate` builds the graph of a dataset (:mod:`fgcal.estimation.graph`), finds the parameters the
data cannot identify (they are held at nominal and named), solves by Levenberg-Marquardt from
the nominal model (the base placement is first fitted to the measurements), and computes the
parameters' covariance as the inverse of the solve's Schur complement. No I/O here.

The pieces live beside it: the options (:mod:`fgcal.estimation.options`), the graph of a dataset
and its start (:mod:`fgcal.estimation.build`), the solver (:mod:`fgcal.estimation.solve`), noise
and outliers (:mod:`fgcal.estimation.noise`), held parameters (:mod:`fgcal.estimation.holding`).
"""
from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from fgcal._version import __version__
from fgcal.errors import FgcalError
from fgcal.estimation.admit import admit_rows
from fgcal.estimation.admit import check_equations as _check_equations
from fgcal.estimation.build import _levels, build_graph
from fgcal.estimation.gauge import GAUGE_REASON, TOOL_GAUGE_REASON, gauge_holds, setup_size
from fgcal.estimation.graph import Graph, Sigmas, State
from fgcal.estimation.group_noise import group_noise
from fgcal.estimation.holding import (
    STRUCTURAL_RTOL,
    _identifiability,
    _unidentifiable,
    held_parameters,
    holding_cost,
    priors_the_data_decide,
    typical_geometry,
)
from fgcal.estimation.noise import (
    NoiseMode,
    OutlierMode,
    components,
    fit_test,
    included_leverage,
    level_noise,
    name_outliers,
)
from fgcal.estimation.options import TYPICAL_DEVIATIONS, WEAK_PRIOR, CalibrationOptions
from fgcal.estimation.residuals import at_readings, pose_residuals, raw_at_readings
from fgcal.estimation.result import CalibrationResult, ParameterEstimate
from fgcal.estimation.result_summary import joint_error_info, level_summaries, setup_info
from fgcal.estimation.rounds import WARM_DAMPING, _solve_rounds
from fgcal.estimation.solve import levenberg_marquardt
from fgcal.measurements.dataset import Dataset
from fgcal.measurements.types import BY_LEVEL
from fgcal.robots.identifiability import analyse_information
from fgcal.robots.jacobian_rank import ScaledSpectrum
from fgcal.robots.model import RobotModel

__all__ = [
    "WEAK_PRIOR",
    "CalibrationOptions",
    "Solution",
    "build_graph",
    "calibrate",
    "identifiability_of",
    "levenberg_marquardt",
    "solution_covariance",
    "solve_calibration",
]

# The GTSAM forms of the problem live in fgcal.estimation.gtsam_graph (which imports gtsam); reached through
# this module too, loaded only when first asked for.
_GTSAM_NAMES = ("gtsam_covariance", "gtsam_levenberg_marquardt", "nonlinear_graph", "to_gtsam")


def __getattr__(name):
    if name in _GTSAM_NAMES:
        from fgcal.estimation import gtsam_graph

        return getattr(gtsam_graph, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

log = logging.getLogger(__name__)


def identifiability_of(ds: Dataset, model: RobotModel, options: CalibrationOptions = CalibrationOptions()):
    """What ``ds`` can identify, from the information of the graph :func:`calibrate` would solve.

    Every level the dataset has counts (probe points, centres, poses, with the joint readings'
    noise), linearised at the nominal model with the base fitted to the data.
    """
    every = model.parameters(extra=options.extra, exclude=options.exclude).names
    names = gauge_holds(ds, model, every, _levels(ds, options), tool=False)[0]  # the world frame's and scale's
    graph, state, _ = build_graph(ds, model, names, options)
    return _identifiability(graph, state)


def _covariance(graph: Graph, state: State, lin) -> np.ndarray:
    """The parameters' covariance, computed in one place: the inverse of the Schur complement the
    solve forms (:meth:`Graph.covariance`; ``gtsam.Marginals`` agrees, see the tests). A singular
    information ends in one line instead of a meaningless inverse."""
    spectrum = graph.parameter_spectrum(state, lin)  # shared with the identifiability at the solution
    if not spectrum.live.all():  # a parameter without information: scaled by its own (tiny) diagonal
        spectrum = ScaledSpectrum(graph.parameter_information(state, lin), floor=0.0)
    weak = spectrum.values <= 1e-12 * spectrum.values[-1]
    if weak.any() and graph.prior is not None:
        # A direction that only a finite prior determines is not singular (exact data beside a
        # prior of typical deviations): the prior's share of its information says so.
        vec = spectrum.vectors
        weak = spectrum.values <= 1e-12 * spectrum.values[-1]
        p = np.where(np.isfinite(graph.prior[1]), 1.0 / np.asarray(graph.prior[1]) ** 2, 0.0) * spectrum.scale**2
        weak &= np.einsum("pk,p,pk->k", vec, p, vec) < 0.5 * spectrum.values
    if weak.any():
        raise FgcalError(f"the {graph.n_poses} poses cannot determine the {len(state.theta)} parameters "
                         "(singular information): measure more poses")
    return graph.covariance(state, lin)


def _measured_points(ds: Dataset, levels) -> np.ndarray | str:
    if "poses" in levels:
        return "pose"
    with_balls = [getattr(ds, lv) for lv in levels if lv != "poses" and hasattr(getattr(ds, lv), "ball")]
    balls = sorted(set().union(*(set(obs.ball.tolist()) for obs in with_balls)))  # pixels have none
    return np.array([ds.tooling.balls[b] for b in balls]).reshape(-1, 3)


@dataclass
class Solution:
    """Where the solve of :func:`solve_calibration` ended: its graph (with the noise estimated and
    the outliers excluded) and state, what was held, and how it got there."""

    graph: Graph
    state: State
    pose_ids: np.ndarray
    levels: tuple
    iterations: int
    converged: bool
    rounds: int  # noise and outlier rounds
    declared: Sigmas  # the noise before estimation
    noise_mode: NoiseMode
    outlier_mode: OutlierMode
    held: list = field(default_factory=list)  # {"name", "value" (file units), "reason"} per held parameter
    theta_start: np.ndarray | None = None  # the start (nominal chain, base fitted) in internal units
    priors: dict = field(default_factory=dict)  # weakly identifiable parameters: their prior sigma (internal)
    refused: list = field(default_factory=list)  # rows refused before the solve (fgcal.estimation.admit)
    data_decided: dict = field(default_factory=dict)  # prior dropped at the solution: the data's sigma (internal)
    start_raw: dict | None = None  # the raw errors at theta_start with the joints at their readings, when formed


def split_held(model: RobotModel, names, redundant: dict, ds: Dataset, options: CalibrationOptions, priors=None,
               fits=None):
    """``(held, priors)``: of the ``redundant`` parameters (at the nominal geometry) those the same
    poses cannot separate at a geometry deviating from the nominal by typical amounts either
    (:func:`~fgcal.estimation.holding.typical_geometry`) stay held: they are redundant wherever the
    robot is (a tool angle for a single tool point, a ballbar's rotation about its pivot). The
    others get a prior of their typical deviation (:data:`~fgcal.estimation.options.TYPICAL_DEVIATIONS`,
    internal units) in ``priors`` (a copy of the given one). ``fits``: as for :func:`build_graph`."""
    priors = dict(priors or {})
    candidates = [n for n in redundant if n in set(model.slot_names)]
    if not candidates:
        return redundant, priors
    every = list(names) + [n for n in candidates if n not in names]
    graph, state, _ = build_graph(ds, model, every, replace(options, prior="none"), start=typical_geometry(model),
                                  fits=fits)
    still = held_parameters(graph, state, lambda g, st: _identifiability(g, st, rtol=STRUCTURAL_RTOL).redundant)
    for n in candidates:
        if n not in still:
            priors[n] = float(TYPICAL_DEVIATIONS.sigmas([n])[0])
            log.info("%s is weakly identifiable here (confounded with %s at the nominal geometry only): "
                     "estimated with a prior of its typical deviation", n, ", ".join(redundant[n]) or "nothing")
    return {n: p for n, p in redundant.items() if n in still or n not in set(model.slot_names)}, priors


def solve_calibration(ds: Dataset, model: RobotModel, options: CalibrationOptions = CalibrationOptions(),
                      start=None, decide_held: bool = True, priors=None, warm=None, fits=None) -> Solution:
    """The solve of :func:`calibrate` without the result's summaries.

    Parameters
    ----------
    start : ndarray, shape (S,), optional
        All slots (internal units) to start the solve from (a warm start: for example an online
        engine's estimate); default the nominal chain with the base fitted to the measurements.
        The optimum is the same; only the way there is shorter.
    decide_held : bool
        False: estimate every parameter of ``options`` (with ``prior="weak"`` the information is
        never singular) instead of holding those the data cannot identify.
    priors : dict, optional
        ``{name: sigma}`` (internal units): priors about the nominal on those parameters (the
        online engines pass those of :func:`split_held`).
    warm : CalibrationResult, optional
        A fit of a related model on the same data (the geometric one, or this model at other
        noise): the parameters it has start the solve at its estimates, the others at the usual
        start (a joint-error block at zero). Only the way to the optimum changes: the decisions
        (held parameters) and the per-pose nominal residuals are those of the usual start.
    fits : dict, optional
        Sphere fits kept between builds of the same dataset (see :func:`build_graph`): the caller's
        when it built the graph of ``ds`` before (an online engine's final smoothing), else a new one.
    """
    fits = {} if fits is None else fits
    noise_mode = NoiseMode(options.noise)
    outlier_mode = OutlierMode(options.outliers)
    params = model.parameters(extra=options.extra, exclude=options.exclude)
    names = list(params.names)
    if options.joint_errors is not None:
        names += options.joint_errors.names(model.n_joints)
    levels = _levels(ds, options)
    ds, refused = admit_rows(ds, model, levels)
    # the gauges: the base where nothing fixes the world frame, the tool where the cameras see it only
    # through an unknown pose on it, a link length where nothing fixes the scale (a decision of the held ones)
    names, held_info = gauge_holds(ds, model, names, levels, scale=decide_held)
    _check_equations(ds, levels, len(names) + setup_size(ds, levels))

    priors = dict(priors or {})
    new_priors: set = set()
    graph, state, pose_ids = build_graph(ds, model, names, options, start=start, priors=priors, fits=fits)
    redundant = held_parameters(graph, state, _unidentifiable) if decide_held else {}
    if redundant:
        # What these poses cannot separate at the nominal geometry: held where it is redundant at any
        # geometry, else estimated with a prior of its typical deviation (the data decide where
        # they can; holding it at a guess would leave its deviation in every prediction).
        given = set(priors)
        redundant, priors = split_held(model, names, redundant, ds, options, priors, fits)
        new_priors = set(priors) - given  # typical-deviation priors (not the caller's)
        for n, partners in redundant.items():
            reason = ("cannot be separated from " + ", ".join(partners)) if partners else "no data constrains it"
            held_info.append({"name": n, "value": float(model.slots_to_file_units(graph.held)[model.slot(n)]),
                              "reason": reason})
            log.warning("%s is not identifiable from these data (%s): held at %g", n, reason, held_info[-1]["value"])
        names = [n for n in names if n not in redundant]
        graph, state, pose_ids = build_graph(ds, model, names, options, start=start, priors=priors, fits=fits)

    theta_start = state.theta.copy()  # the nominal chain with the base fitted: the per-pose "nominal" error
    # its raw errors, from the solve's first linearisation where its state is at the readings (no ball variables)
    start_raw = graph.linearise(state).raw if warm is None and not len(graph.ball_pose) else None
    damping = 1e-4 if start is None else WARM_DAMPING
    if warm is not None:
        state.theta = _warm_theta(graph.params, state.theta, warm)
        damping = WARM_DAMPING
        graph.forget()  # the start's linearisation (held_parameters'): not kept beside the solve's
    if options.estimate_noise:
        noise_mode = NoiseMode.ESTIMATED
    if options.noise_scale:  # a fixed scale (a model comparison reuses the geometric fit's noise)
        noise_mode = NoiseMode.DECLARED
    state, iterations, converged, rounds, declared = _solve_rounds(graph, state, options, damping, noise_mode,
                                                                   outlier_mode)
    dropped = priors_the_data_decide(graph, state, {n: priors[n] for n in priors if n in new_priors}) \
        if decide_held else {}
    if dropped:
        # Identifiability at the solution: where the data determine a parameter better than its
        # typical-deviation prior, the prior goes (it pulled toward the nominal guess) and the
        # solve goes on from here without it.
        for n, s in dropped.items():
            log.info("%s: the data determine it at the solution (sigma %.3g) better than its typical-deviation "
                     "prior (%.3g): estimated without the prior", n, s, priors[n])
        priors = {n: s for n, s in priors.items() if n not in dropped}
        warm_slots = graph.params.full(state.theta, graph.held)
        graph, state, pose_ids = build_graph(ds, model, names, options, start=warm_slots, priors=priors, fits=fits)
        state, it2, converged, rounds2, declared = _solve_rounds(graph, state, options, WARM_DAMPING, noise_mode,
                                                                 outlier_mode)
        iterations, rounds = iterations + it2, rounds + rounds2
    return Solution(graph, state, pose_ids, tuple(levels), iterations, converged, rounds, declared, noise_mode,
                    outlier_mode, held_info, theta_start, priors, refused, dropped, start_raw)


def _warm_theta(params, theta, warm) -> np.ndarray:
    """``theta`` with the parameters ``warm`` (a result) estimated replaced by its estimates."""
    est = {p.name: p.estimate for p in warm.parameters}
    values = params.to_file_units(theta)
    for i, name in enumerate(params.names):
        if name in est:
            values[i] = est[name]
    return params.from_file_units(values)


def solution_covariance(sol: Solution) -> np.ndarray:
    """The parameters' covariance (P, P), internal units, at the solution's noise."""
    return _covariance(sol.graph, sol.state, sol.graph.linearise(sol.state))


def calibrate(ds: Dataset, model: RobotModel, options: CalibrationOptions = CalibrationOptions(),
              warm=None) -> CalibrationResult:
    """Identify the kinematic parameters of ``model`` from ``ds`` by one factor-graph solve.

    By default each level's noise is estimated from the residuals where the redundancy allows
    (:mod:`fgcal.estimation.noise`) and gross errors are excluded and named; the covariance is at the
    estimated noise.

    ``warm``: a result of a related model on the same data to start from (see :func:`solve_calibration`).

    Raises
    ------
    FgcalError
        If the data cannot determine the parameters (too few poses), naming how many are needed.
    """
    sol = solve_calibration(ds, model, options, warm=warm)
    graph, state, pose_ids, levels, declared = sol.graph, sol.state, sol.pose_ids, sol.levels, sol.declared
    noise_mode, held_info, theta_start = sol.noise_mode, sol.held, sol.theta_start
    iterations, converged, rounds = sol.iterations, sol.converged, sol.rounds
    # Everything below works from one linearisation at the solution.
    lin = graph.linearise(state)  # the solve's last one (remembered by the graph)
    cov = _covariance(graph, state, lin)
    final = graph.params
    identifiability = analyse_information(graph.parameter_information(state, lin), final.names,
                                          spectrum=graph.parameter_spectrum(state, lin))
    sv = identifiability.singular_values
    still = identifiability.redundant
    if still:
        log.warning("at the solution these parameters are not identifiable: %s", ", ".join(still))
    slots = final.full(state.theta, graph.held)
    slots_file = model.slots_to_file_units(slots)
    est = final.to_file_units(state.theta)
    nominal = final.to_file_units(final.nominal())
    cov_file = final.covariance_to_file_units(cov)
    cov_file = 0.5 * (cov_file + cov_file.T)  # symmetric but for rounding, which a near-gauge freedom magnifies
    sigma = np.sqrt(np.diag(cov_file))
    levels_summary = level_summaries(graph, state, lin)
    h = graph.row_leverage(state, graph.information_inverse(state, lin), lin)  # the last noise round's, kept
    noise_table = level_noise(components(graph, lin, h), graph.sigmas, declared, noise_mode)
    groups = group_noise(graph, lin, h, declared, noise_mode)  # each camera's, beside the component's
    ssq_declared = sum(n.variance_factor * n.redundancy for n in noise_table.values())
    red_total = sum(n.redundancy for n in noise_table.values())
    outliers = name_outliers(graph, lin, h, ds, pose_ids,
                             included_leverage(graph, state) if any(m.any() for m in graph.excluded.values()) else None)
    costly = [h_ for h_ in held_info if h_["reason"] not in (GAUGE_REASON, TOOL_GAUGE_REASON)]  # a choice of frame
    if costly:
        cost = holding_cost(model, slots, final.names[:graph.n_geo], [h_["name"] for h_ in costly], graph.readings,
                            _measured_points(ds, levels))
        for h_ in costly:
            h_["cost_mm"] = cost[h_["name"]]
    opts = asdict(options)
    opts["noise_scale"] = {lv: n.used / n.declared for lv, n in noise_table.items()
                           if n.declared > 0 and abs(n.used / n.declared - 1) > 1e-12}
    opts["noise"], opts["outliers"] = noise_mode.value, sol.outlier_mode.value
    if sol.priors:  # weakly identifiable: estimated with a prior of their typical deviation (file units)
        opts["typical_deviation_priors"] = {n: float(np.degrees(s) if model.slot_is_angle[model.slot(n)] else s)
                                       for n, s in sol.priors.items()}
    if sol.data_decided:  # weak at the nominal geometry, determined by the data at the solution (file units)
        opts["priors_dropped_at_solution"] = {n: float(np.degrees(s) if model.slot_is_angle[model.slot(n)] else s)
                                              for n, s in sol.data_decided.items()}
    raw = lin.raw
    residuals = {}
    if "probes" in raw:
        residuals["probes_mm"] = raw["probes"][0][:, 0].tolist()
    for level in graph.measurements:
        residuals.update(BY_LEVEL[level].residual_summary(raw[level][0]))
        if hasattr(BY_LEVEL[level], "residual_places"):  # a camera's: where on the image each residual is
            residuals.update(BY_LEVEL[level].residual_places(raw[level][0], graph.measurements[level], pose_ids,
                                                             graph.setup))
    if "joints" in raw:
        residuals["joints_deg"] = model.joints_to_file_units(raw["joints"][0]).ravel().tolist()
    tool_xyz = model.forward(slots, graph.joints(state))[:, :3, 3]
    read_raw = raw_at_readings(graph, state.theta) if graph.joint_vars else None  # once, for both summaries
    from fgcal.estimation.result_tooling import tooling_record
    from fgcal.robots.robot_file import model_to_dict

    return CalibrationResult(
        robot=model.name, n_poses=int(len(pose_ids)), robot_model=model_to_dict(model),
        parameters=[ParameterEstimate(n, u, float(a), float(b), float(s))
                    for n, u, a, b, s in zip(final.names, final.units, nominal, est, sigma)],
        covariance=cov_file, slots={n: float(v) for n, v in zip(model.slot_names, slots_file)}, held=held_info,
        levels=levels_summary, iterations=iterations, converged=converged, cost=float(lin.cost),
        singular_values=[float(v) for v in sv], condition_number=float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf"),
        pose_ids=[int(p) for p in pose_ids], options=opts, dataset=str(ds.path) if ds.path else None,
        fgcal_version=__version__, residuals=residuals, tool_xyz=tool_xyz.tolist(),
        noise_mode=noise_mode.value, noise=noise_table, noise_groups=groups, outliers=outliers,
        fit_test={"statistic": float(ssq_declared), "redundancy": float(red_total),
                  "p_value": fit_test(ssq_declared, red_total), "noise_rounds": rounds},
        at_readings=at_readings(graph, state, read_raw),
        pose_residuals=pose_residuals(graph, state, theta_start, pose_ids, read_raw, lin.raw, sol.start_raw),
        joint_errors=joint_error_info(final, options, model.joints_to_file_units(graph.readings)),
        setup=setup_info(graph, state, held_info, sol.refused), tooling=tooling_record(ds, levels))
