"""Accuracy statistics, per-pose flags, tolerance verdict, predicted and held-parameter errors."""
import copy

import numpy as np
import pytest
from scipy.optimize import least_squares

from fgcal.estimation.calibrate import CalibrationOptions, calibrate
from fgcal.estimation.verification import verify
from fgcal.report.accuracy import (
    accuracy_stats,
    flag_poses,
    held_parameter_cost,
    predicted_position_sigma,
    round_to_sigma,
    tolerance_verdict,
    verification_joints,
)
from fgcal.robots.kinematics import forward
from fgcal.robots.model import SLOT_NAMES, slots_from_file_units
from fgcal.studies.simulate import SimulationSettings, simulate


@pytest.fixture(scope="module")
def calibrated(puma):
    rng = np.random.default_rng(151)
    ident, _ = simulate(puma, rng, SimulationSettings(n_poses=15))
    truth = slots_from_file_units(np.array([ident.truth[n] for n in SLOT_NAMES]))
    check, _ = simulate(puma, rng, SimulationSettings(n_poses=30), truth=truth)
    result = calibrate(ident, puma, CalibrationOptions(extra=("j1.d",)))
    return result, verify(result, check, puma).to_dict()


@pytest.mark.parametrize("value,sigma,expected", [
    (431.80123, 0.01234, ("431.801", "0.012")), (5.0, 0.96, ("5.00", "0.96")), (1234.5, 123, ("1230", "120")),
    (-0.00001, 0.01, ("0.000", "0.010")), (12.3456, 1.0, ("12.3", "1.0")), (3.3, None, ("3.3", "-"))])
def test_round_to_sigma(value, sigma, expected):
    assert round_to_sigma(value, sigma) == expected


def test_accuracy_stats_against_numpy():
    rng = np.random.default_rng(152)
    vec = rng.normal(0.1, 0.05, size=(500, 3))
    e = np.linalg.norm(vec, axis=1)
    s = accuracy_stats(e, vec)
    assert s.n == 500 and s.mean == pytest.approx(e.mean()) and s.std == pytest.approx(e.std(ddof=1))
    assert s.p95 == pytest.approx(np.percentile(e, 95)) and s.max == e.max()
    assert s.rms == pytest.approx(np.sqrt(np.mean(e**2)))
    np.testing.assert_allclose(s.bias_xyz, [0.1, 0.1, 0.1], atol=0.01)  # the systematic part
    assert s.bias == pytest.approx(np.linalg.norm(vec.mean(axis=0)))


def test_verify_output_keeps_its_fields_and_adds_positions(calibrated, puma):
    _, v = calibrated
    p = v["poses"][0]
    assert {"pose", "position_mm", "orientation_deg", "before_position_mm", "before_orientation_deg"} <= set(p)
    assert np.linalg.norm(p["error_xyz_mm"]) == pytest.approx(p["position_mm"])
    assert np.linalg.norm(p["before_error_xyz_mm"]) == pytest.approx(p["before_position_mm"])
    q = puma.joints_to_internal(verification_joints(v))
    assert q.shape == (30, 6)
    np.testing.assert_allclose(forward(puma.nominal, q)[:, :3, 3] + [x["before_error_xyz_mm"] for x in v["poses"]],
                               [x["xyz_mm"] for x in v["poses"]], atol=1e-9)


def test_flags_name_the_outlier_and_the_pose_worse_than_nominal(calibrated):
    _, v = calibrated
    v = copy.deepcopy(v)
    v["poses"][4]["position_mm"] = 30 * np.median([p["position_mm"] for p in v["poses"]])
    v["poses"][7]["position_mm"] = v["poses"][7]["before_position_mm"] * 1.01
    flags = {f.pose: f.flags for f in flag_poses(v)}
    ids = [p["pose"] for p in v["poses"]]
    assert any(f.startswith("outlier") for f in flags[ids[4]])
    assert "worse than the nominal model" in flags[ids[7]]
    clean = [i for i in ids if i not in (ids[4], ids[7])]
    assert not any(f.startswith("outlier") for i in clean for f in flags[i])


def test_tolerance_verdict(calibrated):
    _, v = calibrated
    err = np.array([p["position_mm"] for p in v["poses"]])
    ok = tolerance_verdict(v, float(err.max()) * 1.01)
    assert ok.passed and ok.sentence().startswith("PASS")
    tol = float(np.median(err))
    bad = tolerance_verdict(v, tol)
    assert not bad.passed and bad.n_beyond == int((err > tol).sum())
    worst = v["poses"][int(np.argmax(err))]["pose"]
    assert bad.beyond[0] == worst and bad.sentence().startswith("FAIL") and str(worst) in bad.sentence()


def test_predicted_sigma_matches_monte_carlo(calibrated, puma):
    result, v = calibrated
    q = puma.joints_to_internal(verification_joints(v))
    predicted = predicted_position_sigma(result, q)
    rng = np.random.default_rng(153)
    draws = rng.multivariate_normal(result.estimate, result.covariance, size=2000)
    x0 = result.slot_vector()
    idx = [SLOT_NAMES.index(n) for n in result.names]
    is_deg = np.array([p.unit == "deg" for p in result.parameters])
    p0 = forward(x0, q)[:, :3, 3]
    sq = np.zeros(len(q))
    for d in draws:
        x = x0.copy()
        x[idx] = np.where(is_deg, np.radians(d), d)
        sq += np.sum((forward(x, q)[:, :3, 3] - p0) ** 2, axis=1)
    mc = np.sqrt(sq / len(draws))
    np.testing.assert_allclose(predicted, mc, rtol=0.1)


def test_held_parameter_cost(calibrated, puma):
    result, v = calibrated
    q = puma.joints_to_internal(verification_joints(v))
    # j1.d cannot be separated from base.pz: holding it costs nothing
    (cost,) = held_parameter_cost(result, q)
    assert cost.name == "j1.d" and cost.max_mm < 1e-9 and "costs nothing" in cost.sentence()
    # hold an identifiable length: what a 0.5 mm deviation leaves after re-fitting the others (nonlinear)
    r = copy.deepcopy(result)
    k = r.names.index("j2.a")
    keep = [i for i in range(len(r.parameters)) if i != k]
    r.held.append({"name": "j2.a", "value": r.parameters[k].estimate, "reason": "test"})
    r.parameters = [r.parameters[i] for i in keep]
    r.covariance = r.covariance[np.ix_(keep, keep)]
    cost = {c.name: c for c in held_parameter_cost(r, q)}["j2.a"]
    x0 = r.slot_vector()
    x_true = x0.copy()
    x_true[SLOT_NAMES.index("j2.a")] += 0.5
    target = forward(x_true, q)[:, :3, 3]
    idx = [SLOT_NAMES.index(n) for n in r.names]

    def resid(t):
        x = x0.copy()
        x[idx] = t
        return (forward(x, q)[:, :3, 3] - target).ravel()

    left = least_squares(resid, x0[idx], x_scale="jac").fun.reshape(-1, 3)
    assert cost.typical == 0.5 and cost.rms_mm > 1e-3
    assert cost.rms_mm == pytest.approx(np.sqrt(np.mean(np.sum(left**2, axis=1))), rel=0.05)


def test_verify_position_only_data(ur10):
    """A tracker reflector (one ball): verify compares the points; orientation is null."""
    from dataclasses import replace

    from fgcal.robots.model import Tooling

    model = replace(ur10, tooling=Tooling(0.0, {"R": np.array([30.0, 0.0, 50.0])}))
    rng = np.random.default_rng(154)
    settings = SimulationSettings(n_poses=40, levels=("centres",), n_balls=1)
    ident, _ = simulate(model, rng, settings)
    truth = slots_from_file_units(np.array([ident.truth[n] for n in SLOT_NAMES]))
    check, _ = simulate(model, rng, SimulationSettings(n_poses=20, levels=("centres",), n_balls=1), truth=truth)
    result = calibrate(ident, model)
    v = verify(result, check, model).to_dict()
    assert v["n_poses"] == 20 and v["orientation_deg"] is None and v["poses"][0]["orientation_deg"] is None
    # the numbers, recomputed here: calibrated point vs measured centre, and vs the true point
    q = check.joints_rad[check.row_of(check.centres.pose)]
    off = np.array([30.0, 0.0, 50.0])
    T = forward(result.slot_vector(), q)
    p_cal = T[:, :3, :3] @ off + T[:, :3, 3]
    np.testing.assert_allclose([p["position_mm"] for p in v["poses"]],
                               np.linalg.norm(check.centres.xyz - p_cal, axis=1), rtol=1e-9)
    T = forward(truth, q)
    np.testing.assert_allclose([p["truth_position_mm"] for p in v["poses"]],
                               np.linalg.norm(T[:, :3, :3] @ off + T[:, :3, 3] - p_cal, axis=1), rtol=1e-9)
    assert v["truth"]["position_mm"]["rms"] < 0.1 * v["truth"]["before"]["position_mm"]["rms"]
