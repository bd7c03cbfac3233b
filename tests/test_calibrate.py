import json
import subprocess
import sys

import gtsam
import numpy as np
import pytest

import factors as fx
from fgcal.errors import FgcalError
from fgcal.estimation.baseline import two_stage
from fgcal.estimation.calibrate import (
    CalibrationOptions,
    build_graph,
    calibrate,
    gtsam_covariance,
    levenberg_marquardt,
    nonlinear_graph,
)
from fgcal.estimation.result import load_result, save_result
from fgcal.measurements.dataset import Noise
from fgcal.robots.kinematics import forward
from fgcal.robots.model import SLOT_NAMES, slots_from_file_units
from fgcal.robots.transforms import pose_difference
from fgcal.studies.simulate import SimulationSettings, simulate

EXACT = Noise(cmm_sigma=0.0, joint_resolution=0.0)


def _truth_of(ds, names):
    return np.array([ds.truth[n] for n in names])


@pytest.mark.parametrize("levels", [("probes",), ("centres",), ("poses",), ("probes", "centres", "poses")])
def test_noise_free_data_recovers_the_truth(puma, levels):
    ds, _ = simulate(puma, np.random.default_rng(70), SimulationSettings(n_poses=12, noise=EXACT, levels=levels))
    result = calibrate(ds, puma)
    assert result.converged and result.held == []
    np.testing.assert_allclose(result.estimate, _truth_of(ds, result.names), atol=1e-6)
    np.testing.assert_allclose(result.slot_vector(), slots_from_file_units(_truth_of(ds, SLOT_NAMES)), atol=1e-8)


@pytest.fixture(scope="module")
def monte_carlo(puma):
    """20 seeded 21-pose datasets with the paper's noise, calibrated by fgcal and by the two-stage baseline."""
    z, chi, ours, baseline = [], [], [], []
    for seed in range(20):
        rng = np.random.default_rng(1000 + seed)
        ds, _ = simulate(puma, rng, SimulationSettings(n_poses=21))
        result = calibrate(ds, puma)
        err = result.estimate - _truth_of(ds, result.names)
        z.append(err / result.sigma)
        chi.append(err @ np.linalg.solve(result.covariance, err))
        truth = slots_from_file_units(_truth_of(ds, SLOT_NAMES))
        ver, _ = simulate(puma, rng, SimulationSettings(n_poses=21, noise=EXACT), truth=truth)  # same robot
        q = ver.joints_rad
        for slots, out in ((result.slot_vector(), ours), (two_stage(ds, puma)[0], baseline)):
            d, _ = pose_difference(forward(slots, q), forward(truth, q))
            out.append(np.sqrt(np.mean(np.sum(d**2, axis=1))))
    return np.array(z), np.array(chi), np.array(ours), np.array(baseline)


def test_normalised_errors_are_standard(monte_carlo):
    z, chi, _, _ = monte_carlo
    assert abs(z.mean()) < 0.1  # 600 values: the mean's own sigma is 0.04
    assert 0.8 < z.std() < 1.25
    assert 24 < chi.mean() < 36  # chi-square with 30 dof, within 20%


def test_joint_solve_beats_the_two_stage_method(monte_carlo):
    _, _, ours, baseline = monte_carlo
    # measured: about 0.045 against 0.064 mm RMS position error at new poses
    assert ours.mean() < 0.85 * baseline.mean()
    assert np.mean(ours < baseline) > 0.7


def test_ignoring_the_rounding_makes_the_covariance_lie(puma):
    chi = []
    for seed in range(10):
        ds, _ = simulate(puma, np.random.default_rng(1100 + seed), SimulationSettings(n_poses=21))
        r = calibrate(ds, puma, CalibrationOptions(joint_noise=False, noise="declared"))
        err = r.estimate - _truth_of(ds, r.names)
        chi.append(err @ np.linalg.solve(r.covariance, err))
    assert np.mean(chi) > 2 * 30


def test_same_graph_in_gtsam(puma):
    """GTSAM's own optimiser and Marginals on the factors package's graph agree with the batched solve."""
    ds, _ = simulate(puma, np.random.default_rng(71), SimulationSettings(n_poses=7, levels=("probes", "centres",
                                                                                            "poses")))
    graph, state, _ = build_graph(ds, puma, puma.identifiable_names(), CalibrationOptions())
    solved, _, converged = levenberg_marquardt(graph, state)
    assert converged
    cov = gtsam_covariance(graph, solved)
    g, values = nonlinear_graph(graph, state)
    assert g.error(values) == pytest.approx(graph.cost(state), rel=1e-9)
    p = gtsam.LevenbergMarquardtParams()
    p.setRelativeErrorTol(1e-14)
    p.setAbsoluteErrorTol(1e-14)
    p.setMaxIterations(200)
    theta = gtsam.LevenbergMarquardtOptimizer(g, values, p).optimize().atVector(fx.theta_key())
    np.testing.assert_allclose(theta, solved.theta, atol=1e-6 * np.sqrt(np.diag(cov)).min())
    g2, v2 = nonlinear_graph(graph, solved)
    np.testing.assert_allclose(gtsam.Marginals(g2, v2).marginalCovariance(fx.theta_key()), cov,
                               rtol=1e-6, atol=1e-9 * np.abs(cov).max())
    # calibrate's covariance, the inverse of the solve's Schur complement, is GTSAM's
    np.testing.assert_allclose(graph.covariance(solved), cov, rtol=1e-6, atol=1e-9 * np.abs(cov).max())


def test_redundant_parameter_is_held_and_named(puma):
    ds, _ = simulate(puma, np.random.default_rng(72), SimulationSettings(n_poses=15))
    r = calibrate(ds, puma, CalibrationOptions(extra=("j1.theta", "j2.d")))
    held = {h["name"]: h for h in r.held}
    assert set(held) == {"j1.theta", "j2.d"}
    assert "base.phi" in held["j1.theta"]["reason"] and "j3.d" in held["j2.d"]["reason"]
    assert len(r.parameters) == 30 and r.slots["j1.theta"] == 0.0


def test_position_only_holds_what_it_cannot_see(puma):
    from dataclasses import replace

    from fgcal.robots.model import Tooling
    tracker = replace(puma, tooling=Tooling(6.35, {"R": np.array([10.0, 20.0, 40.0])}))  # one reflector
    ds, _ = simulate(tracker, np.random.default_rng(73), SimulationSettings(n_poses=30, levels=("centres",),
                                                                            n_balls=1, noise=EXACT))
    r = calibrate(ds, puma)
    # a point off the flange axis: the tool's six parameters only place it (3 dof)
    assert len(r.held) == 3 and len(r.parameters) == 27
    assert all(h["name"].startswith("tool.") for h in r.held)
    # what is identified is exact, and the position of the measured ball is reproduced
    truth = slots_from_file_units(_truth_of(ds, SLOT_NAMES))
    q = ds.joints_rad
    ball = ds.tooling.balls[ds.centres.ball[0]]
    from fgcal.robots.kinematics import tool_points
    np.testing.assert_allclose(tool_points(forward(r.slot_vector(), q), ball), tool_points(forward(truth, q), ball),
                               atol=1e-6)


def test_too_few_poses_says_how_many(puma):
    ds, _ = simulate(puma, np.random.default_rng(74), SimulationSettings(n_poses=4))
    with pytest.raises(FgcalError, match="4 poses give 24 equations but the 30 parameters need at least 30"):
        calibrate(ds, puma)


@pytest.mark.parametrize("loss", ["huber", "cauchy"])
def test_robust_losses_resist_outliers(puma, loss):
    ds, _ = simulate(puma, np.random.default_rng(75), SimulationSettings(n_poses=30, outlier_fraction=0.03,
                                                                         outlier_size=1.0))
    assert len(ds.truth_outliers) >= 5
    plain = calibrate(ds, puma, CalibrationOptions(outliers="none", noise="declared"))
    robust = calibrate(ds, puma, CalibrationOptions(robust=loss, outliers="none", noise="declared"))
    truth = _truth_of(ds, plain.names)
    z_plain = np.sqrt(np.mean(((plain.estimate - truth) / robust.sigma) ** 2))
    z_robust = np.sqrt(np.mean(((robust.estimate - truth) / robust.sigma) ** 2))
    assert z_robust < 0.5 * z_plain and z_robust < 2.0


def test_noise_is_estimated(puma):
    ds, _ = simulate(puma, np.random.default_rng(76), SimulationSettings(n_poses=30, noise=Noise(0.02, 0.01)))
    ds.noise = Noise(0.01, 0.01)  # the file claims half the real CMM noise
    r = calibrate(ds, puma, CalibrationOptions(noise="declared"))
    assert 3.0 < r.levels["probes"].variance_factor < 5.0
    assert r.noise_mode == "declared" and r.noise["probes"].used == 0.01
    fixed = calibrate(ds, puma)
    assert abs(fixed.levels["probes"].variance_factor - 1) < 0.05
    assert 0.017 < fixed.levels["probes"].sigma < 0.023


def test_result_round_trip(puma, tmp_path):
    ds, _ = simulate(puma, np.random.default_rng(77), SimulationSettings(n_poses=10))
    r = calibrate(ds, puma, CalibrationOptions(extra=("j1.d",)))
    save_result(r, tmp_path / "r.json")
    back = load_result(tmp_path / "r.json")
    assert back.names == r.names and back.held == r.held and back.pose_ids == r.pose_ids
    np.testing.assert_array_equal(back.estimate, r.estimate)
    np.testing.assert_array_equal(back.covariance, r.covariance)
    np.testing.assert_array_equal(back.slot_vector(), r.slot_vector())
    assert back.levels == r.levels
    d = json.loads((tmp_path / "r.json").read_text())
    assert d["format"] == "fgcal-result/1" and set(d["parameters"][0]) >= {"name", "unit", "nominal", "estimate", "sigma"}


def _run(*args):
    return subprocess.run([sys.executable, "-m", "fgcal.cli", *map(str, args)], capture_output=True, text=True)


def test_cli_calibrate_and_verify(puma, tmp_path):
    assert _run("simulate", tmp_path / "id", "--poses", "21", "--seed", "3").returncode == 0
    assert _run("simulate", tmp_path / "ver", "--poses", "21", "--seed", "4", "--truth",
                tmp_path / "id" / "truth.yaml").returncode == 0
    run = _run("calibrate", tmp_path / "id", "--out", tmp_path / "r.json")
    assert run.returncode == 0, run.stderr
    assert "probes" in run.stdout and "j2.beta" in run.stdout
    run = _run("verify", tmp_path / "r.json", tmp_path / "ver", "--out", tmp_path / "v.json")
    assert run.returncode == 0, run.stderr
    v = json.loads((tmp_path / "v.json").read_text())
    assert v["n_poses"] == 21
    for key in ("position_mm", "orientation_deg"):
        assert set(v[key]) == {"mean", "rms", "max"}
        assert v["truth"][key]["rms"] < 0.1 * v["truth"]["before"][key]["rms"]
    assert v["truth"]["position_mm"]["rms"] < 0.1


def test_cli_bad_input_leaves_no_result(puma, tmp_path):
    assert _run("simulate", tmp_path / "d", "--poses", "4").returncode == 0
    run = _run("calibrate", tmp_path / "d", "--out", tmp_path / "r.json")
    assert run.returncode == 2 and "need at least 30" in run.stderr and "Traceback" not in run.stderr
    assert not (tmp_path / "r.json").exists()
    (tmp_path / "d" / "joints.csv").write_text("pose,q1,q2,q3,q4,q5,q6\n1,0,0,0,0,0\n")
    run = _run("calibrate", tmp_path / "d", "--out", tmp_path / "r.json")
    assert run.returncode == 2 and "joints.csv: line 2" in run.stderr and not (tmp_path / "r.json").exists()
    run = _run("verify", tmp_path / "nope.json", tmp_path / "d")
    assert run.returncode == 2 and "nope.json: file not found" in run.stderr


@pytest.mark.parametrize("levels", [("probes",), ("centres",)])
def test_a_warm_start_ends_at_the_cold_optimum_in_fewer_steps(puma, levels):
    """``solve_calibration(start=...)`` (how the online engines' final smoothing starts from their
    estimate) reaches the optimum, noise and covariance of the cold start (the nominal chain with
    the base fitted), in fewer Levenberg-Marquardt iterations; the equation check still refuses
    too few poses."""
    from fgcal.estimation.calibrate import solution_covariance, solve_calibration

    settings = SimulationSettings(n_poses=40, levels=levels, noise=Noise(0.02, 0.02))
    ds, truth = simulate(puma, np.random.default_rng(77), settings)
    # The iterations are counted to a gain of 1e-10 of the cost: at the default 1e-12 the last one
    # is taken or not on a gain of ~1e-12 (2e-10 of 165), which the kinematics' rounding decides.
    options = CalibrationOptions(prior="weak", tolerance=1e-10)
    cold = solve_calibration(ds, puma, options, decide_held=False)
    cov = solution_covariance(cold)
    sigma = np.sqrt(np.diag(cov))
    start = cold.graph.params.full(cold.state.theta + 0.5 * sigma * np.random.default_rng(5).standard_normal(len(sigma)),
                                   cold.graph.held)
    warm = solve_calibration(ds, puma, options, start=start, decide_held=False)
    assert warm.graph.params.names == cold.graph.params.names
    assert np.max(np.abs(warm.state.theta - cold.state.theta) / sigma) < 1e-4
    np.testing.assert_allclose(np.sqrt(np.diag(solution_covariance(warm))), sigma, rtol=1e-5)
    assert warm.graph.sigmas.probe == pytest.approx(cold.graph.sigmas.probe, rel=1e-6)
    assert warm.iterations < cold.iterations
    with pytest.raises(FgcalError, match="poses give"):
        solve_calibration(ds.select(ds.pose_ids[:3]), puma, options, start=start, decide_held=False)
    with pytest.raises(FgcalError, match="finite slots"):
        solve_calibration(ds, puma, options, start=start[:-1], decide_held=False)


@pytest.mark.parametrize("settings", [
    SimulationSettings(n_poses=5, levels=("probes",)),
    SimulationSettings(n_poses=9, levels=("centres",), n_balls=1),
    SimulationSettings(n_poses=7, levels=("centres",), n_balls=2),
    SimulationSettings(n_poses=4, levels=("poses",)),
    SimulationSettings(n_poses=20, levels=("distances",), n_balls=1),
    SimulationSettings(n_poses=6, levels=("centres", "distances"), n_balls=2),
    SimulationSettings(n_poses=5, levels=("probes", "centres"), n_balls=2),  # a ball at two levels counts once
])
def test_the_equation_count_is_the_poses_degrees_of_freedom(puma, settings):
    """The count calibrate refuses on equals a plain per-pose count written here: a full pose or
    three balls give 6, two balls 5, one ball 3, a ballbar length 1."""
    import re

    from fgcal.estimation.calibrate import _check_equations

    ds, _ = simulate(puma, np.random.default_rng(len(settings.levels) + settings.n_poses), settings)
    expected = 0
    for p in ds.pose_ids:
        balls = set()
        for lv in settings.levels:
            obs = getattr(ds, lv)
            if lv == "distances":
                expected += int(np.sum(obs.pose == p))
            elif lv != "poses":
                balls |= set(obs.ball[obs.pose == p].tolist())
        full = "poses" in settings.levels and bool(np.any(ds.poses.pose == p))
        expected += 6 if full else (0, 3, 5, 6)[min(len(balls), 3)]
    with pytest.raises(FgcalError) as err:
        _check_equations(ds, settings.levels, 10**6)
    assert int(re.search(r"give (\d+) equations", str(err.value)).group(1)) == expected
    _check_equations(ds, settings.levels, expected)  # exactly enough: no error


def test_sphere_fits_kept_between_builds_give_fresh_builds(puma):
    """``build_graph(fits=...)`` (the online final smoothing builds the smoothed poses twice: the
    held decision's graph at the batch's start, then the solve's at the engine's estimate) gives
    the states of builds without it, bit for bit, and the second build adds nothing to ``fits``:
    only the fit started at its own prediction is computed again."""
    from fgcal.estimation.build import build_graph

    ds, _ = simulate(puma, np.random.default_rng(31), SimulationSettings(n_poses=30))
    names = puma.parameters().names
    start = puma.nominal + np.random.default_rng(2).normal(0.0, 1e-3, puma.nominal.shape)
    builds = [(CalibrationOptions(prior="none"), None), (CalibrationOptions(prior="weak"), start)]
    fits: dict = {}
    kept = []
    for options, at in builds:
        _, shared, _ = build_graph(ds, puma, names, options, start=at, fits=fits)
        kept.append(len(fits))
        _, fresh, _ = build_graph(ds, puma, names, options, start=at)
        for u, v in ((shared.theta, fresh.theta), (shared.c, fresh.c), (shared.q, fresh.q)):
            assert u.tobytes() == v.tobytes()
    assert kept[0] > 0 and kept[1] == kept[0]
