"""Which poses to record for a camera calibration (DESIGN.md 8.4): ``fgcal design --dataset`` with pixels.

The candidates are the dataset's images (each with the corners it saw) or joint sets given by
the user; a candidate given as joints sees the target where the calibrated model puts it, and is
usable only with the target in view: :data:`MIN_CORNERS` or more of its points in front of the
camera, on the image and seen at less than :data:`~fgcal.measurements.pixels.GRAZING_DEG` from a
planar target's normal. The dataset is calibrated once (its noise estimated, as the calibration
will have it); each candidate's information is that of its corners' pixels (their analytic
Jacobians in the robot's parameters, the cameras and the targets, at the calibrated geometry).

The criterion (``pred``, I-optimality over the workspace the candidates sample): the predicted
RMS position error (mm) of the target's points in the camera frame at every usable candidate,
``sqrt(tr(W C))`` with ``C`` the plan's covariance (a weak prior regularises a plan too small to
identify everything) and ``W`` the mean over the candidates' corners of ``G' G`` (``G``: a
corner's camera-frame position by the parameters). Its minimum over plans of ``n`` poses: a greedy
start, then exchanges (one pose out, one in) while they lower it. Varied distances and tilts are
what lowers it (the intrinsics and the mount separate only over them); it is compared with
random plans of the same size from the same candidates. No I/O here.
"""
from __future__ import annotations

import logging

import numpy as np

from fgcal.errors import FgcalError
from fgcal.measurements.dataset import Dataset
from fgcal.measurements.pixels import GRAZING_DEG, MIN_DEPTH_MM, PIXELS, PixelObservations, pixel_model
from fgcal.robots.model import RobotModel
from fgcal.studies.design_dataset_plan import DatasetDesign

__all__ = ["MIN_CORNERS", "design_cameras"]

log = logging.getLogger(__name__)

MIN_CORNERS = 4  # a candidate image needs this many of the target's points in view
WIDE_SETUP = (1000.0, 1.0)  # the regularising prior on a camera's or target's entries (mm or px, rad)


def _candidate_corners(ds: Dataset, model: RobotModel, sol, ids, q) -> tuple[PixelObservations, np.ndarray]:
    """The corners each candidate (index into ``ids``) would see, and which candidates are usable (K,)."""
    obs = ds.pixels
    if obs is None:
        raise FgcalError(f"{ds.path or 'dataset'}: design for cameras needs pixels.csv")
    specs = obs.specs
    pairs = list(dict.fromkeys(zip(obs.camera.tolist(), obs.target.tolist(), strict=True)))
    pose, cam, point = [], [], []
    for k in range(len(ids)):
        for c, t in pairs:
            for p in specs[t].points:
                pose.append(k)
                cam.append(c)
                point.append(p)
    every = PixelObservations.build(np.array(pose, dtype=int), cam, point, np.zeros((len(pose), 2)), specs)
    graph, theta = sol.graph, sol.state.theta
    terms = PIXELS.terms(every, None, {k: k for k in range(len(ids))}, graph.setup)
    uv, p_c = pixel_model(theta[:graph.n_geo], q[terms.pose], terms.data, graph.setup_values(theta), graph.index,
                          graph.held, graph.chain, need_jac=False)
    w = np.array([specs[c].width for c in every.camera.tolist()], dtype=float)
    h = np.array([specs[c].height for c in every.camera.tolist()], dtype=float)
    seen = (p_c[:, 2] > MIN_DEPTH_MM) & (uv[:, 0] > -0.5) & (uv[:, 1] > -0.5) & (uv[:, 0] < w - 0.5) \
        & (uv[:, 1] < h - 0.5)
    keep = np.zeros(len(every), dtype=bool)
    for k in range(len(ids)):
        rows = np.nonzero(terms.pose == k)[0]
        for c, t in pairs:
            mine = rows[(every.camera[rows] == c) & (every.target[rows] == t)]
            ok = mine[seen[mine]]
            if specs[t].planar and len(ok):  # the board's normal in the camera frame against the lines of sight
                normal = np.cross(p_c[mine[1]] - p_c[mine[0]], p_c[mine[-1]] - p_c[mine[0]])
                cos = np.abs(p_c[ok] @ normal) / (np.linalg.norm(p_c[ok], axis=1) * np.linalg.norm(normal) + 1e-300)
                ok = ok[cos > np.cos(np.radians(GRAZING_DEG))]
            if len(ok) >= MIN_CORNERS and len(ok) == len(mine):  # the whole target in view
                keep[ok] = True
    out = every.subset(keep)
    out.uv = uv[keep]
    usable = np.isin(np.arange(len(ids)), out.pose)
    return out, usable


def _information(sol, q, obs: PixelObservations, n_candidates: int):
    """Per candidate its information (K, P, P) over the solve's free parameters (robot, then set-up)
    at the calibrated geometry, and ``W`` (P, P): the mean over the corners of ``G' G``."""
    graph, theta = sol.graph, sol.state.theta
    layout = graph.setup
    n_geo, S = graph.n_geo, layout.n_free
    if graph.K:
        raise FgcalError("design for cameras takes no joint error model (--joint-errors)")
    terms = PIXELS.terms(obs, None, {k: k for k in range(n_candidates)}, layout)
    s = graph.setup_values(theta)
    _, J_t, _, J_s, cols = PIXELS.setup_error(theta[:n_geo], q[terms.pose], terms.data, s, graph.index, graph.held,
                                              graph.chain)
    where = layout.column()[cols]  # (M, 21) the free column of each block entry, -1 fixed
    m = len(obs)
    J = np.zeros((m, 2, n_geo + S))
    J[:, :, :n_geo] = J_t
    for j in range(cols.shape[1]):
        free = np.nonzero(where[:, j] >= 0)[0]
        J[free, :, n_geo + where[free, j]] += J_s[free, :, j]  # one column per row: no repeated index
    J /= np.asarray(PIXELS.sigma(graph.sigmas), dtype=float)[None, :, None]
    info = np.zeros((n_candidates, n_geo + S, n_geo + S))
    rows = J.reshape(m, 2, -1)
    np.add.at(info, terms.pose, np.einsum("mri,mrj->mij", rows, rows))
    # G: a corner's camera-frame position by the free parameters (central differences)
    x0 = np.concatenate([theta[:n_geo], theta[len(theta) - S:]])

    def points(x):
        return pixel_model(x[:n_geo], q[terms.pose], terms.data, layout.full(x[n_geo:]), graph.index, graph.held,
                           graph.chain, need_jac=False)[1]

    G = np.empty((m, 3, len(x0)))
    for i in range(len(x0)):
        step = np.zeros(len(x0))
        step[i] = 1e-6 * max(1.0, abs(x0[i]))
        G[:, :, i] = (points(x0 + step) - points(x0 - step)) / (2 * step[i])
    W = np.einsum("mri,mrj->ij", G, G) / m
    return info, W


def _prior(sol) -> np.ndarray:
    """The regularising prior's information (P,): the weak prior on the robot, wide on the set-up."""
    from fgcal.estimation.options import WEAK_PRIOR

    graph = sol.graph
    robot = WEAK_PRIOR.sigmas(list(graph.params.names)[:graph.n_geo])
    setup = np.where(graph.setup.is_angle(), WIDE_SETUP[1], WIDE_SETUP[0])
    return 1.0 / np.concatenate([robot, setup]) ** 2


def _pred(M, W) -> float:
    try:
        return float(np.sqrt(max(np.trace(np.linalg.solve(M, W)), 0.0)))
    except np.linalg.LinAlgError:
        return float("inf")


def _exchange(info, W, prior, usable, n: int, max_iterations: int):
    """A plan of ``n`` usable candidates minimising ``pred``: greedy, then exchanges. ``(chosen, pred, exchanges)``."""
    cand = np.nonzero(usable)[0]
    M = np.diag(prior)
    chosen: list[int] = []
    for _ in range(n):
        rest = [k for k in cand if k not in chosen]
        pick = int(min(rest, key=lambda k: _pred(M + info[k], W)))
        chosen.append(pick)
        M = M + info[pick]
    value, steps = _pred(M, W), 0
    while steps < max_iterations:
        best: tuple[float, int, int] | None = None
        for i in chosen:
            for j in cand:
                if j in chosen:
                    continue
                v = _pred(M - info[i] + info[j], W)
                if v < value * (1 - 1e-9) and (best is None or v < best[0]):
                    best = (v, i, int(j))
        if best is None:
            break
        value, out, into = best
        M = M - info[out] + info[into]
        chosen[chosen.index(out)] = into
        steps += 1
    return np.array(sorted(chosen), dtype=int), value, steps


def design_cameras(ds: Dataset, model: RobotModel, n_poses: int, candidates=None, random_sets: int = 200,
                   rng: np.random.Generator | None = None, progress=None, max_iterations: int = 200):
    """:func:`fgcal.studies.design_dataset.design_from_dataset` for a dataset with pixels: the plan
    of ``n_poses`` of the dataset's images (or of ``candidates``: (ids (K,), joints (K, n) deg))
    with the lowest ``pred`` (see the module's text), and ``pred`` of ``random_sets`` random plans."""
    from fgcal.estimation.calibrate import solve_calibration

    rng = rng if rng is not None else np.random.default_rng(0)
    if progress is not None:
        progress(f"calibrating {ds.path or 'the dataset'} ({ds.n_poses} images) for its geometry and noise")
    sol = solve_calibration(ds, model)
    if candidates is None:
        ids, q_deg = ds.pose_ids, ds.joints_deg
    else:
        ids, q_deg = (np.asarray(c) for c in candidates)
    q = model.joints_to_internal(q_deg)
    inside = model.in_limits(q)
    obs, usable = _candidate_corners(ds, model, sol, ids, q)
    usable &= inside
    where = "the candidates" if candidates is not None else f"{ds.path or 'the dataset'}"
    if usable.sum() < n_poses:
        raise FgcalError(f"{where}: {int(usable.sum())} candidate poses see the target for a plan of {n_poses}: "
                         "fewer candidates than poses")
    info, W = _information(sol, q, obs, len(ids))
    prior = _prior(sol)
    if progress is not None:
        progress(f"information of {len(ids)} candidates ready ({int(usable.sum())} see the target)")
    chosen, value, steps = _exchange(info, W, prior, usable, n_poses, max_iterations)
    pool = np.nonzero(usable)[0]
    rand = np.array([_pred(np.diag(prior) + info[rng.choice(pool, n_poses, replace=False)].sum(axis=0), W)
                     for _ in range(random_sets)])
    noise = {n: (float(v.declared), float(v.used), v.unit) for n, v in sol_noise(sol).items()}
    from fgcal.estimation.noise import NoiseMode

    return DatasetDesign(ids[chosen], q_deg[chosen], "pred", {"pred": value}, rand, ("pixels",), len(ids),
                         int(usable.sum()), steps, {}, noise, NoiseMode.ESTIMATED)


def sol_noise(sol) -> dict:
    """The pixels' noise the solve settled on: ``{component: LevelNoise-like (declared, used, unit)}``."""
    from types import SimpleNamespace

    sigma = float(np.max(PIXELS.sigma(sol.graph.sigmas)))
    declared = float(np.max(PIXELS.sigma(sol.declared)))
    return {"pixels": SimpleNamespace(declared=declared, used=sigma, unit="px")}
