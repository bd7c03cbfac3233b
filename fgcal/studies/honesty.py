"""Are the default calibration's uncertainties honest? Seeded scenarios against the simulated truth.

Each :data:`SCENARIOS` row simulates a PUMA 560 with the paper's noise (CMM 0.01 mm, joint
resolution 0.01 deg, 21 random poses, 3 balls x 4 probe points) changed in one respect,
calibrates it with default options, and compares with the truth: the chi-square of the true
error per parameter (1 is honest), the share of 95% intervals that cover the truth, and the RMS
position error of the balls at 100 random joint sets against the paper's two-stage method
(:func:`fgcal.estimation.baseline.two_stage`; least squares on the measured centres or poses when there are
no probe points). Where the noise in the file differs from the simulated one ("undeclared"), the
dataset keeps the declared values. Used by ``bench/bench_honest.py`` and the tests. No I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares

from fgcal.estimation.baseline import two_stage
from fgcal.estimation.calibrate import calibrate
from fgcal.estimation.options import CalibrationOptions
from fgcal.measurements.dataset import Noise
from fgcal.robots.kinematics import forward, jacobians, tool_points
from fgcal.robots.model import SLOT_NAMES, ParameterSet, slots_from_file_units
from fgcal.robots.transforms import pose_difference
from fgcal.studies.simulate import SimulationSettings, simulate

__all__ = [
    "SCENARIOS",
    "Scenario",
    "add_gross_errors",
    "online_agreement",
    "run_scenario",
    "scenario_dataset",
    "summarise",
]

Z95 = 1.959963984540054


@dataclass(frozen=True)
class Scenario:
    """One row: simulation settings, the noise the file declares, and injected gross probe errors."""

    settings: SimulationSettings = SimulationSettings(n_poses=21)
    declared: Noise | None = None  # None: the simulated noise is declared
    gross_errors: int = 0
    gross_size: float = 0.5  # mm along the probe direction
    mirrored: int = 0  # balls re-probed on a narrow cap where a plain sphere fit lands on the mirror image
    options: CalibrationOptions = field(default_factory=CalibrationOptions)


PAPER = Noise(0.01, 0.01)
SCENARIOS = {
    "21 poses": Scenario(),
    "7 poses": Scenario(SimulationSettings(n_poses=7)),
    "200 poses": Scenario(SimulationSettings(n_poses=200)),
    "centres only": Scenario(SimulationSettings(n_poses=21, levels=("centres",))),
    "poses only": Scenario(SimulationSettings(n_poses=21, levels=("poses",))),
    "1 ball per pose": Scenario(SimulationSettings(n_poses=21, n_balls=1)),
    "2 balls per pose": Scenario(SimulationSettings(n_poses=21, n_balls=2)),
    "joint resolution 0": Scenario(SimulationSettings(n_poses=21, noise=Noise(0.01, 0.0))),
    "joint resolution 0.1 deg": Scenario(SimulationSettings(n_poses=21, noise=Noise(0.01, 0.1))),
    "repeatability 0.01 deg undeclared": Scenario(SimulationSettings(n_poses=21, noise=Noise(0.01, 0.01, 0.01)),
                                                  declared=PAPER),
    "CMM noise 5x declared": Scenario(SimulationSettings(n_poses=21, noise=Noise(0.05, 0.01)), declared=PAPER),
    "3 gross probe errors": Scenario(gross_errors=3),
}


def add_gross_errors(ds, truth, n: int, size: float, rng) -> list[tuple[int, str, int]]:
    """Displace ``n`` random probe points by ``size`` mm along their true probing direction (in place).

    Returns ``(pose, ball, row in probes.csv)`` of each.
    """
    pr = ds.probes
    rows = rng.choice(len(pr), size=n, replace=False)
    q = ds.joints_rad[ds.row_of(pr.pose[rows])]
    offsets = np.array([ds.tooling.balls[b] for b in pr.ball[rows]])
    centres = tool_points(forward(truth, q), offsets[:, None, :])[:, 0]
    d = pr.xyz[rows] - centres
    pr.xyz[rows] += size * rng.choice([-1.0, 1.0], size=(n, 1)) * d / np.linalg.norm(d, axis=1, keepdims=True)
    return [(int(pr.pose[k]), str(pr.ball[k]), int(k)) for k in rows]


def add_mirrored_caps(ds, truth, n: int, rng, half_angle_deg: float = 8.0) -> list[tuple[int, str]]:
    """Re-probe ``n`` random balls on a narrow cap (in place) where a plain sphere fit (no prediction)
    converges to the mirror image of the centre through the points. Returns their ``(pose, ball)``."""
    from fgcal.measurements.spherefit import fit_spheres_checked

    pr = ds.probes
    keys = list(dict.fromkeys(zip(pr.pose.tolist(), pr.ball.tolist())))
    out: list[tuple[int, str]] = []
    for k in rng.permutation(len(keys)):
        if len(out) == n:
            break
        pose, ball = keys[k]
        rows = np.nonzero((pr.pose == pose) & (pr.ball == ball))[0]
        # where the ball was: the fit of its original (well spread) points, not the forward
        # kinematics at the readings, which the joint noise puts ~0.05 mm away (the new cap would
        # then disagree with the pose's other balls by ten times its precision along its axis)
        centre = fit_spheres_checked([pr.xyz[rows]], ds.tooling.radius, max(ds.noise.cmm_sigma, 1e-6))[0].centre
        axis = pr.xyz[rows].mean(axis=0) - centre
        axis /= np.linalg.norm(axis)
        e1 = np.cross(axis, [1.0, 0, 0] if abs(axis[0]) < 0.9 else [0, 1.0, 0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(axis, e1)
        for _ in range(200):
            polar = np.radians(rng.uniform(0, half_angle_deg, len(rows)))
            az = rng.uniform(0, 2 * np.pi, len(rows))
            d = (np.cos(polar)[:, None] * axis + np.sin(polar)[:, None] * (np.cos(az)[:, None] * e1
                                                                              + np.sin(az)[:, None] * e2))
            pts = centre + ds.tooling.radius * d + rng.normal(size=d.shape) * ds.noise.cmm_sigma
            fit = fit_spheres_checked([pts], ds.tooling.radius, max(ds.noise.cmm_sigma, 1e-6))[0]
            if fit.ok and np.linalg.norm(fit.centre - centre) > ds.tooling.radius:
                pr.xyz[rows] = pts
                out.append((int(pose), str(ball)))
                break
    return out


def _baseline(ds, model, names) -> np.ndarray:
    """Two-stage (probes) or single-stage least squares on centres or poses, readings taken as exact."""
    if ds.probes is not None:
        return two_stage(ds, model, names)[0]
    params = ParameterSet(model, tuple(names))
    if ds.centres is not None:
        c = ds.centres
        q = ds.joints_rad[ds.row_of(c.pose)]
        off = np.array([ds.tooling.balls[b] for b in c.ball]).reshape(-1, 1, 3)

        def res(th):
            return (jacobians(params.full(th), q, off).points[:, 0] - c.xyz).ravel()
    else:
        p = ds.poses
        q = ds.joints_rad[ds.row_of(p.pose)]
        T = p.matrices()
        rot_scale = ds.noise.pose_position_sigma / np.radians(ds.noise.pose_orientation_sigma)

        def res(th):
            d, delta = pose_difference(T, forward(params.full(th), q))
            return np.concatenate([d.ravel(), rot_scale * delta.ravel()])
    sol = least_squares(res, params.nominal(), method="lm", xtol=1e-12, ftol=1e-12)
    return params.full(sol.x)


def _reference(result, truth, model, q, points) -> np.ndarray:
    """The truth of the estimated parameters, with the held ones' deviations absorbed as the data allow."""
    names = result.names
    held = [h["name"] for h in result.held]
    t = np.array([truth[SLOT_NAMES.index(n)] for n in names])
    if not held:
        return t
    params = ParameterSet(model, tuple(names + held))
    slots = jacobians(truth, q, points).point_slots
    assert slots is not None  # asked for by the points
    J = slots[..., params.index].reshape(-1, len(names) + len(held))
    x = result.slot_vector()
    dh = np.array([truth[SLOT_NAMES.index(n)] - x[SLOT_NAMES.index(n)] for n in held])
    return t + np.linalg.lstsq(J[:, :len(names)], J[:, len(names):] @ dh, rcond=None)[0]


def scenario_dataset(model, scenario: Scenario, seed: int):
    """``(dataset, truth slots, planted gross errors, rng)`` of one seeded row of a scenario."""
    rng = np.random.default_rng(seed)
    ds, _ = simulate(model, rng, scenario.settings)
    truth = slots_from_file_units(np.array([ds.truth[n] for n in SLOT_NAMES]))
    planted = add_gross_errors(ds, truth, scenario.gross_errors, scenario.gross_size, rng) \
        if scenario.gross_errors else []
    if scenario.mirrored:
        add_mirrored_caps(ds, truth, scenario.mirrored, rng)
    if scenario.declared is not None:
        ds.noise = replace(scenario.declared, pose_position_sigma=ds.noise.pose_position_sigma,
                           pose_orientation_sigma=ds.noise.pose_orientation_sigma)
    return ds, truth, planted, rng


def online_agreement(model, kind: str, seed: int, reverse: bool = False, scenario: Scenario = Scenario()) -> dict:
    """An online engine fed a scenario's poses (reversed on request) against the batch solve of all of them.

    Returns ``max_sigma`` (largest |online - batch| over the batch sigma), ``rejected`` (poses the
    engine refused), ``mirrored`` (balls whose plain sphere fit, without the kinematic
    prediction, lands more than a radius from the true centre: the mirror image) and
    ``batch_truth`` (largest |batch - truth| over the batch sigma).
    """
    from fgcal.measurements.spherefit import fit_spheres_checked
    from fgcal.online.engines import make_engine, pose_records

    ds, truth, _, _ = scenario_dataset(model, scenario, seed)
    batch = calibrate(ds, model, replace(scenario.options, prior="weak"))
    engine = make_engine(kind, ds, model, scenario.options)
    records = pose_records(ds)[::-1] if reverse else pose_records(ds)
    rejected = sum(not engine.update(rec).accepted for rec in records)
    engine.finish()
    theta, _ = engine.estimate()
    est = engine.params.to_file_units(theta)
    mirrored = 0
    for rec in records:
        if not rec.probes:
            continue
        fits = fit_spheres_checked([p for _, p in rec.probes], ds.tooling.radius, ds.noise.cmm_sigma)
        true = tool_points(forward(truth, rec.q[None]), np.array([ds.tooling.balls[b] for b, _ in rec.probes]))[0]
        mirrored += sum(np.linalg.norm(f.centre - t) > ds.tooling.radius for f, t in zip(fits, true))
    truth_est = ParameterSet(model, tuple(batch.names)).to_file_units(_reference(batch, truth, model, ds.joints_rad,
                                                                               model.tooling.offsets()))
    return {"max_sigma": float(np.max(np.abs(est - batch.estimate) / batch.sigma)), "rejected": rejected,
            "mirrored": int(mirrored), "batch_truth": float(np.max(np.abs(batch.estimate - truth_est) / batch.sigma))}


def run_scenario(model, scenario: Scenario, seeds) -> list[dict]:
    """One dict per seed: ``chi2_per_dof``, ``covered`` (fraction), ``fgcal_mm``, ``baseline_mm``, ``outliers``."""
    out = []
    points = model.tooling.offsets()
    for seed in seeds:
        ds, truth, planted, rng = scenario_dataset(model, scenario, seed)
        r = calibrate(ds, model, scenario.options)
        # the truth in the estimated parameters (file units, as the result's)
        ref = _reference(r, truth, model, ds.joints_rad, points)
        params = ParameterSet(model, tuple(r.names))
        err = r.estimate - params.to_file_units(ref)
        chi2 = float(err @ np.linalg.solve(r.covariance, err))
        q_new = rng.uniform(model.joint_limits[:, 0], model.joint_limits[:, 1], size=(100, 6))
        true_pts = tool_points(forward(truth, q_new), points)

        def rms(slots, q_new=q_new, true_pts=true_pts):
            return float(np.sqrt(np.mean(np.sum((tool_points(forward(slots, q_new), points) - true_pts) ** 2, axis=2))))

        base = _baseline(ds, model, model.identifiable_names())
        found = {(o.pose, o.ball) for o in r.outliers if o.level == "probes"}
        out.append({"seed": seed, "chi2_per_dof": chi2 / len(err),
                    "covered": float(np.mean(np.abs(err) <= Z95 * r.sigma)), "fgcal_mm": rms(r.slot_vector()),
                    "baseline_mm": rms(base), "n_params": len(err), "held": len(r.held),
                    "outliers": len(r.outliers), "planted_found": sum((p, b) in found for p, b, _ in planted),
                    "noise": {k: n.used for k, n in r.noise.items()}})
    return out


def summarise(rows: list[dict]) -> dict:
    """Mean chi-square per dof, coverage, mean accuracy of fgcal and the baseline over the seeds."""
    return {"n": len(rows), "chi2_per_dof": float(np.mean([r["chi2_per_dof"] for r in rows])),
            "coverage": float(np.mean([r["covered"] for r in rows])),
            "fgcal_mm": float(np.mean([r["fgcal_mm"] for r in rows])),
            "baseline_mm": float(np.mean([r["baseline_mm"] for r in rows])),
            "outliers": float(np.mean([r["outliers"] for r in rows])),
            "planted_found": float(np.mean([r["planted_found"] for r in rows])),
            "held": float(np.mean([r["held"] for r in rows]))}
