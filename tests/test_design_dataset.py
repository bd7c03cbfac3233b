"""Design for a dataset's measurement type (probes, centres = position only, poses), robot and noise."""
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fgcal.errors import FgcalError
from fgcal.estimation.calibrate import calibrate
from fgcal.estimation.verification import verify
from fgcal.io.dataset_io import save_dataset
from fgcal.measurements.dataset import Noise
from fgcal.robots.model import slots_from_file_units
from fgcal.robots.robot_file import model_from_dict, model_to_dict, save_model
from fgcal.studies.design import candidate_pool
from fgcal.studies.design_dataset import dataset_layout, design_from_dataset, load_plan, save_plan
from fgcal.studies.design_info import information
from fgcal.studies.design_validate import compare_on_held_out
from fgcal.studies.simulate import SimulationSettings, simulate

NOISE = Noise(0.01, 0.01)
_REL = Path("shared/data/landgraf-ur10/Series_B/measurements_joint_configurations.csv")
SERIES = next((p / _REL for p in Path(__file__).resolve().parents if (p / _REL).exists()), None)


def _cli(*args, timeout=120):
    return subprocess.run([sys.executable, "-m", "fgcal.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


@pytest.mark.parametrize("level", ["centres", "poses"])
def test_information_matches_the_estimators_covariance(puma, level):
    """The design's information for position-only and full-pose data predicts a calibration's sigmas."""
    ds, _ = simulate(puma, np.random.default_rng(130), SimulationSettings(n_poses=20, noise=NOISE, levels=(level,)))
    info = information(puma, ds.joints_rad, dataset_layout(ds, puma), ds.noise)
    predicted = np.sqrt(np.diag(np.linalg.inv(info.sum(axis=0))))
    r = calibrate(ds, puma)
    actual = r.sigma / np.where(np.array([p.unit == "deg" for p in r.parameters]), np.degrees(1), 1)
    ratio = actual / predicted
    assert 0.8 < np.median(ratio) < 1.25 and ratio.min() > 0.5 and ratio.max() < 2.0


@pytest.mark.parametrize("level", ["centres", "poses"])
def test_plan_from_a_dataset_beats_random_sets_at_held_out_poses(puma, level):
    """Position-only and full-pose datasets: the plan keeps the dataset's pose ids, is predicted
    better than most random sets, and verifies better than the median random set on new poses
    of the same simulated robot."""
    settings = SimulationSettings(n_poses=150, noise=NOISE, levels=(level,))
    ds, _ = simulate(puma, np.random.default_rng(131), settings)
    truth = np.array(list(ds.truth.values()))  # all slots, in order (mm, deg)
    held, _ = simulate(puma, np.random.default_rng(132), SimulationSettings(n_poses=60, noise=NOISE, levels=(level,)),
                       truth=slots_from_file_units(truth))
    c = compare_on_held_out(ds, held, puma, 12, random_sets=9, rng=np.random.default_rng(133))
    plan = c.plan
    assert set(plan.pose_ids) <= set(ds.pose_ids) and len(set(plan.pose_ids)) == 12
    np.testing.assert_allclose(plan.joints_deg, ds.joints_deg[ds.row_of(plan.pose_ids)])
    assert plan.levels == (level,) and not plan.dropped
    assert plan.values["pred"] < np.percentile(plan.random_pred, 10)
    assert c.plan_mean < np.median(c.random_mean)


def _misdeclared(puma, true: Noise, declared: Noise, seed: int):
    """A simulated 150-pose dataset of full poses with noise ``true`` that declares ``declared``,
    60 new poses of the same robot, and the realised position error RMS (mm, against the truth at
    the new poses) of a calibration from given pose ids."""
    settings = SimulationSettings(n_poses=150, noise=true, levels=("poses",))
    ds, _ = simulate(puma, np.random.default_rng(seed), settings)
    held, _ = simulate(puma, np.random.default_rng(seed + 1), replace(settings, n_poses=60),
                       truth=slots_from_file_units(np.array(list(ds.truth.values()))))
    ds = replace(ds, noise=declared)

    def realised(ids):
        return float(np.sqrt(np.mean(verify(calibrate(ds.select(ids), puma), held, puma).truth_after.position_mm ** 2)))
    return ds, realised


def test_design_for_the_estimated_noise_predicts_and_beats_random_sets(puma):
    """A dataset whose declared position noise is 10x too small (as a tracker's stated noise is,
    against a robot's unmodelled errors): designing for the declared noise misweighs position
    against orientation, and its plan calibrates worse than the median random set; designing for
    the noise estimated from the dataset gives a plan whose predicted accuracy (at new poses,
    against the simulated truth) is the realised one, and which beats the random sets."""
    true = Noise(0.01, 0.0, pose_position_sigma=0.1, pose_orientation_sigma=0.01)
    ds, realised = _misdeclared(puma, true, replace(true, pose_position_sigma=0.01), 140)
    plan = design_from_dataset(ds, puma, 12, random_sets=100, rng=np.random.default_rng(142))
    declared = design_from_dataset(ds, puma, 12, random_sets=100, rng=np.random.default_rng(142), noise="declared")
    decl, used, _ = plan.noise["poses"]
    assert decl == 0.01 and used == pytest.approx(0.1, rel=0.15)
    assert plan.noise["poses_rotation"][1] == pytest.approx(0.01, rel=0.15) and not declared.noise

    rng = np.random.default_rng(143)
    random = np.median([realised(rng.choice(ds.pose_ids, 12, replace=False)) for _ in range(10)])
    got = realised(plan.pose_ids)
    assert got < 0.85 * random and realised(declared.pose_ids) > random  # measured: 0.100, 0.139, 0.155 mm
    assert plan.values["pred"] < np.percentile(plan.random_pred, 5)
    # predicted = realised, for the plan and the random sets (measured: 0.125 / 0.100, 0.156 / 0.139 mm) ...
    assert plan.values["pred"] == pytest.approx(got, rel=0.35)
    assert np.median(plan.random_pred) == pytest.approx(random, rel=0.25)
    # ... where the declared noise promises 9x better than realised
    assert np.median(declared.random_pred) < 0.2 * random


def test_unmodelled_joint_error_is_found_and_its_sandwich_predicts_the_realised_accuracy(puma):
    """The robot's unmodelled error as a random joint-space error (the simulator's repeatability,
    0.02 deg) that the dataset does not declare: the design finds it from the excess of the
    estimated noise (0.245 mm and 0.027 deg per pose against the declared 0.01 mm, as on the
    Landgraf UR10), and the covariance of the estimator as it weighs the data under that error
    (the sandwich) predicts the realised accuracy at new poses, against the simulated truth, for
    the plan and for random sets; the plan beats the random sets."""
    true = Noise(0.01, 0.0, 0.02, pose_position_sigma=0.01, pose_orientation_sigma=0.001)
    ds, realised = _misdeclared(puma, true, replace(true, repeatability=0.0), 150)
    plan = design_from_dataset(ds, puma, 12, random_sets=100, rng=np.random.default_rng(152))
    assert plan.noise["unmodelled joint error"][1] == pytest.approx(0.02, rel=0.15)  # measured 0.0195 deg

    rng = np.random.default_rng(153)
    random = np.median([realised(rng.choice(ds.pose_ids, 12, replace=False)) for _ in range(10)])
    got = realised(plan.pose_ids)
    assert got < 0.85 * random  # measured 0.291 against 0.369 mm
    assert plan.values["pred"] == pytest.approx(got, rel=0.2)  # measured 0.281
    assert np.median(plan.random_pred) == pytest.approx(random, rel=0.2)  # measured 0.381


def test_sandwich_middle_is_the_information_when_the_weights_are_right(puma):
    from fgcal.studies.design_info import information_and_middle, layout_from_access, sigmas_of

    pool = candidate_pool(puma, 40, np.random.default_rng(154))
    for level in ("probes", "centres", "poses"):
        layout = layout_from_access(puma, pool, (level,))
        info = information(puma, pool, layout, NOISE)
        same, middle = information_and_middle(puma, pool, layout, NOISE)
        np.testing.assert_allclose(same, info)
        np.testing.assert_allclose(middle, info, rtol=1e-9, atol=1e-9 * np.abs(info).max())
        # weights of twice the actual sigma on every row: the middle is a quarter of their information
        sig = sigmas_of(NOISE, puma)
        half = sig.replaced(probe=2 * sig.probe, centre=2 * sig.centre, pose_position=2 * sig.pose_position,
                       pose_rotation=2 * sig.pose_rotation, kinematic=2 * sig.kinematic, joint=2 * sig.joint)
        _, m2 = information_and_middle(puma, pool, layout, NOISE, sigmas=half, actual=sig)
        np.testing.assert_allclose(m2, information(puma, pool, layout, NOISE, sigmas=half) / 4, rtol=1e-9,
                                   atol=1e-9 * np.abs(info).max())


def test_plan_round_trip_and_cli_with_candidate_file(puma, tmp_path):
    ds, _ = simulate(puma, np.random.default_rng(134), SimulationSettings(n_poses=30, noise=NOISE, levels=("centres",)))
    save_dataset(ds, tmp_path / "ds")
    # the user's own candidates: other poses, other ids
    q = candidate_pool(puma, 80, np.random.default_rng(135))
    ids = np.arange(501, 581)
    outside = np.degrees(q[:1]) + [400.0, 0, 0, 0, 0, 0]  # beyond joint 1's limit: left out
    messages = []
    plan = design_from_dataset(ds, puma, 10, (np.r_[ids, 999], np.vstack([np.degrees(q), outside])),
                               random_sets=20, progress=messages.append)
    assert plan.n_candidates == 80 and 999 not in plan.pose_ids
    # progress: every step is told, and their number is bounded
    assert "greedy start: 10 of 10 poses" in messages and len(messages) <= 1 + 10 + 200
    save_plan(plan, tmp_path / "plan.csv")
    back_ids, back_q = load_plan(tmp_path / "plan.csv")
    np.testing.assert_array_equal(back_ids, plan.pose_ids)
    np.testing.assert_array_equal(back_q, plan.joints_deg)
    assert set(plan.pose_ids) <= set(ids)
    save_plan(plan.__class__(ids, np.degrees(q), "pred", {}, np.zeros(1), ("centres",), 80, 80, 0),
              tmp_path / "candidates.csv")
    run = _cli("design", "--dataset", tmp_path / "ds", "--candidates", tmp_path / "candidates.csv", "--poses", 10,
               "--out", tmp_path / "cli-plan.csv")
    assert run.returncode == 0, run.stderr
    cli_ids, _ = load_plan(tmp_path / "cli-plan.csv")
    assert set(cli_ids) <= set(ids) and len(cli_ids) == 10
    assert "predicted position error RMS" in run.stdout and "quartiles" in run.stdout
    too_many = _cli("design", "--dataset", tmp_path / "ds", "--poses", 31, "--out", tmp_path / "x.csv")
    assert too_many.returncode == 2 and "fewer candidates than poses" in too_many.stderr
    assert len(too_many.stderr.strip().splitlines()) == 1


@pytest.fixture(scope="module")
def one_reflector(tmp_path_factory, puma):
    """The PUMA with a single tracker reflector at the flange (issue 12: design looped forever)."""
    d = model_to_dict(puma)
    d["name"] = "puma-one-reflector"
    d["tooling"] = {"radius": 0.0, "balls": {"P": [0.0, 0.0, 0.0]}}
    path = tmp_path_factory.mktemp("reflector") / "robot.yaml"
    save_model(model_from_dict(d), path)
    return path


def test_one_reflector_ends_and_says_what_it_cannot_do(one_reflector, tmp_path):
    out = tmp_path / "plan.csv"
    probes = _cli("design", "--robot", one_reflector, "--poses", 12, "--candidates", 300, "--out", out)
    assert probes.returncode == 2 and "radius" in probes.stderr
    assert len(probes.stderr.strip().splitlines()) == 1
    few = _cli("design", "--robot", one_reflector, "--levels", "centres", "--poses", 6, "--candidates", 300,
               "--out", out)
    assert few.returncode == 2 and "Traceback" not in few.stderr
    errors = [line for line in few.stderr.splitlines() if line.startswith("fgcal: error")]
    assert len(errors) == 1 and "at least 9 poses needed" in errors[0]
    ok = _cli("design", "--robot", one_reflector, "--levels", "centres", "--poses", 15, "--candidates", 300,
              "--out", out)
    assert ok.returncode == 0, ok.stderr
    # a point at the flange origin sees nothing of the tool's orientation: named, not designed for
    assert "not identifiable" in ok.stdout and "tool.phi" in ok.stdout
    assert np.loadtxt(out, delimiter=",", skiprows=1).shape == (15, 7)


def test_candidate_pool_gives_up_when_nothing_is_reachable(puma):
    d = model_to_dict(puma)
    d["volume"] = {"min": [5000.0, 5000.0, 5000.0], "max": [5100.0, 5100.0, 5100.0]}
    far = model_from_dict(d)
    with pytest.raises(FgcalError, match="only 0 of"):
        candidate_pool(far, 50, np.random.default_rng(0), max_tries=2000)


@pytest.mark.skipif(SERIES is None, reason="the Landgraf UR10 series (shared/data/landgraf-ur10) is not beside the "
                                           "checkout: real-data design test skipped")
def test_landgraf_plan_against_random_sets():
    """Issue 15: 30 of ~1050 recorded UR10 poses, designed, against random 30-pose sets from the
    same candidates, each calibrated and verified at the held-out goals (bench/bench_design_landgraf.py
    runs it with 40 sets on 6 splits: the plan beats the median random set on 5 of 6, and 44 of
    48 plans from subsets of the poses do). The design is for the noise the calibration
    estimates, the robot's unmodelled errors (~0.25 mm per pose against the tracker's stated
    0.011 mm, taken for a ~0.017 deg joint error), so its predicted accuracy is a realistic one
    (README). The held-out error is ~90% non-geometric (~0.40 mm from all poses) and a single
    plan beats the median random set with a probability of ~0.9, so the test asserts what holds
    on split 0 with margin: the plan is predicted far better than the random sets and calibrates
    about as well as typical ones or better."""
    from fgcal.io.landgraf import read_series, series_to_datasets

    calib, held, model_dict, _ = series_to_datasets(read_series(SERIES), str(SERIES), holdout=0.3,
                                                    rng=np.random.default_rng(0))
    c = compare_on_held_out(calib, held, model_from_dict(model_dict), 30, random_sets=10,
                            rng=np.random.default_rng([0, 1]))
    decl, used, unit = c.plan.noise["poses"]
    assert unit == "mm" and decl < 0.02 and 0.2 < used < 0.3
    assert 0.012 < c.plan.noise["unmodelled joint error"][1] < 0.025  # deg; 0.0195 with joint variables
    assert c.plan.values["pred"] < np.percentile(c.plan.random_pred, 5)
    assert 0.1 < c.plan.values["pred"] < 0.25  # measured 0.170 mm; the stated noise would predict 0.008
    assert 0.35 < c.plan_mean < np.percentile(c.random_mean, 90)


def test_design_holds_the_scale_as_the_batch_on_planes_alone():
    """Contacts on three unknown tables (tests/test_scale_gauge.py's UR10): nothing fixes a length,
    and the batch holds j2.a (SCALE_REASON). The design estimates what the batch estimates: its
    parameters are the calibration's, its information over them (the planes marginalised) is the
    graph's normal equations (before, the design left the scale to its rank analysis of the pool,
    which held the tool's z offset instead)."""
    from test_scale_gauge import _tables

    from fgcal.estimation.calibrate import CalibrationOptions, build_graph
    from fgcal.estimation.gauge import SCALE_REASON
    from fgcal.estimation.noise import NoiseMode
    from fgcal.studies.design import Candidates
    from fgcal.studies.design_consistency import candidates_of
    from fgcal.studies.design_dataset import dataset_noise, with_dataset_tooling

    model, ds, _, _, q = _tables(per_plane=30)
    model = with_dataset_tooling(ds, model)  # the tables' ball
    result = calibrate(ds, model)
    assert [h["name"] for h in result.held if h["reason"] == SCALE_REASON] == ["j2.a"]
    found = dataset_noise(ds, model, NoiseMode.DECLARED)
    layout = dataset_layout(ds, model)
    prep = candidates_of(ds, model, q, layout, found)
    assert list(prep.names) == [n for n in result.names if not n.startswith("plane.")]
    graph, state, _ = build_graph(ds, model, list(prep.names), CalibrationOptions(prior="none"))
    total, _ = prep.total(np.arange(ds.n_poses))
    expected = graph.parameter_information(state)
    np.testing.assert_allclose(total, expected, rtol=1e-8, atol=1e-9 * np.abs(expected).max())

    # the base-only rule of before: the scale is left to the pool's rank analysis, which holds another
    # length than the batch's (the tool's z offset) and designs for a different set of parameters
    free = type(model.parameters())(model, tuple(n for n in model.parameters().names if not n.startswith("base.")))
    loose = Candidates.build(model, q, ds.noise, layout=layout, params=free)
    assert set(loose.dropped) - {"tool.phi", "tool.theta", "tool.psi"} == {"tool.pz"}
    assert "j2.a" in loose.names and set(loose.names) != set(prep.names)

    plan = design_from_dataset(ds, model, 45, random_sets=50, noise=found)
    assert np.isfinite(plan.values["pred"]) and plan.values["pred"] < np.median(plan.random_pred)
