"""Batch calibration (the paper's ID6, as one factor graph) with honest covariances.

:func:`calibrate` builds the graph of a dataset (:mod:`fgcal.estimation.graph`), finds the parameters the
data cannot identify (they are held at nominal and named), solves by Levenberg-Marquardt from
the nominal model (the base placement is first fitted to the measurements), and computes the
parameters' covariance as the inverse of the solve's Schur complement. No I/O here.
"""
from __future__ import annotations

import logging
from dataclasses import asdict, dataclass

import numpy as np

from fgcal import __version__
from fgcal.measurements.dataset import LEVELS, Dataset
from fgcal.measurements.types import BY_LEVEL, kinematic_levels
from fgcal.errors import FgcalError
from fgcal.estimation.graph import Graph, Sigmas, State
from fgcal.estimation.holding import held_parameters, holding_cost
from fgcal.estimation.identifiability import analyse_information
from fgcal.robots.kinematics import tool_points
from fgcal.robots.model import EULER_FIELDS, RobotModel
from fgcal.estimation.noise import (NoiseMode, OutlierMode, components, find_outliers, fit_test, level_noise, name_outliers,
                    scaled_inverse, update_sigmas)
from fgcal.measurements.posefit import rigid_fit
from fgcal.estimation.result import CalibrationResult, LevelSummary, ParameterEstimate, ResidualSummary
from fgcal.measurements.spherefit import best_of_candidates, fit_spheres_batch, mirror_through_points, point_groups
from fgcal.studies.simulate import Deviations
from fgcal.robots.transforms import to_euler_zyx_trans
from fgcal.estimation.gravity import model_inertials
from fgcal.estimation.joint_errors import BlockParameters, JointErrorBlock, JointErrorSpec, is_block_name

__all__ = ["CalibrationOptions", "calibrate", "build_graph", "levenberg_marquardt", "WEAK_PRIOR",
           "identifiability_of"]

# The GTSAM forms of the problem live in fgcal.estimation.gtsam_graph (which imports gtsam); reached through
# this module too, loaded only when first asked for.
_GTSAM_NAMES = ("gtsam_covariance", "gtsam_levenberg_marquardt", "nonlinear_graph", "to_gtsam")


def __getattr__(name):
    if name in _GTSAM_NAMES:
        from fgcal.estimation import gtsam_graph

        return getattr(gtsam_graph, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

log = logging.getLogger(__name__)

# Weak prior: ten times the typical deviations of DESIGN.md (mm, deg).
WEAK_PRIOR = Deviations(length=5.0, angle=0.5, base_length=50.0, base_angle=5.0)
MIN_SIGMA = 1e-6  # exact data (sigma 0) still has floating-point noise
MAX_NOISE_ROUNDS = 40


@dataclass(frozen=True)
class CalibrationOptions:
    """How to calibrate.

    Attributes
    ----------
    levels : tuple of str or None
        Measurement levels to use (``probes``, ``centres``, ``poses``); all present by default.
    robust : {None, "huber", "cauchy"}
        Robust loss on the measurement factors; ``robust_k`` its threshold in sigmas.
    prior : {"none", "weak"}
        ``weak``: a prior of ten times the typical deviation on every parameter
        (:data:`WEAK_PRIOR`), which keeps an ill-posed solve finite.
    joint_noise : bool
        Model the joint readings' rounding and repeatability with joint variables.
    kinematic_sigma : float
        Unmodelled error (mm) between a ball-centre variable and the forward kinematics.
    noise : NoiseMode
        ``estimated`` (default): each level's noise (joint readings included) is estimated from the
        residuals where the redundancy allows, and the covariance is at that noise; ``declared``:
        dataset.yaml's values only.
    outliers : OutlierMode
        ``exclude`` (default): gross errors are found by data snooping, excluded and named.
    estimate_noise : bool
        Kept for old callers: True forces ``noise="estimated"``.
    engine : {"batch", "gtsam"}
        ``batch``: fgcal's Levenberg-Marquardt with one batched Schur complement per step;
        ``gtsam``: GTSAM's own Levenberg-Marquardt on :func:`to_gtsam` (slower: every custom
        factor is a Python callback). The covariance is computed the same way for both.
    extra, exclude : tuple of str
        Slots to add to, or remove from, the identifiable parameters.
    noise_scale : dict or None
        Fixed factors on each level's declared noise (``{"poses": 12.0}``), for example the
        ones a previous ``estimate_noise`` run found.
    joint_errors : JointErrorSpec or None
        A block of non-geometric joint errors (compliance, error map) estimated with the geometry
        (:mod:`fgcal.estimation.joint_errors`); ``None``: the geometric model.
    """

    levels: tuple | None = None
    robust: str | None = None
    robust_k: float | None = None
    prior: str = "none"
    joint_noise: bool = True
    kinematic_sigma: float = 1e-4
    noise: NoiseMode = NoiseMode.ESTIMATED
    outliers: OutlierMode = OutlierMode.EXCLUDE
    estimate_noise: bool = False
    extra: tuple = ()
    exclude: tuple = ()
    max_iterations: int = 100
    tolerance: float = 1e-12
    noise_scale: dict | None = None
    joint_errors: JointErrorSpec | None = None
    engine: str = "batch"


def _pose_dof(n_balls: int, full_pose: bool) -> int:
    return 6 if full_pose or n_balls >= 3 else {0: 0, 1: 3, 2: 5}[n_balls]


def _sigmas(ds: Dataset, model: RobotModel, options: CalibrationOptions, scale=None) -> Sigmas:
    scale = scale or {}
    n = ds.noise
    # A joint reading's sigma is in its file unit (deg, or mm for a prismatic joint).
    joint = model.joints_to_internal(np.full(model.n_joints, n.joint_sigma_deg)) if options.joint_noise else 0.0
    centre = n.centre_sigma if n.centre_sigma is not None else n.cmm_sigma
    pos = n.pose_position_sigma if n.pose_position_sigma is not None else n.cmm_sigma
    rot = np.radians(n.pose_orientation_sigma) if n.pose_orientation_sigma is not None else n.cmm_sigma / 100.0
    return Sigmas(probe=max(n.cmm_sigma, MIN_SIGMA) * scale.get("probes", 1.0),
                  centre=max(centre, MIN_SIGMA) * scale.get("centres", 1.0),
                  pose_position=max(pos, MIN_SIGMA) * scale.get("poses", 1.0),
                  pose_rotation=max(rot, MIN_SIGMA / 1000.0) * scale.get("poses", 1.0),
                  joint=joint, kinematic=options.kinematic_sigma,
                  distance=max(n.distance_sigma if n.distance_sigma is not None else n.cmm_sigma, MIN_SIGMA)
                  * scale.get("distances", 1.0))


def _levels(ds: Dataset, options: CalibrationOptions) -> list[str]:
    present = ds.levels()
    if options.levels is None:
        return present
    for lv in options.levels:
        if lv not in LEVELS:
            raise FgcalError(f"unknown level {lv!r} ({', '.join(LEVELS)})")
        if lv not in present:
            raise FgcalError(f"{ds.path or 'dataset'}: has no {lv} (it has: {', '.join(present) or 'none'})")
    return list(options.levels)


def _initial_base(model: RobotModel, held, q, world_points_by_pose):
    """Fit the base placement to measured points with the nominal chain (a rigid fit)."""
    x = held.copy()
    base = [model.slot(f"base.{f}") for f in EULER_FIELDS]
    x[base] = 0.0
    if not world_points_by_pose:
        return held
    poses = np.array(list(world_points_by_pose), dtype=int)
    T = model.forward(x, q[poses])  # one kinematics evaluation for all poses
    pred = np.vstack([tool_points(T[k:k + 1], offsets)[0]
                      for k, (offsets, _) in enumerate(world_points_by_pose.values())])
    meas = np.vstack([world for _, world in world_points_by_pose.values()])
    if len(pred) < 3 or np.linalg.matrix_rank(pred - pred.mean(0), tol=1e-6) < 2:
        return held
    fit = rigid_fit(pred, meas, sigma=1.0)
    try:
        values = to_euler_zyx_trans(fit.T)
    except ValueError:
        return held
    out = held.copy()
    out[base] = values
    return out


def _initial_pivot(model: RobotModel, held, q, offsets, length):
    """Slots with the base moved so that the world origin is the ballbar's pivot.

    ``|p_i - c|^2 = L_i^2`` with ``p_i`` the nominal ball positions is linear in ``(c, |c|^2)``;
    the base then becomes ``Trans(-c) A_b``. Its rotation stays nominal (distances cannot see it).
    """
    p = tool_points(model.forward(held, q), offsets[:, None, :] if offsets.ndim == 2 else offsets)[:, 0]
    A = np.column_stack([2 * p, -np.ones(len(p))])
    b = np.sum(p**2, axis=1) - np.asarray(length, dtype=float) ** 2
    if len(p) < 4 or np.linalg.matrix_rank(A) < 4:
        return held
    return model.with_world_origin_at(held, np.linalg.lstsq(A, b, rcond=None)[0][:3])


def build_graph(ds: Dataset, model: RobotModel, names, options: CalibrationOptions, held=None, scale=None):
    """The factor graph of ``ds`` over the parameters ``names``; returns ``(graph, state, pose_ids)``.

    Only poses with at least one measurement at the chosen levels take part.
    """
    levels = _levels(ds, options)
    block_names = [n for n in names if is_block_name(n)]  # joint-error block (fgcal.estimation.joint_errors)
    names = [n for n in names if not is_block_name(n)]
    params = model.parameters(extra=[n for n in names if n not in model.identifiable_names()])
    params = type(params)(model, tuple(names))
    held = model.nominal.copy() if held is None else np.asarray(held, dtype=float)
    measured = set()
    for lv in levels:
        measured |= set(getattr(ds, lv).pose.tolist())
    pose_ids = np.array([p for p in ds.pose_ids if p in measured], dtype=int)
    if not len(pose_ids):
        raise FgcalError(f"{ds.path or 'dataset'}: no pose has measurements at levels {', '.join(levels)}")
    row = {p: i for i, p in enumerate(pose_ids)}
    q = model.joints_to_internal(ds.joints_deg[ds.row_of(pose_ids)])
    sig = _sigmas(ds, model, options, scale if scale is not None else options.noise_scale)
    kw = {}
    world_points = {}
    init_c = None
    if "probes" in levels:
        pr = ds.probes
        keys = list(dict.fromkeys(zip(pr.pose.tolist(), pr.ball.tolist())))
        var = {k: j for j, k in enumerate(keys)}
        ball_pose = np.array([row[p] for p, _ in keys], dtype=int)
        ball_offset = np.array([ds.tooling.balls[b] for _, b in keys])
        # Start each centre from a sphere fit of its points (batched over balls with equal counts).
        init_c = np.full((len(keys), 3), np.nan)
        var_of_probe = np.array([var[(p, b)] for p, b in zip(pr.pose.tolist(), pr.ball.tolist())], dtype=int)
        for vs, pts in point_groups(var_of_probe, pr.xyz, minimum=4):
            init_c[vs] = fit_spheres_batch(pts, ds.tooling.radius)
        for j, (p, b) in enumerate(keys):
            if np.all(np.isfinite(init_c[j])):
                offs, pts_w = world_points.get(row[p], (np.zeros((0, 3)), np.zeros((0, 3))))
                world_points[row[p]] = (np.vstack([offs, ds.tooling.balls[b]]), np.vstack([pts_w, init_c[j]]))
        kw.update(probes=(np.array([row[p] for p in pr.pose], dtype=int),
                          np.array([var[(p, b)] for p, b in zip(pr.pose.tolist(), pr.ball.tolist())], dtype=int),
                          pr.xyz), ball_pose=ball_pose, ball_offset=ball_offset, radius=ds.tooling.radius)
    kw["measurements"] = {}
    for kind in kinematic_levels(levels):
        terms = kind.terms(getattr(ds, kind.level), ds.tooling, row)
        kw["measurements"][kind.level] = terms
        for i, (offs, pts_w) in kind.world_points(terms).items():
            if i in world_points and kind.level != "poses":  # a measured pose fixes the pose alone
                offs, pts_w = np.vstack([world_points[i][0], offs]), np.vstack([world_points[i][1], pts_w])
            world_points[i] = (offs, pts_w)
    pivot_start = None
    if "distances" in levels:
        terms = kw["measurements"]["distances"]
        pivot_start = _initial_pivot(model, held, q[terms.pose], *terms.data)
    if options.prior == "weak":
        kw["prior"] = (params.take(model.nominal), WEAK_PRIOR.sigmas(names))
    elif options.prior != "none":
        raise FgcalError(f"unknown prior {options.prior!r} (none, weak)")
    start = _initial_base(model, held, q, world_points) if pivot_start is None or world_points else pivot_start
    if block_names:  # --- joint-error block: appended to theta, zero-mean prior, G from the readings
        block = JointErrorBlock.build(options.joint_errors or JointErrorSpec(), model.n_joints,
                                      model_inertials(model), block_names, model.chain)
        mean, sd = kw.get("prior", (params.take(model.nominal), np.full(len(params), np.inf)))
        params = BlockParameters(params, block)
        kw["prior"] = (np.concatenate([mean, np.zeros(len(block))]), np.concatenate([sd, block.prior_sigma]))
        kw["joint_errors"] = block.design(q, start)
    graph = Graph(params, held, q, sig, robust=options.robust, robust_k=options.robust_k, **kw)
    theta0 = params.take(start)
    if init_c is not None and len(graph.ball_pose):
        # Refit each centre from the kinematic prediction: of the two centres that fit a cap of
        # points equally well, the one near the prediction is the ball's. Balls whose points do
        # not fit a sphere start at the prediction itself.
        T0 = model.forward(params.full(theta0, start), q)
        predicted = tool_points(T0[graph.ball_pose], graph.ball_offset[:, None, :])[:, 0]
        for vs, pts in point_groups(var_of_probe, pr.xyz, minimum=3):
            first = init_c[vs]
            ok = np.all(np.isfinite(first), axis=1)
            first_ok = np.where(ok[:, None], first, predicted[vs])
            candidates = [fit_spheres_batch(pts, ds.tooling.radius, guess=g)
                          for g in (first_ok, mirror_through_points(pts, first_ok), predicted[vs])]
            init_c[vs] = best_of_candidates(pts, ds.tooling.radius, candidates, ds.noise.cmm_sigma, predicted[vs])
        bad = ~np.all(np.isfinite(init_c), axis=1) | (np.linalg.norm(init_c - predicted, axis=1) > 50.0)
        init_c[bad] = predicted[bad]
    state = graph.initial_state(theta0, init_c)
    graph.held = params.full(theta0, start)  # held slots stay at the fitted start's values
    return graph, state, pose_ids


# Relative change of the cost below which two costs are the same up to rounding: the residuals
# are differences of coordinates of ~1e3 mm computed to ~1e-13 mm, whitened by sigmas of ~1e-2.
COST_ROUNDING = 1e-10


def levenberg_marquardt(graph: Graph, state: State, max_iterations=100, tolerance=1e-12, lin=None):
    """Minimise the graph's cost; returns ``(state, iterations, converged)``.

    ``lin``: the linearisation at ``state`` when the caller has it. The solve stops when a step
    (or the Gauss-Newton model's prediction of it) changes the cost by no more than
    ``tolerance`` relative, or by no more than rounding: such a step is not tried again damped.
    """
    lin = graph.linearise(state) if lin is None else lin
    cost = lin.cost
    damping = 1e-4
    for it in range(1, max_iterations + 1):
        for _ in range(30):
            try:
                new, d_theta, predicted = graph.step(state, lin, damping)
            except np.linalg.LinAlgError:
                damping *= 10
                continue
            if damping <= 1e-3 and 0 <= predicted <= tolerance * max(cost, 1e-300):
                return state, it, True  # at the minimum: what is left to gain is rounding
            lin.cache.clear()  # its normal equations are formed again if this step is rejected
            new_lin = graph.linearise(new)
            if np.isfinite(new_lin.cost) and new_lin.cost <= cost:
                break
            if np.isfinite(new_lin.cost) and new_lin.cost - cost <= COST_ROUNDING * cost and predicted <= COST_ROUNDING * cost:
                return state, it, True  # the change is rounding, not a worse point
            damping *= 10
        else:
            log.warning("Levenberg-Marquardt: no step reduces the cost (damping %.3g)", damping)
            return state, it, False
        gain = cost - new_lin.cost
        state, lin = new, new_lin
        damping = max(damping / 10, 1e-12)
        small_step = np.max(np.abs(d_theta)) < 1e-12 * (1 + np.max(np.abs(state.theta)))
        if gain <= tolerance * max(cost, 1e-300) or small_step or new_lin.cost < 1e-24:
            return state, it, True
        cost = new_lin.cost
    return state, max_iterations, False


def _solve(graph: Graph, state: State, options: CalibrationOptions, lin=None):
    if options.engine == "batch":
        return levenberg_marquardt(graph, state, options.max_iterations, options.tolerance, lin=lin)
    if options.engine == "gtsam":
        from fgcal.estimation.gtsam_graph import gtsam_levenberg_marquardt

        return gtsam_levenberg_marquardt(graph, state, options.max_iterations, options.tolerance)
    raise FgcalError(f"unknown engine {options.engine!r} (batch, gtsam)")


def _level_summaries(graph: Graph, state: State, cov_internal, lin=None) -> dict[str, LevelSummary]:
    lin = graph.linearise(state) if lin is None else lin
    red = graph.leverage_by_level(state, cov_internal, lin)
    out = {}
    units = {"probes": "mm", "kinematic": "mm", "joints": "deg", "prior": "-"}
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
            out[level] = LevelSummary(len(e), _rms(dist), "mm", sigma, vf, redundancy,
                                      None if angle is None else _rms(angle), sigma_angle)
            continue
        norms = np.linalg.norm(np.reshape(e, (len(e), -1)), axis=1)
        scale = np.degrees(1.0) if level == "joints" else 1.0
        sigma = {"probes": sig.probe, "kinematic": sig.kinematic,
                 "joints": _joint_sigma_file_units(graph), "prior": float("nan")}[level]
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


def _hold_order(names) -> list[int]:
    """Column order for blaming: the tool's angles last, so they are held first.

    Position-only data see a point on the tool, not its orientation: holding the tool's angles
    and keeping its translation keeps that point linear in the parameters wherever the solve goes
    (holding translations instead leaves a rotation that degenerates away from the start).
    """
    late = [i for i, n in enumerate(names) if n in ("tool.phi", "tool.theta", "tool.psi")]
    return [i for i in range(len(names)) if i not in late] + late


def _identifiability(graph: Graph, state: State, lin=None):
    names = list(graph.params.names)[:graph.n_geo]  # a joint-error block has its own prior: geometry only
    order = _hold_order(names)
    S = graph.parameter_information(state, lin)[np.ix_(order, order)]
    return analyse_information(S, [names[i] for i in order])


def _unidentifiable(graph: Graph, state: State, lin=None) -> dict[str, list[str]]:
    return _identifiability(graph, state, lin).redundant


def identifiability_of(ds: Dataset, model: RobotModel, options: CalibrationOptions = CalibrationOptions()):
    """What ``ds`` can identify, from the information of the graph :func:`calibrate` would solve.

    Every level the dataset has counts (probe points, centres, poses, with the joint readings'
    noise), linearised at the nominal model with the base fitted to the data.
    """
    graph, state, _ = build_graph(ds, model, model.parameters(extra=options.extra, exclude=options.exclude).names,
                                  options)
    return _identifiability(graph, state)


def _covariance(graph: Graph, state: State, lin) -> np.ndarray:
    """The parameters' covariance, computed in one place: the inverse of the Schur complement the
    solve forms (:meth:`Graph.covariance`; ``gtsam.Marginals`` agrees, see the tests). A singular
    information ends in one line instead of a meaningless inverse."""
    S = graph.parameter_information(state, lin)
    d = np.sqrt(np.maximum(np.diag(S), 1e-300))
    ev = np.linalg.eigvalsh(S / np.outer(d, d))
    if ev[0] <= 1e-12 * ev[-1]:
        raise FgcalError(f"the {graph.n_poses} poses cannot determine the {len(state.theta)} parameters "
                         "(singular information): measure more poses")
    return graph.covariance(state, lin)


def _at_readings(graph: Graph, state: State) -> dict[str, ResidualSummary]:
    """Residuals with the joints at their readings and centres on the kinematics (the training error)."""
    if not graph.joint_vars:
        return {}
    at = state.copy()
    at.q = graph.readings.copy()
    if len(graph.ball_pose):
        T = graph.params.model.forward(graph.params.full(state.theta, graph.held), at.q[graph.ball_pose])
        at.c = tool_points(T, graph.ball_offset[:, None, :])[:, 0]
    raw = graph.linearise(at).raw
    out = {}
    for level in ("probes", *BY_LEVEL):
        if level not in raw:
            continue
        e = raw[level][0][~graph.excluded.get(level, np.zeros(len(raw[level][0]), dtype=bool))]
        if level in BY_LEVEL:
            dist, angle = BY_LEVEL[level].metric(e)
            out[level] = ResidualSummary(len(e), _rms(dist), "mm", None if angle is None else _rms(angle))
        else:
            out[level] = ResidualSummary(len(e), _rms(np.linalg.norm(e.reshape(len(e), -1), axis=1)), "mm")
    return out


def _measured_points(ds: Dataset, levels) -> np.ndarray | str:
    if "poses" in levels:
        return "pose"
    balls = sorted(set().union(*(set(getattr(ds, lv).ball.tolist()) for lv in levels if lv != "poses")))
    return np.array([ds.tooling.balls[b] for b in balls]).reshape(-1, 3)


def calibrate(ds: Dataset, model: RobotModel, options: CalibrationOptions = CalibrationOptions()) -> CalibrationResult:
    """Identify the kinematic parameters of ``model`` from ``ds`` by one factor-graph solve.

    By default each level's noise is estimated from the residuals where the redundancy allows
    (:mod:`fgcal.estimation.noise`) and gross errors are excluded and named; the covariance is at the
    estimated noise.

    Raises
    ------
    FgcalError
        If the data cannot determine the parameters (too few poses), naming how many are needed.
    """
    noise_mode = NoiseMode(options.noise)
    outlier_mode = OutlierMode(options.outliers)
    params = model.parameters(extra=options.extra, exclude=options.exclude)
    names = list(params.names)
    if options.joint_errors is not None:
        names += options.joint_errors.names(model.n_joints)
    levels = _levels(ds, options)
    # Degrees of freedom per pose: full pose 6, two balls 5, one ball 3.
    dof = 0
    for p in ds.pose_ids:
        balls = set()
        full = False
        for lv in levels:
            obs = getattr(ds, lv)
            width = BY_LEVEL[lv].width if lv in BY_LEVEL else 3  # a probed ball places a point
            if width >= 6:
                full |= bool(np.any(obs.pose == p))
            elif width == 3:
                balls |= set(obs.ball[obs.pose == p].tolist())
            else:
                dof += width * int(np.sum(obs.pose == p))
        dof += _pose_dof(min(len(balls), 3), full)
    if dof < len(names):
        raise FgcalError(f"{ds.path or 'dataset'}: {ds.n_poses} poses give {dof} equations but the "
                         f"{len(names)} parameters need at least {len(names)} "
                         f"(at least {int(np.ceil(len(names) / 6))} full poses; more to average the noise)")

    graph, state, pose_ids = build_graph(ds, model, names, options)
    held_info = []
    redundant = held_parameters(graph, state, _unidentifiable)
    if redundant:
        for n, partners in redundant.items():
            reason = ("cannot be separated from " + ", ".join(partners)) if partners else "no data constrains it"
            held_info.append({"name": n, "value": float(model.slots_to_file_units(graph.held)[model.slot(n)]),
                              "reason": reason})
            log.warning("%s is not identifiable from these data (%s): held at %g", n, reason, held_info[-1]["value"])
        names = [n for n in names if n not in redundant]
        graph, state, pose_ids = build_graph(ds, model, names, options)
        lin = None

    state, iterations, converged = _solve(graph, state, options)
    declared = graph.sigmas
    if options.estimate_noise:
        noise_mode = NoiseMode.ESTIMATED
    if options.noise_scale:  # a fixed scale (a model comparison reuses the geometric fit's noise)
        noise_mode = NoiseMode.DECLARED
    # Noise estimation and outlier exclusion, alternated with re-solves until neither changes.
    rounds = 0
    for rounds in range(1, MAX_NOISE_ROUNDS + 1):
        lin = graph.linearise(state)
        h = graph.row_leverage(state, scaled_inverse(graph.parameter_information(state, lin)), lin)
        changed = False
        if outlier_mode is OutlierMode.EXCLUDE:
            for level, ks in find_outliers(graph, lin, h).items():
                mask = graph.excluded.setdefault(level, np.zeros(len(graph.row[level]), dtype=bool))
                mask[ks] = True
                changed = True
        if noise_mode is NoiseMode.ESTIMATED:
            graph.sigmas, moved = update_sigmas(graph.sigmas, components(graph, lin, h), declared)
            changed |= moved
        if not changed:
            break
        state, it2, converged = _solve(graph, state, options)
        iterations += it2
    else:
        log.warning("noise estimation did not settle in %d rounds", MAX_NOISE_ROUNDS)

    # Everything below works from one linearisation at the solution.
    lin = graph.linearise(state)  # the solve's last one (remembered by the graph)
    cov = _covariance(graph, state, lin)
    final = graph.params
    identifiability = analyse_information(graph.parameter_information(state, lin), final.names)
    sv = identifiability.singular_values
    still = identifiability.redundant
    if still:
        log.warning("at the solution these parameters are not identifiable: %s", ", ".join(still))
    slots = final.full(state.theta, graph.held)
    slots_file = model.slots_to_file_units(slots)
    est = final.to_file_units(state.theta)
    nominal = final.to_file_units(final.nominal())
    cov_file = final.covariance_to_file_units(cov)
    sigma = np.sqrt(np.diag(cov_file))
    levels_summary = _level_summaries(graph, state, cov, lin)
    h = graph.row_leverage(state, cov, lin)
    noise_table = level_noise(components(graph, lin, h), graph.sigmas, declared, noise_mode)
    ssq_declared = sum(n.variance_factor * n.redundancy for n in noise_table.values())
    red_total = sum(n.redundancy for n in noise_table.values())
    outliers = name_outliers(graph, lin, h, ds, pose_ids)
    if held_info:
        cost = holding_cost(model, slots, final.names, [h_["name"] for h_ in held_info], graph.readings,
                            _measured_points(ds, levels))
        for h_ in held_info:
            h_["cost_mm"] = cost[h_["name"]]
    opts = asdict(options)
    opts["noise_scale"] = {lv: n.used / n.declared for lv, n in noise_table.items()
                           if n.declared > 0 and abs(n.used / n.declared - 1) > 1e-12}
    opts["noise"], opts["outliers"] = noise_mode.value, outlier_mode.value
    raw = lin.raw
    residuals = {}
    if "probes" in raw:
        residuals["probes_mm"] = raw["probes"][0][:, 0].tolist()
    for level in graph.measurements:
        residuals.update(BY_LEVEL[level].residual_summary(raw[level][0]))
    if "joints" in raw:
        residuals["joints_deg"] = model.joints_to_file_units(raw["joints"][0]).ravel().tolist()
    tool_xyz = model.forward(slots, graph.joints(state))[:, :3, 3]
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
        noise_mode=noise_mode.value, noise=noise_table, outliers=outliers,
        fit_test={"statistic": float(ssq_declared), "redundancy": float(red_total),
                  "p_value": fit_test(ssq_declared, red_total), "noise_rounds": rounds},
        at_readings=_at_readings(graph, state),
        joint_errors=_joint_error_info(final, options, model.joints_to_file_units(graph.readings)))


def _joint_error_info(params, options: CalibrationOptions, qd) -> dict:
    """What a result keeps of its joint-error block: the spec, the names, the joint region (file units)."""
    if not isinstance(params, BlockParameters):
        return {}
    names = list(params.block.names)
    return {"spec": options.joint_errors.to_dict(), "names": names,
            "map_terms": sum(n.startswith("map.") for n in names),
            "joint_ranges_deg": [[float(lo), float(hi)] for lo, hi in zip(qd.min(axis=0), qd.max(axis=0))],
            "validity": "the joint error map holds only inside these joint ranges and in the set-up it was "
                        "fitted on (tool, payload, mounting)" if any(n.startswith("map.") for n in names) else ""}
