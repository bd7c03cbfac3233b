"""compensate keeps the commanded configuration, takes base-frame targets and a TCP, and writes
the reachable targets when some are not (exit status 3)."""
import subprocess
import sys

import numpy as np
import pytest
from conftest import random_joints

from fgcal.estimation.calibrate import calibrate
from fgcal.estimation.result import save_result
from fgcal.io.dataset_io import write_csv
from fgcal.robots.compensate import Frame, base_transform, compensate_targets, tcp_matrix
from fgcal.robots.kinematics import forward, jacobians
from fgcal.robots.transforms import matrix_to_quaternion
from fgcal.studies.simulate import SimulationSettings, simulate


@pytest.fixture(scope="module")
def ur10_result(ur10):
    ds, _ = simulate(ur10, np.random.default_rng(161), SimulationSettings(n_poses=15))
    return calibrate(ds, ur10)


def _commanded(model, n, seed):
    """Joint sets across the workspace, away from singularities, with the issue's example first."""
    q = random_joints(model, 30 * n, seed)
    q = np.angle(np.exp(1j * q))  # one turn: the UR's +-360 deg limits allow two
    J = jacobians(model.nominal, q).pose_joints * np.array([1, 1, 1, 100, 100, 100.0])[None, :, None]
    q = q[np.linalg.svd(J, compute_uv=False)[:, -1] > 50.0][: n - 1]
    return np.vstack([np.radians([-20, 60, -120, -30, 50, 0]), q])


def test_branch_kept_on_every_target_base_frame_and_tcp(ur10, ur10_result):
    x = ur10_result.slot_vector()
    q_cmd = _commanded(ur10, 40, seed=162)
    tcp = tcp_matrix([10.0, -20.0, 150.0], [5.0, 90.0, -30.0])
    # the user's targets: where the nominal robot would put the TCP, in the robot's base frame
    T_base = np.linalg.inv(base_transform(ur10, ur10.nominal)) @ forward(ur10.nominal, q_cmd) @ tcp
    c = compensate_targets(ur10, x, T_base, seeds=q_cmd, frame=Frame.BASE, tcp=tcp)
    assert c.reachable.all(), [r for r in c.reasons if r]
    # the issue's criterion for a 6R arm: elbow (q3) and wrist (q5) keep their signs; every joint stays close
    assert np.all(np.sign(c.q[:, [2, 4]]) == np.sign(q_cmd[:, [2, 4]]))
    assert np.degrees(np.abs(c.q - q_cmd)).max() < 3.0 and c.joint_change_deg.max() < 3.0
    # the calibrated robot puts the TCP on the target, in the instrument frame via the calibrated base
    reached = forward(x, c.q) @ tcp
    np.testing.assert_allclose(reached, base_transform(ur10, x) @ T_base, atol=1e-6)
    assert np.nanmax(c.position_error_mm) < 1e-6


def test_refuses_a_solution_off_the_commanded_branch(ur10, ur10_result):
    x = ur10_result.slot_vector()
    q_cmd = _commanded(ur10, 3, seed=163)
    T = forward(x, q_cmd)
    flipped = q_cmd.copy()
    flipped[:, 4] *= -1  # seeds on the other wrist branch: the only solution nearby is the commanded one
    c = compensate_targets(ur10, x, T, seeds=flipped)
    assert not c.reachable.any()
    assert all("leaves the commanded configuration" in r for r in c.reasons)
    assert np.isnan(c.q).all()
    # no commanded joints and no closed form for this arm (a 7-joint Panda): named, not guessed
    from pathlib import Path

    from fgcal.robots.robot_file import load_model

    panda = load_model(Path(__file__).parent / "data" / "urdf" / "panda.urdf", chain={"tip": "panda_link8"})
    T7 = forward(panda.nominal, np.zeros((3, 7)) + 0.3, chain=panda.chain)
    c = compensate_targets(panda, panda.nominal, T7)
    assert all(r.startswith("no seed joints") for r in c.reasons) and np.isnan(c.q).all()
    assert any("no closed-form IK" in note for note in c.notes)


def test_cli_partial_success_writes_the_reachable_targets(ur10, ur10_result, tmp_path):
    save_result(ur10_result, tmp_path / "r.json")
    x = ur10_result.slot_vector()
    q_cmd = _commanded(ur10, 6, seed=164)
    T = forward(x, q_cmd)
    T[[1, 4], :3, 3] += [5000.0, 0.0, 0.0]  # 5 m beyond the arm's reach
    ids = [11, 12, 13, 14, 15, 16]
    write_csv(tmp_path / "t.csv", ["pose", "x", "y", "z", "qw", "qx", "qy", "qz", "q1", "q2", "q3", "q4", "q5", "q6"],
              [[p, *T[i, :3, 3], *matrix_to_quaternion(T[i, :3, :3]), *np.degrees(q_cmd[i])] for i, p in enumerate(ids)])
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "compensate", str(tmp_path / "r.json"),
                          str(tmp_path / "t.csv"), "--out", str(tmp_path / "cmd.csv")], capture_output=True, text=True)
    assert run.returncode == 3, run.stderr
    assert "pose 12: not written" in run.stderr and "pose 15: not written" in run.stderr
    assert "2 of 6 targets not reachable" in run.stderr and "Traceback" not in run.stderr
    cmd = np.loadtxt(tmp_path / "cmd.csv", delimiter=",", skiprows=1)
    assert cmd[:, 0].tolist() == [11, 13, 14, 16]
    good = [0, 2, 3, 5]
    np.testing.assert_allclose(forward(x, np.radians(cmd[:, 1:])), T[good], atol=1e-6)
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "compensate", str(tmp_path / "r.json"),
                          str(tmp_path / "t.csv"), "--tcp", "1,2"], capture_output=True, text=True)
    assert run.returncode == 2 and "--tcp" in run.stderr


def test_puma_without_seeds_stays_in_one_branch(puma):
    from fgcal.robots.ik import BRANCHES, solve_puma_batch
    q = random_joints(puma, 200, seed=165)
    branch = BRANCHES[2]
    T = forward(puma.nominal, q)
    q_branch, ok = solve_puma_batch(puma, T, branch)
    ok &= np.array([puma.in_limits(qi)[0] if np.all(np.isfinite(qi)) else False for qi in q_branch])
    T = T[ok][:10]
    c = compensate_targets(puma, puma.nominal, T, branch=branch)
    assert c.reachable.all() and c.branch == branch
    np.testing.assert_allclose(c.q, q_branch[ok][:10], atol=1e-6)  # the nominal solution of that branch
