import subprocess
import sys

import numpy as np
import pytest

from fgcal.estimation.calibrate import calibrate
from fgcal.measurements.dataset import Noise
from fgcal.robots.deviations import Deviations
from fgcal.robots.kinematics import forward
from fgcal.studies.design import (
    Candidates,
    _scores,
    candidate_pool,
    design_plan,
    indices,
    pose_information,
    random_design_values,
)
from fgcal.studies.plans import ball_access
from fgcal.studies.simulate import SimulationSettings, simulate
from fgcal.studies.study import run_trial, trials_for

NOISE = Noise(0.01, 0.01)


def test_indices_of_a_known_spectrum():
    s = np.array([1.0, 2.0, 4.0])
    v = indices(np.diag(s**2), m=2, scale=np.ones(3), W=np.eye(3))
    assert v["O1"] == pytest.approx(2.0 / np.sqrt(2))
    assert v["O2"] == pytest.approx(0.25) and v["O3"] == pytest.approx(1.0)
    assert v["O4"] == pytest.approx(0.25) and v["O5"] == pytest.approx(1 / 1.75)
    assert v["pred"] == pytest.approx(np.sqrt(1 + 1 / 4 + 1 / 16))


def test_information_matches_the_estimators_covariance(puma):
    """The design's noise model is the estimator's: its predicted covariance matches a calibration's."""
    ds, _ = simulate(puma, np.random.default_rng(120), SimulationSettings(n_poses=15))
    info, usable = pose_information(puma, ds.joints_rad, NOISE)
    assert usable.all()
    predicted = np.sqrt(np.diag(np.linalg.inv(info.sum(axis=0))))
    r = calibrate(ds, puma)
    actual = r.sigma / np.where(np.array([u == "deg" for u in (p.unit for p in r.parameters)]), np.degrees(1), 1)
    ratio = actual / predicted
    assert 0.75 < np.median(ratio) < 1.3 and ratio.min() > 0.5 and ratio.max() < 2.0


def test_designed_plan_is_predicted_better_than_random(puma):
    rng = np.random.default_rng(121)
    pool = candidate_pool(puma, 600, rng)
    prepared = Candidates.build(puma, pool, NOISE)
    design = design_plan(puma, 12, pool, NOISE, index="pred", prepared=prepared)
    random_pred = [random_design_values(prepared, 12, np.random.default_rng(k))[1]["pred"] for k in range(100)]
    assert design.values["pred"] < np.percentile(random_pred, 5)
    d1 = design_plan(puma, 12, pool, NOISE, index="O1", prepared=prepared)
    assert d1.values["O1"] >= max(random_design_values(prepared, 12, np.random.default_rng(k))[1]["O1"]
                                  for k in range(100))
    ok, _, _ = ball_access(forward(puma.nominal, design.q), puma.tooling, puma.volume)
    assert np.all(ok.sum(axis=1) >= 3) and puma.in_limits(design.q).all()


def test_designed_plan_calibrates_better_than_most_random_sets():
    """The issue's test: over several truth draws, a designed 12-pose plan verifies below the 25th
    percentile of random 12-pose sets, and its predicted accuracy is within 30% of the realised."""
    trials = trials_for("design", trials=6, random_sets=30, candidates=1000, seed=5)
    rows = [run_trial(t) for t in trials if t.design in ("pred", "random")]
    random = [r["position_rms_mm"] for r in rows if r["design"] == "random"]
    designed = [r for r in rows if r["design"] == "pred"]
    realised = np.mean([r["position_rms_mm"] for r in designed])
    predicted = designed[0]["predicted_position_rms_mm"]
    assert realised < np.percentile(random, 25)
    assert abs(predicted - realised) / realised < 0.3


def test_cli_design(tmp_path):
    out = tmp_path / "plan.csv"
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "design", "--poses", "8", "--candidates", "400",
                          "--seed", "2", "--index", "O1", "--out", str(out)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    plan = np.loadtxt(out, delimiter=",", skiprows=1)
    assert plan.shape == (8, 7) and list(plan[:, 0]) == list(range(1, 9))
    assert "predicted position error RMS" in run.stdout and "O1" in run.stdout
    bad = subprocess.run([sys.executable, "-m", "fgcal.cli", "design", "--poses", "3", "--out", str(out), "--force"],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "at least 5" in bad.stderr


def test_rank_update_scores_equal_the_direct_inverse(puma):
    """The fast ``pred`` score (Woodbury, rank-r updates) equals trace(W inv(T +- info_k)) directly."""
    from fgcal.studies.design_info import information, layout_from_access
    from fgcal.studies.design_predict import low_rank, pred_update

    pool = candidate_pool(puma, 60, np.random.default_rng(122))
    scale = Deviations().sigmas(puma.parameters().names)
    for level in ("poses", "centres"):
        info = information(puma, pool, layout_from_access(puma, pool, (level,)), NOISE)
        L = low_rank(info)
        assert L is not None and L.shape[2] == 6  # a pose moves the tool rigidly: 6 directions
        np.testing.assert_allclose(L @ np.swapaxes(L, 1, 2), info, rtol=1e-9, atol=1e-9 * np.abs(info).max())
        W = np.eye(info.shape[1])
        total = info[:20].sum(axis=0)
        direct = [-np.sqrt(np.trace(W @ np.linalg.inv(total + s * m))) for s, m in [(1.0, i) for i in info]]
        np.testing.assert_allclose(pred_update(total, L, W, 1.0, scale), direct, rtol=1e-9)
        np.testing.assert_allclose(pred_update(total, L, W, 1.0, scale), _scores(total[None] + info, scale, "pred", W),
                                   rtol=1e-9)
        direct = [-np.sqrt(np.trace(W @ np.linalg.inv(total - m))) for m in info[:20]]
        np.testing.assert_allclose(pred_update(total, L[:20], W, -1.0, scale), direct, rtol=1e-7)
