"""The calibration problem in GTSAM's own terms: a ``gtsam.NonlinearFactorGraph`` of the
``factors`` package, GTSAM's Levenberg-Marquardt on it, and ``gtsam.Marginals`` as a cross-check
of the batched solve's covariance. Slower than :mod:`fgcal.estimation.calibrate`'s batched solve (every custom
factor is a Python callback), the same answer; the graph is for users to extend. No I/O here.
"""
from __future__ import annotations

import logging

import numpy as np

from fgcal.errors import FgcalError
from fgcal.estimation.build import _levels, build_graph
from fgcal.estimation.gauge import gauge_holds
from fgcal.estimation.graph import Graph, State
from fgcal.estimation.graph_types import COST_ROUNDING
from fgcal.estimation.holding import _unidentifiable
from fgcal.estimation.options import CalibrationOptions
from fgcal.measurements.dataset import Dataset
from fgcal.measurements.types import BY_LEVEL
from fgcal.robots.model import RobotModel

log = logging.getLogger(__name__)

__all__ = ["distance_constraint_factor", "gtsam_covariance", "gtsam_levenberg_marquardt", "nonlinear_graph", "to_gtsam"]


def gtsam_levenberg_marquardt(graph: Graph, state: State, max_iterations=100, tolerance=1e-12):
    """Levenberg-Marquardt on the GTSAM graph of :func:`nonlinear_graph`; ``(state, iterations, converged)``.

    The loop is driven from Python on a ``gtsam.Values`` it owns: each iteration linearises the
    graph once (``NonlinearFactorGraph.linearize``), solves the system damped by ``lambda * I``
    (GTSAM's own Levenberg-Marquardt damping: a unit prior per variable) with
    ``GaussianFactorGraph.optimize`` and moves by ``Values.retract``. Inside
    ``gtsam.LevenbergMarquardtOptimizer`` every ``CustomFactor`` callback costs time proportional
    to the whole ``Values`` (DESIGN.md section 5): there the cost grew with the square of the poses;
    here it is linear. Without a robust loss each pose's balls are one factor
    (:func:`factors.pose_balls_factor`) whose rows, for all poses at once, are filled before each
    linearisation (:class:`factors.PoseBallRows`): the callbacks only hand GTSAM their blocks. The
    damped systems share one COLAMD ordering (their structure is the same). Stops when an accepted
    step lowers the error by no more than ``tolerance`` relative (GTSAM's ``relativeErrorTol``),
    when a step changes it by rounding only
    (:data:`fgcal.estimation.graph_types.COST_ROUNDING`), when no damping up to 1e5 lowers it, or after
    ``max_iterations``.
    """
    import gtsam

    import factors.gtsam_factors as fx  # the module itself: no lazy look-up per name (40,000 at 1,000 poses)

    g, values, shared = _nonlinear_graph(graph, state)
    keys = list(values.keys())

    def at(v):  # the pose factors' rows at v, all poses at once, then v itself
        if shared is not None:  # (the values' q and c vectors in key order: q_0 ... q_{N-1}, c_0 ...)
            q = gtsam.utilities.extractVectors(v, "q") if graph.joint_vars else graph.readings
            shared.fill(v, v.atVector(fx.theta_key()), q, gtsam.utilities.extractVectors(v, "c"))
        return v

    dims = [values.atVector(k).shape[0] for k in keys]
    eye = {d: np.eye(d) for d in set(dims)}
    zero_of = {d: np.zeros(d) for d in eye}
    # Without a robust loss the error is the linearisation's at zero (0.5 |b|^2): each trial point
    # is linearised once, and an accepted one's linearisation is the next iteration's.
    exact = graph.robust is None
    zero = values.zeroVectors()
    lin = g.linearize(at(values))
    error = lin.error(zero) if exact else g.error(values)
    lam, iterations, converged = 1e-5, 0, False  # GTSAM's lambdaInitial
    ordering = None
    while iterations < max_iterations and not converged:
        iterations += 1
        while True:
            assert lin is not None  # None only once converged
            damped = gtsam.GaussianFactorGraph()
            damped.push_back(lin)  # lin's factors themselves (elimination only reads them): no copy
            model = {d: gtsam.noiseModel.Isotropic.Sigma(d, 1.0 / np.sqrt(lam)) for d in eye}
            for k, d in zip(keys, dims, strict=True):
                damped.add(k, eye[d], zero_of[d], model[d])
            if ordering is None:  # every damped system has the same structure: its COLAMD ordering once
                ordering = gtsam.Ordering.ColamdGaussianFactorGraph(damped)
            new = at(values.retract(damped.optimize(ordering)))
            new_lin = g.linearize(new) if exact else None
            new_error = new_lin.error(zero) if new_lin is not None else g.error(new)
            log.debug("LM %d: lambda %.1e error %.12g -> %.12g", iterations, lam, error, new_error)
            if np.isfinite(new_error) and new_error <= error:
                converged = error - new_error <= tolerance * max(error, 1e-300)
                values, error, lam = new, new_error, max(lam / 10, 1e-12)
                lin = new_lin if exact else (None if converged else g.linearize(at(values)))
                break
            if np.isfinite(new_error) and new_error - error <= COST_ROUNDING * error:
                converged = True  # the change is rounding: at the minimum (as the batch solve decides)
                break
            lam *= 10
            if lam > 1e5:  # GTSAM's lambdaUpperBound
                converged = True
                break
    out = state.copy()
    out.theta = np.asarray(values.atVector(fx.theta_key()), dtype=float)
    if graph.joint_vars:
        out.q = gtsam.utilities.extractVectors(values, "q").reshape(state.q.shape)
    if len(graph.ball_pose):
        out.c = gtsam.utilities.extractVectors(values, "c").reshape(state.c.shape)
    return out, iterations, converged


def to_gtsam(ds: Dataset, model: RobotModel, options: CalibrationOptions = CalibrationOptions()):
    """The whole calibration problem as a ``gtsam.NonlinearFactorGraph`` and its initial ``gtsam.Values``.

    Keys (see the ``factors`` package): ``factors.theta_key()`` the parameter vector (in the
    order of the returned names, internal units mm/rad), ``factors.joint_key(i)`` pose i's joint
    variables, ``factors.centre_key(j)`` ball-centre variable j. Add your own factors and optimise
    with any GTSAM optimiser.

    Returns
    -------
    graph : gtsam.NonlinearFactorGraph
    values : gtsam.Values
    names : list of str
        The parameters of ``theta_key()``; parameters the data cannot identify are left out (held),
        and so is the base when nothing fixes the world frame (contacts at unknown fixtures), and the
        longest link length when nothing fixes the scale either (no known distance). The
        free set-up entries (``fixture.NAME.x``, ``plane.NAME.tilt_u``, ...) close the vector.
    pose_ids : ndarray of int
        The dataset pose id of each joint key index.
    """
    every = model.parameters(extra=options.extra, exclude=options.exclude).names
    names = gauge_holds(ds, model, every, _levels(ds, options), tool=False)[0]  # the gauges, as calibrate holds them
    graph, state, pose_ids = build_graph(ds, model, names, options)
    redundant = _unidentifiable(graph, state)
    if redundant:
        graph, state, pose_ids = build_graph(ds, model, [n for n in names if n not in redundant], options)
    g, values = nonlinear_graph(graph, state)
    return g, values, list(graph.params.names), pose_ids


def gtsam_covariance(graph: Graph, state: State, lin=None) -> np.ndarray:
    """Covariance of theta from ``gtsam.Marginals`` on the graph linearised at ``state``.

    A cross-check of :meth:`Graph.covariance` (the inverse of the solve's Schur complement),
    which :func:`calibrate` uses. The whitened rows become ``gtsam.JacobianFactor``s: per ball, its probe and kinematic rows
    over (theta, q_i, c_ib); per pose, its centre, pose and joint rows over (theta, q_i).
    """
    import gtsam

    import factors.gtsam_factors as fx  # the module itself: no lazy look-up per name (40,000 at 1,000 poses)

    lin = graph.linearise(state) if lin is None else lin
    J_theta = np.zeros((graph.n_poses, graph.m, len(state.theta)))
    J_theta[:, :graph.m_theta] = lin.J_theta
    gfg = gtsam.GaussianFactorGraph()
    t_key = fx.theta_key()
    qdim = graph.n_joints if graph.joint_vars else 0
    unit = {}

    def add(keys_blocks, b):
        if len(b) not in unit:
            unit[len(b)] = gtsam.noiseModel.Unit.Create(len(b))
        args = []
        for k, B in keys_blocks:
            args += [k, np.ascontiguousarray(B)]
        gfg.add(gtsam.JacobianFactor(*args, np.ascontiguousarray(b), unit[len(b)]))

    for i in range(graph.n_poses):
        q_block = lambda rows, i=i: [(fx.joint_key(i), lin.J_local[i, rows, :qdim])] if qdim else []  # noqa: E731
        for j, rows in graph.ball_rows[i]:
            col = graph.ball_col[j]
            add([(t_key, J_theta[i, rows])] + q_block(rows) + [(fx.centre_key(j), lin.J_local[i, rows, col:col + 3])],
                -lin.r[i, rows])
        rows = graph.pose_rows[i]
        if len(rows):
            add([(t_key, J_theta[i, rows])] + q_block(rows), -lin.r[i, rows])
    if len(lin.prior_r):
        add([(t_key, lin.prior_J)], -lin.prior_r)
    sol = gtsam.VectorValues()
    sol.insert(t_key, np.zeros(len(state.theta)))
    for i in range(graph.n_poses if qdim else 0):
        sol.insert(fx.joint_key(i), np.zeros(qdim))
    for j in range(len(graph.ball_pose)):
        sol.insert(fx.centre_key(j), np.zeros(3))
    return gtsam.Marginals(gfg, sol).marginalCovariance(t_key)


def nonlinear_graph(graph: Graph, state: State):
    """The same problem as a ``gtsam.NonlinearFactorGraph`` of the ``factors`` package, with values.

    GTSAM's own optimisers and ``gtsam.Marginals`` work on it directly; it is slower than the
    batched solve (each custom factor is called from C++ with a copy of all values) but is the
    reference the batched solve is tested against.
    """
    g, values, _ = _nonlinear_graph(graph, state, share=False)
    return g, values


def _nonlinear_graph(graph: Graph, state: State, share: bool = True):
    """:func:`nonlinear_graph` and the :class:`factors.PoseBallRows` its pose factors read (None:
    ``share`` False, or no such factors); the optimiser that owns the values fills it."""
    import gtsam

    import factors.gtsam_factors as fx  # the module itself: no lazy look-up per name (40,000 at 1,000 poses)

    if graph.K:
        raise FgcalError("the GTSAM reference graph covers the geometric model only (no joint-error block)")
    g = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    t_key = fx.theta_key()
    values.insert(t_key, np.asarray(state.theta, dtype=float))
    sig = graph.sigmas
    robust = graph.robust
    k = graph.robust_k

    def kept(level, n):  # the factors the outlier handling has not excluded (the batch weighs those 0)
        return ~graph.excluded.get(level, np.zeros(n, dtype=bool))

    def qargs(i):
        return ({"q_key": fx.joint_key(i)} if graph.joint_vars else {"q_fixed": graph.readings[i]}) | {"chain": graph.chain}

    if graph.joint_vars:
        for i, keep in enumerate(kept("joints", graph.n_poses)):
            values.insert(fx.joint_key(i), np.asarray(state.q[i], dtype=float))
            if keep:
                g.add(fx.joint_prior(fx.joint_key(i), graph.readings[i], sig.joint))
    for j in range(len(graph.ball_pose)):
        values.insert(fx.centre_key(j), np.asarray(state.c[j], dtype=float))
    shared = None
    if robust is None:  # grouped: one factor per pose's balls, its probe and centre rows (same rows, fewer callbacks)
        if share and len(graph.ball_pose):
            import factors.pose_balls as pb

            shared = pb.PoseBallRows(fx.PoseKinematics(graph.index, graph.held, graph.pose_offsets, graph.chain),
                                     graph.radius if graph.probes is not None else 0.0)
        _pose_ball_factors(g, graph, kept, qargs, t_key, shared)
    else:  # a robust loss is per row: one factor each
        for j, keep in enumerate(kept("kinematic", len(graph.ball_pose))):
            if keep:
                g.add(fx.ball_centre_factor(graph.index, graph.held, graph.ball_offset[j], sig.kinematic, t_key=t_key,
                                            c_key=fx.centre_key(j), **qargs(graph.ball_pose[j])))
    if graph.probes is not None and robust is not None:
        for j, xyz, keep in zip(graph.probes[1], graph.probes[2], kept("probes", len(graph.probes[1]))):
            if keep:
                g.add(fx.probe_factor(fx.centre_key(int(j)), xyz, graph.radius, sig.probe, robust, k))
    # The set-up blocks (fixtures, planes) are the last entries of theta, as in the batch graph: a
    # contact's factor is on (theta, q_i) like any kinematic measurement's, so eliminating the
    # poses stays one small block each and theta's marginal is the batch covariance directly.
    setup = {} if graph.setup is None else {"setup": graph.setup, "setup_column": graph.n_geo + graph.K}
    for level, terms in graph.measurements.items():
        kind = BY_LEVEL[level]
        sigma = kind.sigma(sig)
        extra = setup if getattr(kind, "uses_setup", False) else {}
        for i, keep, *row in zip(terms.pose.tolist(), kept(level, len(terms)), *terms.data):
            if not keep:
                continue
            f = kind.factor(row, graph.index, graph.held, sigma, t_key=t_key, **qargs(i), **extra)
            g.add(f.cloneWithNewNoiseModel(fx.noise_model(sigma, robust, k)) if robust else f)
    if graph.prior is not None:
        g.add(fx.parameter_prior(t_key, graph.prior[0], graph.prior[1]))
    if graph.setup is not None:
        for i in range(len(graph.setup.spec.distances)):
            g.add(distance_constraint_factor(graph.setup, i, graph.n_geo + graph.K, t_key))
    return g, values, shared


def _pose_ball_factors(g, graph: Graph, kept, qargs, t_key: int, shared=None) -> None:
    """Each pose's balls in one factor (:func:`factors.pose_balls_factor`): its kept probe rows and
    the kept centre rows of its balls (excluded rows are left out); ``shared``, a
    :class:`factors.PoseBallRows`, lays out the same rows to fill for all poses at once."""
    import factors.gtsam_factors as fx  # the modules themselves: no lazy look-up per name (40,000 at 1,000 poses)
    import factors.pose_balls as pb

    sig, n_poses = graph.sigmas, graph.n_poses
    keep_c = kept("kinematic", len(graph.ball_pose))
    var, xyz = (graph.probes[1], graph.probes[2]) if graph.probes is not None else (np.zeros(0, int), np.zeros((0, 3)))
    keep_p = np.flatnonzero(kept("probes", len(var)))
    used = keep_c.copy()  # the balls with a row: their kept centre rows or a kept probe point
    used[var[keep_p]] = True
    balls = np.flatnonzero(used)
    balls = balls[np.argsort(graph.ball_pose[balls], kind="stable")]  # by pose, then by variable
    probes = keep_p[np.argsort(graph.ball_pose[var[keep_p]], kind="stable")]  # by pose, in the file's order
    ball_cut = np.searchsorted(graph.ball_pose[balls], np.arange(n_poses + 1))
    probe_cut = np.searchsorted(graph.ball_pose[var[probes]], np.arange(n_poses + 1))
    radius = graph.radius if graph.probes is not None else 0.0
    for i in range(n_poses):
        js = balls[ball_cut[i]:ball_cut[i + 1]]
        if not len(js):
            continue
        rows = probes[probe_cut[i]:probe_cut[i + 1]]
        g.add(pb.pose_balls_factor(graph.index, graph.held, [fx.centre_key(int(j)) for j in js], graph.ball_offset[js],
                                   xyz[rows], np.searchsorted(js, var[rows]), radius, sig.probe, sig.kinematic,
                                   t_key=t_key, kinematic=keep_c[js], **qargs(i),
                                   shared=None if shared is None else (shared, i, graph.ball_slot[js], js)))


def distance_constraint_factor(setup, i: int, setup_column: int, t_key: int):
    """The ``i``-th known distance between two fixture points of the layout ``setup`` as a factor
    on the parameter vector ``t_key`` (whose free set-up entries start at ``setup_column``):
    error ``|p_a - p_b| - distance`` (mm), sigma the constraint's."""
    import gtsam

    import factors.gtsam_factors as fx  # the module itself: no lazy look-up per name (40,000 at 1,000 poses)

    free = np.nonzero(setup.free)[0]
    sigma = setup.spec.distances[i].sigma

    def error(this, values, H):
        theta = values.atVector(t_key)
        e, J, _ = setup.distance_errors(setup.full(theta[setup_column:]))
        if H is not None:
            row = np.zeros((1, len(theta)))
            row[0, setup_column:setup_column + len(free)] = J[i, free]
            H[0] = row
        return e[i:i + 1]

    return gtsam.CustomFactor(fx.noise_model([sigma]), [t_key], error)
