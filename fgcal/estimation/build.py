"""The factor graph of a dataset: its noise, its measurement levels, the starting point (the base
fitted to the measurements, a ballbar's pivot, sphere fits chosen against the kinematic
prediction) and the :class:`fgcal.estimation.graph.Graph` itself. No I/O here.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from fgcal.errors import FgcalError
from fgcal.estimation.graph import Graph, Sigmas
from fgcal.estimation.joint_errors import BlockParameters, JointErrorBlock, JointErrorSpec, is_block_name
from fgcal.estimation.options import MIN_SIGMA, WEAK_PRIOR, CalibrationOptions
from fgcal.estimation.setup_params import SetupParameters, is_setup_name
from fgcal.measurements.dataset import Dataset
from fgcal.measurements.posefit import rigid_fit
from fgcal.measurements.setup import SetupLayout
from fgcal.measurements.spherefit import best_of_candidates, fit_spheres_batch, mirror_through_points, point_groups
from fgcal.measurements.types import all_levels, kinematic_levels, kinematic_types
from fgcal.robots.gravity import model_inertials
from fgcal.robots.kinematics import tool_points
from fgcal.robots.model import EULER_FIELDS, RobotModel
from fgcal.robots.transforms import to_euler_zyx_trans

__all__ = ["MIRRORS", "PLAIN_FITS", "build_graph"]

# Keys of ``fits`` (:func:`build_graph`) for fits the caller made of single balls before, each
# sphere's fit being independent of the others fitted with it: ``{(radius, points' bytes): centre}``
# of :func:`fit_spheres_batch` and ``{(points' bytes, centre's bytes): mirror}`` of
# :func:`mirror_through_points` (an online engine's sphere fits, taken by its final smoothing).
PLAIN_FITS = "plain fits"
MIRRORS = "mirrors"


def _sigmas(ds: Dataset, model: RobotModel, options: CalibrationOptions, scale=None) -> Sigmas:
    """The declared noise of ``ds``, times ``scale``'s factor per noise component.

    ``scale`` is keyed by noise component (:func:`fgcal.estimation.noise.component_table`, as
    ``calibrate`` writes ``options["noise_scale"]``): ``"poses"`` scales a pose's position,
    ``"poses_rotation"`` its rotation, ``"joints"`` every joint reading's; a component not named
    keeps its declared sigma.
    """
    scale = scale or {}
    n = ds.noise
    # A joint reading's sigma is in its file unit (deg, or mm for a prismatic joint).
    joint = (model.joints_to_internal(np.full(model.n_joints, n.joint_sigma_deg)) * scale.get("joints", 1.0)
             if options.joint_noise else 0.0)
    centre = n.centre_sigma if n.centre_sigma is not None else n.cmm_sigma
    pos = n.pose_position_sigma if n.pose_position_sigma is not None else n.cmm_sigma
    rot = np.radians(n.pose_orientation_sigma) if n.pose_orientation_sigma is not None else n.cmm_sigma / 100.0
    other = {name: max(value, MIN_SIGMA) * scale.get(kind.level, 1.0)
             for kind in kinematic_types() for name, value in kind.declared_sigmas(n).items()}
    return Sigmas(other=tuple(sorted(other.items())), probe=max(n.cmm_sigma, MIN_SIGMA) * scale.get("probes", 1.0),
                  centre=max(centre, MIN_SIGMA) * scale.get("centres", 1.0),
                  pose_position=max(pos, MIN_SIGMA) * scale.get("poses", 1.0),
                  pose_rotation=max(rot, MIN_SIGMA / 1000.0) * scale.get("poses_rotation", 1.0),
                  joint=joint, kinematic=options.kinematic_sigma,
                  distance=max(n.distance_sigma if n.distance_sigma is not None else n.cmm_sigma, MIN_SIGMA)
                  * scale.get("distances", 1.0))


def _levels(ds: Dataset, options: CalibrationOptions) -> list[str]:
    present = ds.levels()
    if options.levels is None:
        return present
    for lv in options.levels:
        if lv not in all_levels():
            raise FgcalError(f"unknown level {lv!r} ({', '.join(all_levels())})")
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
    counts = [len(offsets) for offsets, _ in world_points_by_pose.values()]
    at = np.repeat(np.arange(len(poses)), counts)  # each point's pose (row of T)
    offsets = np.vstack([o for o, _ in world_points_by_pose.values()]).reshape(-1, 3)
    pred = tool_points(T[at], offsets[:, None, :])[:, 0]
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


def _rows_of(pose_ids, pose) -> np.ndarray:
    """The row in ``pose_ids`` (N,) of each id of ``pose`` (M,); every one must be there."""
    order = np.argsort(pose_ids, kind="stable")
    return order[np.searchsorted(pose_ids[order], pose)].astype(int)


def _points_by_pose(ball_pose, ball_offset, centre) -> dict:
    """``{pose row: (offsets (k, 3), centres (k, 3))}`` of the balls with a finite centre, poses in
    the order of their first such ball, balls in variable order (the rigid fit's order)."""
    ok = np.flatnonzero(np.all(np.isfinite(centre), axis=1))
    if not len(ok):
        return {}
    rows = ball_pose[ok]
    _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
    order = ok[np.argsort(first[inverse.ravel()], kind="stable")]
    pose, offsets, centres = ball_pose[order].tolist(), ball_offset[order], centre[order]
    cuts = np.flatnonzero(np.diff(ball_pose[order])) + 1
    return {pose[a]: (offsets[a:z], centres[a:z])
            for a, z in zip([0, *cuts.tolist()], [*cuts.tolist(), len(order)])}


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


def _setup_layout(ds: Dataset, model: RobotModel, kinds, start, q, row) -> SetupLayout:
    """The set-up blocks the measurements use, each unknown one started by its measurement type
    from the robot's start (:meth:`fgcal.measurements.contact.SetupMeasurement.block_starts`: a
    fixture point at the mean of its predicted ball centres, a plane fitted to them, a station by
    a rigid fit of what it measured)."""
    used, starts = {}, {}
    T = model.forward(start, q)
    for kind in kinds:
        obs = getattr(ds, kind.level)
        i = np.array([row[p] for p in obs.pose.tolist()], dtype=int)
        blocks = kind.all_blocks(obs) if hasattr(kind, "all_blocks") else kind.blocks_of(obs).tolist()
        used.update(dict.fromkeys(blocks))  # a camera's corners use its camera and their target
        unknown = {n for n in used if n in ds.setup.fixtures and ds.setup.fixtures[n].value is None}
        starts.update(kind.block_starts(obs, T[i], ds.tooling, unknown, ds.path or "dataset"))
    return SetupLayout.build(ds.setup.subset(used), starts)


def _kept(fits: dict | None, fn, *args, **kw):
    """``fn(*args, **kw)`` (arrays and numbers), kept in ``fits`` under the bytes, shapes and values
    of its arguments: a second build of the same dataset asks the same fit again and gets the
    same array (not to be changed by the caller); without ``fits``, computed."""
    if fits is None:
        return fn(*args, **kw)
    key = (fn.__name__, *(_key(a) for a in args), *((k, _key(v)) for k, v in sorted(kw.items())))
    hit = fits.get(key)
    if hit is None:
        hit = fits[key] = fn(*args, **kw)
    return hit


def _known(fits: dict | None, table: str, fn, points, other):
    """``fn(points, other)`` (K spheres): the rows of ``fits[table]`` where every sphere's is there,
    keyed as :data:`PLAIN_FITS` (``other`` the radius) or :data:`MIRRORS` (``other`` the centres,
    (K, 3)) say, fitted before one sphere at a time (the same values); else ``_kept``'s."""
    known = fits.get(table) if fits else None
    if known:
        keys = [(other, p.tobytes()) for p in points] if table == PLAIN_FITS else \
            [(p.tobytes(), c.tobytes()) for p, c in zip(points, other)]
        rows = [known.get(k) for k in keys]
        if all(r is not None for r in rows):
            return np.array(rows, dtype=float).reshape(len(rows), 3)
    return _kept(fits, fn, points, other)


def _rows_key(obs) -> tuple:
    """A key of every array an observation table holds (poses, names, measured values)."""
    return tuple(_key(v) for v in vars(obs).values() if isinstance(v, np.ndarray))


def _key(value):
    if isinstance(value, np.ndarray):
        return value.shape, value.dtype.str, value.tobytes()
    return value


def build_graph(ds: Dataset, model: RobotModel, names, options: CalibrationOptions, held=None, scale=None,
                start=None, priors=None, fits: dict | None = None):
    """The factor graph of ``ds`` over the parameters ``names``; returns ``(graph, state, pose_ids)``.

    Only poses with at least one measurement at the chosen levels take part. The state starts at
    ``start`` (all slots (S,), internal units) when given, else at ``held`` (default the nominal
    chain) with the base fitted to the measurements. ``priors`` ({name: sigma}, internal units):
    priors about the nominal on those parameters (the tighter one where ``options.prior`` has one).
    ``fits``: a dict the caller keeps between builds of the same dataset (:func:`_kept`): the
    sphere fits that do not depend on the start are computed once (the same values).
    """
    levels = _levels(ds, options)
    block_names = [n for n in names if is_block_name(n)]  # joint-error block (fgcal.estimation.joint_errors)
    names = [n for n in names if not is_block_name(n) and not is_setup_name(n)]
    params: Any = model.parameters(extra=[n for n in names if n not in model.identifiable_names()])
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
    kw: dict[str, Any] = {}
    world_points: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    init_c = None
    pr = ds.probes
    if "probes" in levels and pr is not None:
        probe_row = _rows_of(pose_ids, pr.pose)
        ball_names, ball_of_probe = np.unique(pr.ball, return_inverse=True)
        # The ball variables: one per (pose, ball), numbered in the order of first appearance.
        key, first, inverse = np.unique(probe_row * len(ball_names) + ball_of_probe.ravel(),
                                        return_index=True, return_inverse=True)
        by_first = np.argsort(first, kind="stable")
        rank = np.empty_like(by_first)
        rank[by_first] = np.arange(len(by_first))
        var_of_probe = rank[inverse.ravel()]
        ball_pose = (key // len(ball_names))[by_first].astype(int)
        ball_offset = np.array([ds.tooling.balls[b] for b in ball_names])[(key % len(ball_names))[by_first]]
        ball_offset = ball_offset.reshape(-1, 3).astype(float)
        # Start each centre from a sphere fit of its points (batched over balls with equal counts).
        init_c = np.full((len(key), 3), np.nan)
        for vs, pts in point_groups(var_of_probe, pr.xyz, minimum=4):
            init_c[vs] = _known(fits, PLAIN_FITS, fit_spheres_batch, pts, ds.tooling.radius)
        world_points = _points_by_pose(ball_pose, ball_offset, init_c)
        kw.update(probes=(probe_row, var_of_probe, pr.xyz), ball_pose=ball_pose, ball_offset=ball_offset,
                  radius=ds.tooling.radius)
    kw["measurements"] = {}
    setup_kinds = [k for k in kinematic_levels(levels) if getattr(k, "uses_setup", False)]
    for kind in kinematic_levels(levels):
        if kind in setup_kinds:
            continue  # their terms need the set-up layout, which starts from the robot's start
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
    if priors:
        mean, sd = kw.get("prior", (params.take(model.nominal), np.full(len(params), np.inf)))
        given = np.array([priors.get(n, np.inf) for n in names])
        kw["prior"] = (mean, np.minimum(sd, given))
    warm = start is not None
    if warm:
        start = np.asarray(start, dtype=float)
        if start.shape != held.shape or not np.all(np.isfinite(start)):
            raise FgcalError(f"the start must be {held.shape[0]} finite slots, got shape {start.shape}")
    elif pivot_start is None or world_points:
        start = _initial_base(model, held, q, world_points)
    else:
        start = pivot_start
    layout = None
    if setup_kinds:
        # the same start and poses (the rebuild once the held parameters are out): the same blocks and terms
        layout_key = ("setup_layout", _key(start), _key(q), *((k.level, _rows_key(getattr(ds, k.level))) for k in setup_kinds))
        kept = None if fits is None else fits.get(layout_key)
        if kept is None:
            layout = _setup_layout(ds, model, setup_kinds, start, q, row)
            kept = (layout, {k.level: k.terms(getattr(ds, k.level), ds.tooling, row, layout) for k in setup_kinds})
            if fits is not None:
                fits[layout_key] = kept
        layout = kept[0]
        kw["measurements"].update(kept[1])
        # the measurements in registry order (the graph's row layout does not depend on this dict)
    if block_names:  # --- joint-error block: appended to theta, zero-mean prior, G from the readings
        block = JointErrorBlock.build(options.joint_errors or JointErrorSpec(), model.n_joints,
                                      model_inertials(model), block_names, model.chain)
        mean, sd = kw.get("prior", (params.take(model.nominal), np.full(len(params), np.inf)))
        params = BlockParameters(params, block)
        kw["prior"] = (np.concatenate([mean, np.zeros(len(block))]), np.concatenate([sd, block.prior_sigma]))
        kw["joint_errors"] = (block.design_columns(q, start), block.joints)
    if layout is not None:  # --- set-up unknowns close theta, with their priors (inf: none)
        mean, sd = kw.get("prior", (params.take(model.nominal), np.full(len(params), np.inf)))
        s_mean, s_sd = layout.prior()
        params = SetupParameters(params, layout)
        kw["prior"] = (np.concatenate([mean, s_mean]), np.concatenate([sd, s_sd]))
        kw["setup"] = layout
    graph = Graph(params, held, q, sig, robust=options.robust, robust_k=options.robust_k, **kw)
    theta0 = params.take(start)
    if init_c is not None and pr is not None and len(graph.ball_pose):
        # Refit each centre from the kinematic prediction: of the two centres that fit a cap of
        # points equally well, the one near the prediction is the ball's. Balls whose points do
        # not fit a sphere start at the prediction itself. A given start is near the optimum: its
        # prediction decides alone (the noise may be many times the declared one, and a centre
        # started at a mirror image stays in another minimum).
        T0 = model.forward(params.full(theta0, start), q)
        predicted = tool_points(T0[graph.ball_pose], graph.ball_offset[:, None, :])[:, 0]
        for vs, pts in point_groups(var_of_probe, pr.xyz, minimum=3):
            first = init_c[vs]
            ok = np.all(np.isfinite(first), axis=1)
            first_ok = np.where(ok[:, None], first, predicted[vs])
            # from the plain fits and their mirror images (the same at any start where every plain fit
            # succeeded: kept in ``fits``), and from the prediction
            mirrors = _known(fits, MIRRORS, mirror_through_points, pts, first_ok)
            candidates = [_kept(fits, fit_spheres_batch, pts, ds.tooling.radius, guess=first_ok),
                          _kept(fits, fit_spheres_batch, pts, ds.tooling.radius, guess=mirrors),
                          fit_spheres_batch(pts, ds.tooling.radius, guess=predicted[vs])]
            init_c[vs] = best_of_candidates(pts, ds.tooling.radius, candidates,
                                            np.inf if warm else ds.noise.cmm_sigma, predicted[vs])
        bad = ~np.all(np.isfinite(init_c), axis=1) | (np.linalg.norm(init_c - predicted, axis=1) > 50.0)
        init_c[bad] = predicted[bad]
    state = graph.initial_state(theta0, init_c)
    graph.held = params.full(theta0, start)  # held slots stay at the fitted start's values
    return graph, state, pose_ids
