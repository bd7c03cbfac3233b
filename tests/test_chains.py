"""Chains beyond the paper's 6R arm: prismatic joints, coupled joints (FANUC's J2/J3), DH and
modified-DH tables; FK against plain matrices written here, Jacobians against differences,
calibration of simulated data against the truth."""
import math

import numpy as np
import pytest
from plain_dh import Rx, Rz, Trans, euler

from fgcal.estimation.calibrate import CalibrationOptions, calibrate
from fgcal.measurements.dataset import Noise
from fgcal.robots.model import ParameterSet
from fgcal.robots.robot_file import model_from_dict
from fgcal.studies.simulate import SimulationSettings, simulate

TOOLING = {"radius": 6.35, "balls": {"A": [60, 0, 30], "B": [0, 60, 30], "C": [-60, 0, 30], "D": [0, -90, 30]}}

# A 6-axis arm whose third joint slides along its axis (a prismatic link), in the paper's rows.
PRISMATIC = {
    "format": "fgcal-robot/1", "name": "slider",
    "base": {"phi": 0, "theta": 0, "psi": 0, "px": 0, "py": 0, "pz": 300},
    "links": [{"theta": 0, "d": 0, "a": 100, "alpha": 90}, {"theta": 0, "d": 0, "a": 400, "alpha": 0},
              {"theta": 20, "d": 50, "a": 30, "alpha": 90}, {"theta": 0, "d": 300, "a": 0, "alpha": -90},
              {"theta": 0, "d": 0, "a": 0, "alpha": 90}],
    "tool": {"phi": 0, "theta": 0, "psi": 0, "px": 0, "py": 0, "pz": 120},
    "joints": [{"name": "q1"}, {"name": "q2"}, {"name": "slide", "type": "prismatic"}, {"name": "q4"},
               {"name": "q5"}, {"name": "q6"}],
    "joint_limits": [[-170, 170], [-60, 120], [0, 300], [-180, 180], [-110, 110], [-180, 180]],
    "tooling": TOOLING,
}

# FANUC-style: the J3 reading is measured from the horizontal, so the J3 joint angle is J3 + J2.
COUPLED = {
    "format": "fgcal-robot/1", "name": "fanuc-like", "convention": "dh",
    "base": {"phi": 0, "theta": 0, "psi": 0, "px": 0, "py": 0, "pz": 0},
    "links": [{"theta": 0, "d": 450, "a": 150, "alpha": -90}, {"theta": -90, "d": 0, "a": 600, "alpha": 0},
              {"theta": 0, "d": 0, "a": 200, "alpha": -90}, {"theta": 0, "d": 640, "a": 0, "alpha": 90},
              {"theta": 0, "d": 0, "a": 0, "alpha": -90}, {"theta": 0, "d": 100, "a": 0, "alpha": 0}],
    "tool": {"phi": 0, "theta": 0, "psi": 0, "px": 0, "py": 0, "pz": 0},
    "joint_limits": [[-170, 170], [-90, 140], [-160, 200], [-190, 190], [-120, 120], [-360, 360]],
    "coupling": {"matrix": [[1, 0, 0, 0, 0, 0], [0, 1, 0, 0, 0, 0], [0, 1, 1, 0, 0, 0],
                            [0, 0, 0, 1, 0, 0], [0, 0, 0, 0, 1, 0], [0, 0, 0, 0, 0, 1]]},
    "tooling": TOOLING,
}


def _plain(data, q_file):
    """FK with plain 4x4 matrices, straight from the table (prismatic: Tz(q + d); coupling applied)."""
    types = [j.get("type", "revolute") for j in data.get("joints", [{}] * len(q_file))]
    v = np.asarray(q_file, dtype=float)
    if "coupling" in data:
        v = np.array(data["coupling"]["matrix"], dtype=float) @ v
    T = euler(data["base"])
    rows = data["links"]
    for i, row in enumerate(rows):
        if types[i] == "prismatic":
            L = Rz(math.radians(row["theta"])) @ Trans(0, 0, row["d"] + v[i])
        else:
            L = Rz(math.radians(row["theta"] + v[i])) @ Trans(0, 0, row["d"])
        T = T @ L @ Trans(row["a"], 0, 0) @ Rx(math.radians(row["alpha"]))
    if len(rows) < len(v):
        T = T @ (Trans(0, 0, v[-1]) if types[-1] == "prismatic" else Rz(math.radians(v[-1])))
    return T @ euler(data["tool"])


def _joint_sets(model, n, seed):
    rng = np.random.default_rng(seed)
    return rng.uniform(model.joint_limits[:, 0], model.joint_limits[:, 1], size=(n, model.n_joints))


@pytest.mark.parametrize("data", [PRISMATIC, COUPLED], ids=["prismatic", "coupled"])
def test_forward_kinematics_matches_plain_matrices(data):
    model = model_from_dict(data)
    q = _joint_sets(model, 10, 0)
    ours = model.forward(model.nominal, q)
    for qi, T in zip(model.joints_to_file_units(q), ours):
        assert np.allclose(T, _plain(data, qi), atol=1e-9)


@pytest.mark.parametrize("data", [PRISMATIC, COUPLED], ids=["prismatic", "coupled"])
def test_jacobians_match_central_differences(data):
    model = model_from_dict(data)
    chain = model.chain
    q = _joint_sets(model, 3, 1)
    x = model.nominal
    offsets = np.array([[60.0, 0, 30], [0, 0, 0]])
    jac = chain.jacobians(x, q, offsets)
    h = 1e-6
    for j in range(model.n_joints):
        dq = np.zeros(model.n_joints)
        dq[j] = h
        num = (chain.jacobians(x, q + dq, offsets).points - chain.jacobians(x, q - dq, offsets).points) / (2 * h)
        assert np.allclose(jac.point_joints[..., j], num, atol=1e-5)
    for s in range(len(x)):
        dx = np.zeros(len(x))
        dx[s] = h
        num = (chain.jacobians(x + dx, q, offsets).points - chain.jacobians(x - dx, q, offsets).points) / (2 * h)
        assert np.allclose(jac.point_slots[..., s], num, atol=1e-5)


def test_prismatic_joint_parameters():
    model = model_from_dict(PRISMATIC)
    names = model.identifiable_names()
    # A sliding axis has a direction but no position: fewer parameters than a revolute one (4R + 2P + 6).
    assert len(names) == 4 * 5 + 2 + 6
    assert "slide.d" in names  # the slider's zero offset
    assert model.rule_exceptions  # and the rank check says which rule candidates it dropped


def test_mdh_table_is_the_same_robot():
    """Craig's modified DH of the PUMA 560 gives the same kinematics as its standard DH."""
    dh = {"format": "fgcal-robot/1", "name": "puma-dh", "convention": "dh",
          "base": {"phi": 0, "theta": 0, "psi": 0, "px": 0, "py": 0, "pz": 0},
          "links": [{"theta": 0, "d": 0, "a": 0, "alpha": -90}, {"theta": 0, "d": 0, "a": 431.8, "alpha": 0},
                    {"theta": 0, "d": 150.05, "a": 20.3, "alpha": -90}, {"theta": 0, "d": 431.8, "a": 0, "alpha": 90},
                    {"theta": 0, "d": 0, "a": 0, "alpha": -90}, {"theta": 0, "d": 0, "a": 0, "alpha": 0}],
          "tool": {"phi": 0, "theta": 0, "psi": 0, "px": 0, "py": 0, "pz": 0},
          "joint_limits": [[-160, 160], [-45, 225], [-225, 45], [-110, 170], [-100, 100], [-266, 266]]}
    # Row i of Craig's table: alpha_{i-1}, a_{i-1}, then theta_i, d_i.
    mdh = dict(dh, name="puma-mdh", convention="mdh",
               links=[{"a": 0, "alpha": 0, "theta": 0, "d": 0}, {"a": 0, "alpha": -90, "theta": 0, "d": 0},
                      {"a": 431.8, "alpha": 0, "theta": 0, "d": 150.05},
                      {"a": 20.3, "alpha": -90, "theta": 0, "d": 431.8}, {"a": 0, "alpha": 90, "theta": 0, "d": 0},
                      {"a": 0, "alpha": -90, "theta": 0, "d": 0}])
    a, b = model_from_dict(dh), model_from_dict(mdh)
    q = _joint_sets(a, 10, 2)
    # MDH puts the tool at joint 6's frame, standard DH at the frame after link 6: same here (a6 = d6 = 0).
    assert np.allclose(a.forward(a.nominal, q), b.forward(b.nominal, q), atol=1e-9)


@pytest.mark.parametrize("data", [PRISMATIC, COUPLED], ids=["prismatic", "coupled"])
def test_calibrates_to_the_truth(data):
    model = model_from_dict(data)
    ds, _ = simulate(model, np.random.default_rng(3), SimulationSettings(n_poses=40, noise=Noise(0.01, 0.0)))
    result = calibrate(ds, model, CalibrationOptions())
    truth = np.array([ds.truth[n] for n in result.names])
    err = result.estimate - truth
    chi2 = err @ np.linalg.solve(result.covariance, err)
    assert chi2 / len(err) < 2.5, chi2
    assert result.converged


def test_verify_position_only_reports_point_errors():
    """A single tracker reflector: verify reports point errors and no orientation (DESIGN.md 6)."""
    from dataclasses import replace

    from fgcal.estimation.verification import verify
    from fgcal.robots.model import Tooling
    from fgcal.robots.robot_file import load_model

    model = replace(load_model("ur10"), tooling=Tooling(0.0, {"R": np.array([10.0, 20.0, 80.0])}))
    settings = SimulationSettings(n_poses=40, n_balls=1, levels=("centres",), noise=Noise(0.01, 0.0))
    train, _ = simulate(model, np.random.default_rng(4), settings)
    truth = model.slots_from_file_units(np.array([train.truth[n] for n in model.slot_names]))
    test, _ = simulate(model, np.random.default_rng(5), settings, truth=truth)
    result = calibrate(train, model, CalibrationOptions())
    report = verify(result, test, model)
    d = report.to_dict()
    assert d["reference"] == "measured points" and d["orientation_deg"] is None
    assert d["n_poses"] == test.n_poses
    assert d["truth"]["position_mm"]["rms"] < 0.05 < d["truth"]["before"]["position_mm"]["rms"]
    # the measured-point error is the truth error plus the instrument's noise (0.01 mm per axis)
    assert abs(d["position_mm"]["rms"] ** 2 - d["truth"]["position_mm"]["rms"] ** 2 - 3 * 0.01**2) < 2e-4


def test_gtsam_engine_and_export_give_the_batch_solution(puma):
    """`--engine gtsam` (GTSAM's own optimiser on to_gtsam's graph) ends where the batch solve ends."""
    import gtsam

    import factors as fx
    from fgcal.estimation.calibrate import to_gtsam

    ds, _ = simulate(puma, np.random.default_rng(11), SimulationSettings(n_poses=8))
    batch = calibrate(ds, puma, CalibrationOptions())
    other = calibrate(ds, puma, CalibrationOptions(engine="gtsam"))
    assert other.names == batch.names
    assert np.max(np.abs(other.estimate - batch.estimate) / batch.sigma) < 1e-3
    assert np.allclose(other.covariance, batch.covariance, rtol=1e-3, atol=0)
    graph, values, names, pose_ids = to_gtsam(ds, puma)
    assert names == batch.names and len(pose_ids) == ds.n_poses
    solved = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    theta = solved.atVector(fx.theta_key())
    est = np.where([u == "deg" for u in (p.unit for p in batch.parameters)], np.degrees(theta), theta)
    declared = calibrate(ds, puma, CalibrationOptions(noise="declared", outliers="none"))  # to_gtsam's noise
    assert np.max(np.abs(est - declared.estimate) / declared.sigma) < 1e-3


def test_ballbar_only_dataset_calibrates_with_its_pivot(puma, tmp_path):
    """A telescoping ballbar from an unknown pivot to one tool ball: the world origin is the pivot, so
    the base's translation is the pivot (estimated); what distances cannot see (the base's rotation about
    the pivot, the tool's orientation) is held and named."""
    from fgcal.estimation.verification import verify
    from fgcal.io.dataset_io import load_dataset, save_dataset

    settings = SimulationSettings(n_poses=60, n_balls=1, levels=("distances",), noise=Noise(0.005, 0.0))
    train, _ = simulate(puma, np.random.default_rng(21), settings)
    save_dataset(train, tmp_path / "bar")
    train = load_dataset(tmp_path / "bar")  # distances.csv round trip
    assert train.levels() == ["distances"] and len(train.distances) == train.n_poses
    result = calibrate(train, puma, CalibrationOptions())
    held = {h["name"] for h in result.held}
    assert {"base.phi", "base.theta", "base.psi"} <= held
    assert not held & {"base.px", "base.py", "base.pz"}  # the pivot is estimated
    truth = np.array([train.truth[n] for n in result.names])
    z = (result.estimate - truth) / result.sigma
    assert np.sqrt(np.mean(z**2)) < 2.0, z
    truth_slots = puma.slots_from_file_units(np.array([train.truth[n] for n in puma.slot_names]))
    test, _ = simulate(puma, np.random.default_rng(22), settings, truth=truth_slots)
    d = verify(result, test, puma).to_dict()
    assert d["reference"] == "measured ballbar lengths" and d["orientation_deg"] is None
    assert d["truth"]["position_mm"]["rms"] < 0.02 < d["before"]["position_mm"]["rms"]


def test_export_writes_the_identified_deltas(puma, tmp_path):
    import csv
    import subprocess
    import sys

    from fgcal.estimation.result import save_result

    ds, _ = simulate(puma, np.random.default_rng(12), SimulationSettings(n_poses=10))
    result = calibrate(ds, puma, CalibrationOptions(exclude=("j2.beta",)))
    save_result(result, tmp_path / "r.json")
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "export", str(tmp_path / "r.json"), "--deltas",
                          str(tmp_path / "d.csv")], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    with open(tmp_path / "d.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["name"] for r in rows[:len(result.parameters)]] == result.names
    for r, p in zip(rows, result.parameters):
        assert float(r["delta"]) == pytest.approx(p.estimate - p.nominal, abs=1e-12)
        assert float(r["sigma"]) == pytest.approx(p.sigma)
    assert len(rows) == len(result.parameters) + len(result.held)


@pytest.mark.parametrize("engine", ["isam2", "ekf", "ukf"])
def test_online_engines_take_a_ballbar_and_a_prismatic_arm(puma, engine):
    """Every engine accepts ballbar lengths and a chain with a prismatic joint and ends at the batch
    solve of the same poses (within 0.1 sigma). A ballbar's pivot is unknown at the start, so the
    running estimate refuses most lengths until the final smoothing judges them again."""
    from fgcal.online.engines import make_engine, pose_records

    cases = [(puma, SimulationSettings(n_poses=40, n_balls=1, levels=("distances",), noise=Noise(0.005, 0.01))),
             (model_from_dict(PRISMATIC), SimulationSettings(n_poses=30, levels=("centres",), noise=Noise(0.01, 0.01)))]
    for model, settings in cases:
        ds, _ = simulate(model, np.random.default_rng(31), settings)
        batch = calibrate(ds, model, CalibrationOptions(prior="weak"))
        e = make_engine(engine, ds, model, names=batch.names)
        reports = [e.update(rec) for rec in pose_records(ds, model=model)]
        if "centres" in settings.levels:
            assert sum(r.accepted for r in reports) >= 0.9 * len(reports), [r.reason for r in reports if not r.accepted]
        e.finish()
        theta, _ = e.estimate()
        est = ParameterSet(model, tuple(batch.names)).to_file_units(theta)
        assert np.max(np.abs(est - batch.estimate) / batch.sigma) < 0.1


def test_design_from_a_ballbar_dataset(puma):
    """`design --dataset` plans for a ballbar (linearised with the pivot fitted to the lengths): the plan
    predicts better than the median random set of the same size from the same candidates."""
    from fgcal.studies.design_dataset import design_from_dataset

    settings = SimulationSettings(n_poses=200, n_balls=1, levels=("distances",), noise=Noise(0.005, 0.01))
    ds, _ = simulate(puma, np.random.default_rng(41), settings)
    plan = design_from_dataset(ds, puma, 40, random_sets=30, rng=np.random.default_rng(1))
    assert plan.levels == ("distances",) and len(plan.pose_ids) == 40
    assert set(plan.pose_ids.tolist()) <= set(ds.pose_ids.tolist())
    assert plan.values["pred"] < np.median(plan.random_pred)


@pytest.mark.parametrize("kind", ["6R", "7R", "prismatic", "coupled_with_tool_offset"])
def test_single_pose_kinematics_match_the_operation_walk(kind):
    """One joint set goes through the scan of 4x4 operation matrices (fgcal.robots.single_pose);
    its pose, points and every Jacobian equal those of the operation-by-operation walk (which
    a batch of two poses takes), to rounding, and the Jacobians equal central differences."""
    from fgcal.robots.kinematics import Chain
    from fgcal.robots.single_pose import jacobians_one

    rng = np.random.default_rng(31)
    chain = {"6R": lambda: Chain(("revolute",) * 6), "7R": lambda: Chain(("revolute",) * 7),
             "prismatic": lambda: Chain(("revolute", "revolute", "prismatic", "revolute", "revolute", "revolute")),
             "coupled_with_tool_offset": lambda: Chain(
                 ("revolute",) * 6, joint_map=np.eye(6) + 0.3 * np.eye(6, k=1), joint_offset=rng.normal(size=6),
                 tool_offset=np.array([[0, -1, 0, 5], [1, 0, 0, 6], [0, 0, 1, 7], [0, 0, 0, 1.0]]))}[kind]()
    for _ in range(4):
        x = rng.normal(size=chain.n_slots) * 200
        x[:3] = rng.normal(size=3)
        q = rng.normal(size=chain.n_joints)
        offsets = rng.normal(size=(3, 3)) * 60
        one = jacobians_one(chain, x, q, offsets)
        walk = chain.jacobians_walk(x, q[None], offsets)
        assert chain.jacobians(x, q[None], offsets).T.tobytes() == one.T.tobytes()  # one pose takes the scan
        for field in ("T", "pose_slots", "pose_joints", "points", "point_slots", "point_joints"):
            a, b = getattr(one, field), getattr(walk, field)
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-11 * max(1.0, np.abs(b).max()), err_msg=field)
        h = 1e-6
        for s in rng.choice(chain.n_slots, 5, replace=False):
            dx = np.zeros(chain.n_slots)
            dx[s] = h
            diff = (jacobians_one(chain, x + dx, q, offsets).points - jacobians_one(chain, x - dx, q, offsets).points) / (2 * h)
            np.testing.assert_allclose(one.point_slots[..., s], diff, atol=1e-5 * max(1.0, np.abs(diff).max()))
        for j in range(chain.n_joints):
            dq = np.zeros(chain.n_joints)
            dq[j] = h
            diff = (jacobians_one(chain, x, q + dq, offsets).points - jacobians_one(chain, x, q - dq, offsets).points) / (2 * h)
            np.testing.assert_allclose(one.point_joints[..., j], diff, atol=1e-5 * max(1.0, np.abs(diff).max()))
