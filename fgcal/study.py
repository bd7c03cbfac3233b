"""Simulation studies (the paper's section 3 and Figs. 8, 9, 13): trial definitions and one trial.

A study is a list of :class:`Trial` specifications; :func:`run_trial` simulates a robot, measures
it as the paper did, calibrates it and verifies the result at other poses of the same robot.
Trials are independent and seeded, so they run anywhere (local processes, a Dask cluster) and a
study can resume by skipping the trials it already has. No I/O here.
"""
from __future__ import annotations

import time
import zlib
from dataclasses import asdict, dataclass
from functools import lru_cache

import numpy as np

from .errors import FgcalError

__all__ = ["Trial", "STUDIES", "trials_for", "run_trial", "RESULT_COLUMNS", "EXPERIMENT_REPEATABILITY_DEG"]

# Joint landing error (deg) for the "experiment" study: with it, identification from 21 of the
# paper's planned poses verifies at ~0.3 mm RMS against the measurements, as the paper found.
EXPERIMENT_REPEATABILITY_DEG = 0.0125


@dataclass(frozen=True)
class Trial:
    """One simulated calibration.

    ``plan`` is ``random`` (``n_poses`` random reachable poses, verified at ``n_verify`` others)
    or ``experiment`` (the paper's 48 planned poses, 42 kept, split 21/21; identification from
    ``n_poses`` of the first 21, verification on the other 21).
    """

    study: str
    trial: int
    seed: int
    n_poses: int
    plan: str = "random"
    cmm_sigma: float = 0.01
    joint_resolution: float = 0.01
    repeatability: float = 0.0
    n_verify: int = 50
    robot: str = "puma560"
    design: str = ""
    q_plan: tuple = ()  # a fixed identification plan (rad), for designed experiments
    predicted: float = float("nan")
    index_values: tuple = ()  # (O1, ..., O5) of the plan


RESULT_COLUMNS = ["study", "trial", "seed", "robot", "plan", "design", "n_poses", "cmm_sigma", "joint_resolution",
                  "repeatability", "position_rms_mm", "position_max_mm", "orientation_rms_deg", "orientation_max_deg",
                  "measured_position_rms_mm", "measured_orientation_rms_deg", "predicted_position_rms_mm",
                  "O1", "O2", "O3", "O4", "O5", "seconds"]


def _fig8_9(trials=5, seed=0, **_):
    sizes = [6, 8, 10, 12, 15, 18, 21, 25, 30]
    return [Trial("fig8-9", k, seed, n) for k, (n, _t) in enumerate((n, t) for n in sizes for t in range(trials))]


def _fig13(trials=100, poses=12, seed=0, **_):
    return [Trial("fig13", k, seed, poses) for k in range(trials)]


def _experiment(trials=10, seed=0, **_):
    out = []
    for k, (n, _t) in enumerate((n, t) for n in (7, 14, 21) for t in range(trials)):
        out.append(Trial("experiment", k, seed, n, plan="experiment", repeatability=EXPERIMENT_REPEATABILITY_DEG))
    return out


def _sweep(name, field, values):
    def make(trials=5, poses=21, seed=0, **_):
        return [Trial(name, k, seed, poses, **{field: v}) for k, (v, _t) in
                enumerate((v, t) for v in values for t in range(trials))]
    return make


def _design(trials=8, poses=12, seed=0, candidates=2000, random_sets=40, **_):
    """Designed plans (one per index, planned once on the nominal robot) against random sets,
    each calibrated on ``trials`` truth draws: the answer to the paper's open question."""
    from .dataset import Noise
    from .design import INDICES, Candidates, candidate_pool, design_plan
    from .robot_file import load_model
    from .simulate import random_plan

    model = load_model("puma560")
    rng = np.random.default_rng([seed, 9])
    pool = candidate_pool(model, candidates, rng)
    # The accuracy to predict is at poses drawn as the trials draw their verification poses.
    q_verify = random_plan(model, model.nominal, 1000, rng, model.tooling, model.volume)
    noise = Noise(0.01, 0.01)
    prepared = Candidates.build(model, pool, noise, q_verify)

    def values_of(sel):
        v = prepared.values(sel)
        return v["pred"], tuple(v[k] for k in ("O1", "O2", "O3", "O4", "O5"))

    out, k = [], 0
    for index in INDICES:
        d = design_plan(model, poses, pool, noise, index=index, prepared=prepared)
        pred, vals = values_of(d.chosen)
        for t in range(trials):
            out.append(Trial("design", k, seed + 1000 * t, poses, design=index, q_plan=tuple(map(tuple, d.q)),
                             predicted=pred, index_values=vals))
            k += 1
    ok = np.nonzero(prepared.usable)[0]
    for t in range(random_sets):
        sel = rng.choice(ok, size=poses, replace=False)
        pred, vals = values_of(sel)
        out.append(Trial("design", k, seed + 1000 * (t % trials), poses, design="random",
                         q_plan=tuple(map(tuple, pool[sel])), predicted=pred, index_values=vals))
        k += 1
    return out


STUDIES = {
    "fig8-9": _fig8_9,
    "fig13": _fig13,
    "experiment": _experiment,
    "sweep-cmm": _sweep("sweep-cmm", "cmm_sigma", [0.001, 0.003, 0.01, 0.03, 0.1]),
    "sweep-joint": _sweep("sweep-joint", "joint_resolution", [0.0, 0.001, 0.01, 0.03, 0.1]),
    "sweep-repeatability": _sweep("sweep-repeatability", "repeatability", [0.0, 0.001, 0.003, 0.01, 0.03]),
    "design": _design,
}


def trials_for(study: str, **kw) -> list[Trial]:
    """The trials of a named study; ``trials``, ``poses`` and ``seed`` override the defaults."""
    if study not in STUDIES:
        raise FgcalError(f"unknown study {study!r} ({', '.join(STUDIES)})")
    kw = {k: v for k, v in kw.items() if v is not None}
    return STUDIES[study](**kw)


@lru_cache(maxsize=4)
def _model(robot: str):
    """The robot model, read once per process (trials do not change it)."""
    from .robot_file import load_model

    return load_model(robot)


def prepare_process(robots) -> None:
    """Import what a trial uses and read the ``robots``' models, so that forked workers inherit them."""
    from . import calibrate, kinematics, simulate, spherefit, verify  # noqa: F401

    for robot in robots:
        _model(robot)


@lru_cache(maxsize=4)
def _paper_plan(robot: str):
    from .simulate import paper_plan

    model = _model(robot)
    q, _, _ = paper_plan(model, np.random.default_rng(1993), model.tooling, model.volume)
    return q


_UP = np.array([0.0, 0.0, 1.0])  # the CMM's probe comes down from +z (as in fgcal.simulate)


def _cross(a, b):
    """Row-wise cross products of ``(..., 3)`` arrays, in :func:`fgcal.simulate._cap_directions`'s order."""
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1], a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


@dataclass
class ProbedPoses:
    """Simulated CMM probing of a set of poses, every pose with the same number of balls and points.

    Attributes
    ----------
    pose_ids : ndarray of int, shape (K,)
        The poses kept (those with enough reachable balls on the actual robot), 1-based.
    joints_deg : ndarray, shape (K, n)
        Controller readings in file units (deg; mm for prismatic joints).
    ball_names : ndarray of str, shape (K, B)
        The probed balls of each pose, in the tool's order.
    points : ndarray, shape (K, B, P, 3)
        Probe points in the world (mm).
    """

    pose_ids: np.ndarray
    joints_deg: np.ndarray
    ball_names: np.ndarray
    points: np.ndarray

    def dataset(self, model, noise):
        """The probes as a :class:`~fgcal.dataset.Dataset` (rows by pose, ball, point, as ``measure`` writes)."""
        from .dataset import Dataset, PointObservations

        K, B, P, _ = self.points.shape
        probes = PointObservations(np.repeat(self.pose_ids, B * P), np.repeat(self.ball_names.reshape(-1), P),
                                   self.points.reshape(-1, 3))
        return Dataset(robot=model.name, tooling=model.tooling, noise=noise, provenance={}, pose_ids=self.pose_ids,
                       joints_deg=self.joints_deg, probes=probes)

    def measured_poses(self, tooling, sigma: float):
        """Tool poses measured as :func:`fgcal.verify.measured_poses` measures probe data.

        Sphere fits of known radius with the residual check (as :func:`fgcal.spherefit.fit_spheres_checked`),
        then a least-squares rigid fit of each pose's three or more good balls with its chi-square
        check, all vectorised. Returns the rows (into ``pose_ids``) of the accepted poses, ``(K',)``,
        and their poses ``(K', 4, 4)``.
        """
        from .posefit import rigid_fit
        from .spherefit import fit_sphere, fit_spheres_arrays

        K, B, P, _ = self.points.shape
        if K == 0:
            return np.zeros(0, dtype=int), np.zeros((0, 4, 4))
        pts = self.points.reshape(K * B, P, 3)
        centre, _, _, cov, good = fit_spheres_arrays(pts, tooling.radius, sigma)
        var = np.trace(cov, axis1=1, axis2=2) / 3
        for i in np.nonzero(~good)[0]:  # fit_spheres_checked's path: the full diagnosis decides
            fit = fit_sphere(pts[i], radius=tooling.radius, sigma=sigma)
            good[i], centre[i], var[i] = fit.ok, fit.centre, np.trace(fit.covariance) / 3
        good, centre, var = good.reshape(K, B), centre.reshape(K, B, 3), var.reshape(K, B)
        names, which = np.unique(self.ball_names, return_inverse=True)
        tool = tooling.offsets(names)[which.reshape(K, B)]
        T = np.full((K, 4, 4), np.nan)
        ok = np.zeros(K, dtype=bool)
        whole = good.all(axis=1)
        if B >= 3 and whole.any():
            ok[whole], T[whole] = rigid_fits(tool[whole], centre[whole], np.sqrt(var[whole].mean(axis=1)))
        for k in np.nonzero(~whole & (good.sum(axis=1) >= 3))[0]:  # a ball failed its check: the other balls
            g = good[k]
            fit = rigid_fit(tool[k, g], centre[k, g], sigma=float(np.sqrt(var[k, g].mean())))
            ok[k], T[k] = fit.ok, fit.T
        rows = np.nonzero(ok)[0]
        return rows, T[rows]


def rigid_fits(tool, world, sigma):
    """:func:`fgcal.posefit.rigid_fit` (Kabsch, with its collinearity and chi-square checks) for many poses.

    Parameters
    ----------
    tool, world : ndarray, shape (K, n, 3)
        Ball centres in the tool frame and as measured in the world (mm), n >= 3.
    sigma : ndarray, shape (K,)
        Per-coordinate noise of each pose's centres (mm).

    Returns
    -------
    ok : ndarray of bool, shape (K,)
    T : ndarray, shape (K, 4, 4)
    """
    from .spherefit import FALSE_ALARM, MIN_THRESHOLD_MM, chi2_quantile

    K, n, _ = tool.shape
    pc, wc = tool.mean(axis=1), world.mean(axis=1)
    H = np.einsum("kni,knj->kij", tool - pc[:, None], world - wc[:, None])
    U, S, Vt = np.linalg.svd(H)
    V, Ut = np.swapaxes(Vt, 1, 2), np.swapaxes(U, 1, 2)
    D = np.ones((K, 3))
    D[:, 2] = np.sign(np.linalg.det(V @ Ut))
    R = (V * D[:, None, :]) @ Ut
    t = wc - np.einsum("kij,kj->ki", R, pc)
    resid = world - (tool @ np.swapaxes(R, 1, 2) + t[:, None])
    rms = np.sqrt(np.mean(np.sum(resid**2, axis=2), axis=1))
    bound = float(np.sqrt(chi2_quantile(1 - FALSE_ALARM, 3 * n - 6) / n))
    threshold = np.where(sigma <= 0, MIN_THRESHOLD_MM, np.maximum(MIN_THRESHOLD_MM, sigma * bound))
    ok = (S[:, 1] >= 1e-9 * np.maximum(S[:, 0], 1e-300)) & (rms <= threshold)
    T = np.zeros((K, 4, 4))
    T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = R, t, 1.0
    return ok, T


def simulate_probes(model, slots, q_commanded, rng: np.random.Generator, tooling, noise, volume=None,
                    n_balls: int = 3, probes_per_ball: int = 4) -> ProbedPoses:
    """:func:`fgcal.simulate.measure` of probe points (no outliers), vectorised.

    The same random stream as ``measure`` (the arm's landing error, then per probed ball the cap's
    uniform draws and the points' CMM noise), so the same points to rounding; only the per-ball
    random draws remain a loop.

    Parameters
    ----------
    slots : ndarray, shape (S,)
        The actual robot (mm, rad).
    q_commanded : array_like, shape (N, n)
        Commanded joints (rad, mm).
    """
    from .simulate import ball_access

    q = np.atleast_2d(np.asarray(q_commanded, dtype=float))
    q_actual = q + rng.normal(size=q.shape) * model.joints_to_internal(np.full(model.n_joints, noise.repeatability))
    reading = model.joints_to_file_units(q)
    if noise.joint_resolution > 0:
        reading = np.round(reading / noise.joint_resolution) * noise.joint_resolution
    T = model.forward(slots, q_actual)
    ok, upness, centres = ball_access(T, tooling, volume)
    keep = np.nonzero(ok.sum(axis=1) >= n_balls)[0]
    # The most upward-facing reachable balls (stable among equals), in the tool's order.
    balls = np.sort(np.argsort(np.where(ok, -upness, np.inf), axis=1, kind="stable")[keep, :n_balls], axis=1)
    K, B, P = len(keep), n_balls, probes_per_ball
    n_ring = P - 1
    u = np.empty((K, B, 2 * n_ring + 1))
    g = np.empty((K, B, P, 3))
    for k in range(K):
        for b in range(B):
            u[k, b] = rng.random(2 * n_ring + 1)  # = uniform(0, 2 pi), then (uniform(45, 75), uniform(-0.2, 0.2))
            g[k, b] = rng.normal(size=(P, 3))
    names = np.array(tooling.names)
    unit = np.array([tooling.balls[nm] / np.linalg.norm(tooling.balls[nm]) for nm in names])[balls]  # (K, B, 3)
    outward = np.einsum("kij,kbj->kbi", T[keep, :3, :3], unit)
    axis = outward + _UP
    axis = axis / np.linalg.norm(axis, axis=2, keepdims=True)
    helper = np.where((np.abs(axis[..., 0]) < 0.9)[..., None], np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    e1 = _cross(axis, helper)
    e1 = e1 / np.linalg.norm(e1, axis=2, keepdims=True)
    e2 = _cross(axis, e1)
    start = 0.0 + 2 * np.pi * u[..., :1]
    polar = np.radians(45.0 + 30.0 * u[..., 1::2])
    az = start + 2 * np.pi * np.arange(n_ring) / max(n_ring, 1) + (-0.2 + 0.4 * u[..., 2::2])
    ring = (np.cos(polar)[..., None] * axis[:, :, None]
            + np.sin(polar)[..., None] * (np.cos(az)[..., None] * e1[:, :, None] + np.sin(az)[..., None] * e2[:, :, None]))
    dirs = np.concatenate([axis[:, :, None], ring], axis=2)[:, :, :P]
    c = centres[keep[:, None], balls]  # (K, B, 3)
    points = c[:, :, None] + tooling.radius * dirs + g * noise.cmm_sigma
    return ProbedPoses(np.arange(1, len(q) + 1)[keep], reading[keep], names[balls], points)


def run_trial(trial: Trial, q_identify=None) -> dict:
    """Simulate, calibrate and verify one trial; a row of :data:`RESULT_COLUMNS`.

    ``q_identify`` (N, 6) rad fixes the identification poses (a designed plan); the trial's own
    random draw is used otherwise. The simulation and the verification's sphere and pose fits are
    the vectorised forms of :func:`fgcal.simulate.measure` and :func:`fgcal.verify.measured_poses`
    (same random stream, same estimators and checks: the same numbers, to rounding).
    """
    from .calibrate import calibrate
    from .dataset import Noise
    from .kinematics import forward
    from .simulate import draw_truth, random_plan
    from .verify import compare_poses

    t0 = time.perf_counter()
    model = _model(trial.robot)
    # crc32, not hash(): str hashes differ between processes
    rng = np.random.default_rng([trial.seed, trial.trial, zlib.crc32(trial.study.encode())])
    truth = draw_truth(model, rng)
    noise = Noise(trial.cmm_sigma, trial.joint_resolution, trial.repeatability)
    measured_pos = measured_ori = float("nan")

    def probe(q):
        return simulate_probes(model, truth, q, rng, model.tooling, noise, model.volume)

    if trial.plan == "experiment":
        plan = _paper_plan(trial.robot)
        keep = rng.permutation(len(plan))[:42]  # six poses lost, as in the paper
        ident_pool, verify_q = plan[keep[:21]], plan[keep[21:]]
        q_id = ident_pool[rng.permutation(21)[:trial.n_poses]] if q_identify is None else q_identify
    else:
        q_id = random_plan(model, truth, trial.n_poses, rng, model.tooling, model.volume) if q_identify is None \
            else q_identify
        verify_q = random_plan(model, truth, trial.n_verify, rng, model.tooling, model.volume)
    if trial.q_plan and q_identify is None:
        q_id = np.array(trial.q_plan, dtype=float)
    result = calibrate(probe(q_id).dataset(model, noise), model)
    ver = probe(verify_q)
    q_ver = np.radians(ver.joints_deg)
    x = result.slot_vector()
    T_cal = forward(x, q_ver)
    after = compare_poses(T_cal, forward(truth, q_ver)).summary()
    pos_rms, pos_max = after["position_mm"]["rms"], after["position_mm"]["max"]
    ori_rms, ori_max = after["orientation_deg"]["rms"], after["orientation_deg"]["max"]
    rows, T_meas = ver.measured_poses(model.tooling, noise.cmm_sigma)
    if len(rows):
        against = compare_poses(T_cal[rows], T_meas).summary()
        measured_pos = against["position_mm"]["rms"]
        measured_ori = against["orientation_deg"]["rms"]
    row = asdict(trial)
    for k in ("n_verify", "q_plan", "predicted", "index_values"):
        row.pop(k)
    for name, value in zip(("O1", "O2", "O3", "O4", "O5"), trial.index_values or (float("nan"),) * 5):
        row[name] = value
    row.update(position_rms_mm=pos_rms, position_max_mm=pos_max, orientation_rms_deg=ori_rms,
               orientation_max_deg=ori_max, measured_position_rms_mm=measured_pos,
               measured_orientation_rms_deg=measured_ori, predicted_position_rms_mm=trial.predicted,
               seconds=time.perf_counter() - t0)
    return {k: row[k] for k in RESULT_COLUMNS}
