"""``compensate`` without seed joints: the UR's closed-form IK of the nominal model (branch kept), a
start for the numerical IK (``--seed-joints``, any arm), and position-only targets (a reflector's)."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fgcal.estimation.calibrate import calibrate
from fgcal.estimation.result import save_result
from fgcal.io.dataset_io import write_csv
from fgcal.robots.compensate import compensate_targets
from fgcal.robots.ik import BRANCHES
from fgcal.robots.ik_ur import solve_ur_batch, ur_branch_of
from fgcal.robots.transforms import matrix_to_quaternion
from fgcal.studies.simulate import SimulationSettings, simulate


@pytest.fixture(scope="module")
def ur10_result(ur10):
    ds, _ = simulate(ur10, np.random.default_rng(281), SimulationSettings(n_poses=15))
    return calibrate(ds, ur10)


def _nominal_with(model, x):
    """The nominal links with the calibrated base and tool: what the user's nominal commands assume."""
    out = model.nominal.copy()
    for part in ("base", "tool"):
        s = slice(model.slot(f"{part}.phi"), model.slot(f"{part}.pz") + 1)
        out[s] = x[s]
    return out


def _commands(n, seed):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-np.pi, np.pi, size=(n, 6))
    for j in (2, 4):  # elbow and wrist bent: away from the singularities
        q[:, j] = np.sign(q[:, j]) * np.clip(np.abs(q[:, j]), 0.4, 2.7)
    return q


def test_ur_closed_form_recovers_every_branch(ur10):
    q = _commands(300, 282)
    T = ur10.forward(ur10.nominal, q)
    own = ur_branch_of(ur10, q)
    for branch in BRANCHES:
        sol, ok = solve_ur_batch(ur10, T, branch)
        np.testing.assert_allclose(ur10.forward(ur10.nominal, sol[ok]), T[ok], atol=1e-9)
        assert all(b == branch for b in ur_branch_of(ur10, sol[ok]))
        mine = np.array([b == branch for b in own])
        assert ok[mine].all()  # a joint set's own branch always reaches its pose, with its joints
        np.testing.assert_allclose(np.angle(np.exp(1j * (sol[mine] - q[mine]))), 0.0, atol=1e-9)


def test_cli_writes_every_ur10_target_without_seed_joints(ur10, ur10_result, tmp_path):
    """The issue's case: 5 pose targets, no seed joints (0 of 5 before); the branch is the nominal's."""
    save_result(ur10_result, tmp_path / "r.json")
    x = ur10_result.slot_vector()
    x_nom = _nominal_with(ur10, x)
    branch = BRANCHES[5]
    q = _commands(60, 283)
    q = q[[b == branch for b in ur_branch_of(ur10, q)]][:5]
    assert len(q) == 5
    T = ur10.forward(x_nom, q)  # where the nominal robot believes these commands go
    write_csv(tmp_path / "t.csv", ["pose", "x", "y", "z", "qw", "qx", "qy", "qz"],
              [[i + 1, *T[i, :3, 3], *matrix_to_quaternion(T[i, :3, :3])] for i in range(5)])
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "compensate", str(tmp_path / "r.json"),
                          str(tmp_path / "t.csv"), "--out", str(tmp_path / "cmd.csv"), "--branch", str(branch)],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert "5 of 5 joint commands" in run.stdout
    cmd = np.radians(np.loadtxt(tmp_path / "cmd.csv", delimiter=",", skiprows=1)[:, 1:])
    assert np.abs(ur10.forward(x, cmd)[:, :3, 3] - T[:, :3, 3]).max() < 1e-6  # mm
    assert all(b == branch for b in ur_branch_of(ur10, cmd, slots=x_nom))
    assert np.degrees(np.abs(np.angle(np.exp(1j * (cmd - q))))).max() < 3.0  # the nominal command's configuration
    assert np.abs(cmd - q).max() > 1e-4  # and compensated, not the nominal command itself


def test_default_branch_and_unreachable_named(ur10, ur10_result):
    x = ur10_result.slot_vector()
    q = _commands(8, 284)
    T = ur10.forward(_nominal_with(ur10, x), q)
    T[3, :3, 3] += [4000.0, 0.0, 0.0]
    c = compensate_targets(ur10, x, T)
    assert c.branch is not None and any(str(c.branch) in n for n in c.notes)
    assert not c.reachable[3] and "out of reach" in c.reasons[3]
    ok = c.reachable
    assert ok.sum() == 7
    assert all(b == c.branch for b in ur_branch_of(ur10, c.q[ok], slots=_nominal_with(ur10, x)))
    np.testing.assert_allclose(ur10.forward(x, c.q[ok]), T[ok], atol=1e-6)


def test_start_joints_and_position_only_targets(ur10, ur10_result):
    """A reflector's points: the position reached, the orientation the calibrated robot had at the seed."""
    x = ur10_result.slot_vector()
    x_nom = _nominal_with(ur10, x)
    q = _commands(6, 285)
    T = ur10.forward(x_nom, q)
    c = compensate_targets(ur10, x, T, seeds=q, position_only=np.ones(6, bool))
    assert c.reachable.all(), c.reasons
    np.testing.assert_allclose(ur10.forward(x, c.q)[:, :3, 3], T[:, :3, 3], atol=1e-6)
    np.testing.assert_allclose(ur10.forward(x, c.q)[:, :3, :3], ur10.forward(x, q)[:, :3, :3], atol=1e-9)
    assert np.isnan(c.orientation_error_deg).all()
    # without seeds: a start for the numerical IK (nominal first, then calibrated from that command)
    start = q[0] + 0.3
    targets = ur10.forward(x_nom, q[0] + np.linspace(0.0, 0.5, 4)[:, None])
    c = compensate_targets(ur10, x, targets, start=start, position_only=np.ones(4, bool))
    assert c.reachable.all(), c.reasons
    np.testing.assert_allclose(ur10.forward(x, c.q)[:, :3, 3], targets[:, :3, 3], atol=1e-6)
    c = compensate_targets(ur10, x, targets, position_only=np.ones(4, bool))
    assert not c.reachable.any() and all("--seed-joints" in r for r in c.reasons)


def test_seed_joints_on_a_7_joint_arm(tmp_path):
    """An arm without closed form: ``--seed-joints`` starts the numerical IK; every target written."""
    from fgcal.robots.robot_file import load_model

    panda = load_model(Path(__file__).parent / "data" / "urdf" / "panda.urdf", chain={"tip": "panda_link8"})
    start = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.7])
    q = start + np.random.default_rng(286).uniform(-0.4, 0.4, size=(5, 7))
    T = panda.forward(panda.nominal, q)
    c = compensate_targets(panda, panda.nominal, T, start=start)
    assert c.reachable.all(), c.reasons
    np.testing.assert_allclose(panda.forward(panda.nominal, c.q), T, atol=1e-6)
    assert panda.in_limits(c.q).all()


def test_ur_urdf_and_imported_factory_file_without_seed_joints(ur10):
    """A UR URDF (its rebuilt frames have other twist signs) and a model imported from a calibrated
    kinematics file (off the UR structure): the closed form through a UR table (ideal, then refined)."""
    from fgcal.robots.ik_ur import ur_proxy
    from fgcal.robots.robot_file import load_model
    from fgcal.robots.ur_kinematics import model_from_kinematics, ur_kinematics

    urdf = load_model(Path(__file__).parent / "data" / "urdf" / "ur10_robot.urdf", chain={"tip": "tool0"})
    rng = np.random.default_rng(287)
    x = ur10.nominal.copy()
    for n in ur10.identifiable_names():
        if not n.startswith(("base.", "tool.")):
            x[ur10.slot(n)] += rng.normal(0.0, np.radians(0.1) if ur10.slot_is_angle[ur10.slot(n)] else 1.0)
    factory = model_from_kinematics(ur_kinematics(ur10, x), name="ur10-factory")
    assert ur_proxy(factory) is None and ur_proxy(factory, ideal=True) is not None  # off the structure
    for model in (urdf, factory):
        proxy, px = ur_proxy(model, ideal=True)
        q = _commands(80, 288)
        branch = BRANCHES[6]
        q = q[[b == branch for b in ur_branch_of(proxy, q, slots=px)]][:6]
        T = model.forward(model.nominal, q)
        c = compensate_targets(model, model.nominal, T, branch=branch)
        assert c.reachable.all(), c.reasons
        np.testing.assert_allclose(model.forward(model.nominal, c.q), T, atol=1e-6)
        np.testing.assert_allclose(np.angle(np.exp(1j * (c.q - q))), 0.0, atol=1e-7)  # the commanded joints


def test_cli_position_only_targets_and_a_bad_start(ur10, ur10_result, tmp_path):
    save_result(ur10_result, tmp_path / "r.json")
    x = ur10_result.slot_vector()
    q = _commands(4, 289)
    p = ur10.forward(_nominal_with(ur10, x), q)[:, :3, 3]
    write_csv(tmp_path / "t.csv", ["pose", "x", "y", "z", "q1", "q2", "q3", "q4", "q5", "q6"],
              [[i + 1, *p[i], *np.degrees(q[i])] for i in range(4)])
    cli = [sys.executable, "-m", "fgcal.cli", "compensate", str(tmp_path / "r.json"), str(tmp_path / "t.csv")]
    run = subprocess.run(cli + ["--out", str(tmp_path / "c.csv")], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert "4 of 4" in run.stdout and "positions only" in run.stdout
    cmd = np.radians(np.loadtxt(tmp_path / "c.csv", delimiter=",", skiprows=1)[:, 1:])
    assert np.abs(ur10.forward(x, cmd)[:, :3, 3] - p).max() < 1e-6
    run = subprocess.run(cli + ["--seed-joints", "1,2,3"], capture_output=True, text=True)
    assert run.returncode == 2 and "--seed-joints" in run.stderr and "6 joint values" in run.stderr
    assert "Traceback" not in run.stderr
