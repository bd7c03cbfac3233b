import subprocess
import sys
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from conftest import random_joints

from fgcal.estimation.calibrate import calibrate
from fgcal.estimation.result import save_result
from fgcal.io.dataset_io import write_csv
from fgcal.robots.compensate import compensate
from fgcal.robots.kinematics import forward
from fgcal.robots.model import SLOT_NAMES, slots_from_file_units
from fgcal.robots.robot_file import load_model
from fgcal.robots.transforms import matrix_to_quaternion, pose_difference
from fgcal.robots.urdf import to_urdf
from fgcal.studies.simulate import SimulationSettings, simulate


@pytest.fixture(scope="module")
def calibrated(puma):
    ds, _ = simulate(puma, np.random.default_rng(95), SimulationSettings(n_poses=21))
    truth = slots_from_file_units(np.array([ds.truth[n] for n in SLOT_NAMES]))
    return calibrate(ds, puma), truth


def _urdf_fk(text, q):
    """Forward kinematics of a URDF chain, written here from the URDF conventions alone."""
    root = ET.fromstring(text)

    def origin(j):
        o = j.find("origin")
        x, y, z = (float(v) * 1000 for v in o.get("xyz").split())
        r, p, w = (float(v) for v in o.get("rpy").split())
        cr, sr, cp, sp, cw, sw = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(w), np.sin(w)
        R = np.array([[cw * cp, cw * sp * sr - sw * cr, cw * sp * cr + sw * sr],
                      [sw * cp, sw * sp * sr + cw * cr, sw * sp * cr - cw * sr],
                      [-sp, cp * sr, cp * cr]])
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, [x, y, z]
        return T

    T = np.eye(4)
    k = 0
    for j in root.findall("joint"):
        T = T @ origin(j)
        if j.get("type") == "revolute":
            c, s = np.cos(q[k]), np.sin(q[k])
            T = T @ np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])
            k += 1
    return T


def test_urdf_reproduces_the_calibrated_kinematics(puma, calibrated):
    result, _ = calibrated
    text = to_urdf(puma, result.slot_vector())
    for q in random_joints(puma, 10, seed=96):
        np.testing.assert_allclose(_urdf_fk(text, q), forward(result.slot_vector(), q)[0], atol=1e-6)
    limits = [(float(j.find("limit").get("lower")), float(j.find("limit").get("upper")))
              for j in ET.fromstring(text).findall("joint") if j.get("type") == "revolute"]
    np.testing.assert_allclose(limits, puma.joint_limits)


def _inside(puma, n, seed):
    """Well-conditioned joint sets: near a singularity (elbow straight, wrist centre on the shoulder
    axis, q5 = 0) or a joint limit, a target of the nominal robot may be out of the calibrated robot's reach."""
    from fgcal.robots.kinematics import jacobians
    q = random_joints(puma, 20 * n, seed=seed)
    J = jacobians(puma.nominal, q).pose_joints * np.array([1, 1, 1, 100, 100, 100.0])[None, :, None]
    ok = np.linalg.svd(J, compute_uv=False)[:, -1] > 50.0
    # and 5 deg inside the joint limits: the commanded configuration may not reach beyond them
    margin = np.radians(5.0)
    ok &= np.all((q > puma.joint_limits[:, 0] + margin) & (q < puma.joint_limits[:, 1] - margin), axis=1)
    return q[ok][:n]


def test_compensation_brings_the_real_robot_closer(puma, calibrated):
    result, truth = calibrated
    q_nominal = _inside(puma, 8, seed=97)
    targets = forward(puma.nominal, q_nominal)  # where the user wants the tool
    # seeded by the commanded joints: without them, targets of mixed configurations are solved in one branch
    q, pos, rot = compensate(puma, result.slot_vector(), targets, seeds=q_nominal)
    assert pos.max() < 1e-6 and rot.max() < 1e-6
    before, _ = pose_difference(forward(truth, q_nominal), targets)
    after, _ = pose_difference(forward(truth, q), targets)
    assert np.linalg.norm(after, axis=1).max() < 0.2 < np.linalg.norm(before, axis=1).min()


def test_cli_compensate_and_export(puma, calibrated, tmp_path):
    result, _ = calibrated
    save_result(result, tmp_path / "r.json")
    q = _inside(puma, 3, seed=98)
    T = forward(puma.nominal, q)
    write_csv(tmp_path / "targets.csv", ["pose", "x", "y", "z", "qw", "qx", "qy", "qz", "q1", "q2", "q3", "q4", "q5",
                                         "q6"],
              [[i + 1, *T[i, :3, 3], *matrix_to_quaternion(T[i, :3, :3]), *np.degrees(q[i])] for i in range(3)])
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "compensate", str(tmp_path / "r.json"),
                          str(tmp_path / "targets.csv"), "--out", str(tmp_path / "cmd.csv")], capture_output=True,
                         text=True)
    assert run.returncode == 0, run.stderr
    cmd = np.loadtxt(tmp_path / "cmd.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(forward(result.slot_vector(), np.radians(cmd[:, 1:]))[:, :3, 3], T[:, :3, 3], atol=1e-6)
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "export", str(tmp_path / "r.json"), "--model",
                          str(tmp_path / "m.yaml"), "--urdf", str(tmp_path / "m.urdf")], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    back = load_model(tmp_path / "m.yaml")
    np.testing.assert_allclose(forward(back.nominal, q), forward(result.slot_vector(), q), atol=1e-8)
    assert back.name == "puma560-calibrated"
