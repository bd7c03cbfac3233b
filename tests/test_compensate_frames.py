"""``compensate --frame base``: targets in the robot's own base frame (a URDF's base link, a DH
table's base frame at the mounting face), checked against forward kinematics computed without
fgcal (yourdfpy on the URDF; plain matrices on the DH table)."""
from pathlib import Path

import numpy as np
import plain_dh
import pytest

from fgcal.robots.compensate import Frame, base_transform, compensate_targets
from fgcal.robots.robot_file import load_model, model_from_dict, model_to_dict
from fgcal.robots.transforms import euler_zyx_trans, to_euler_zyx_trans
from fgcal.util.resources import builtin_robot_path
from fgcal.util.yamlio import read_yaml

DATA = Path(__file__).parent / "data" / "urdf"
# a tracker 2.5 m away, turned by 120 deg and tilted: the instrument frame of a dataset
PLACEMENT = euler_zyx_trans(np.radians(120.0), np.radians(3.0), np.radians(-2.0), 2500.0, -300.0, 400.0)


def _placed(model):
    """``model`` as a dataset's robot file places it: base in the instrument frame, through a file round trip."""
    x = model.nominal.copy()
    base = slice(model.slot("base.phi"), model.slot("base.pz") + 1)
    x[base] = to_euler_zyx_trans(PLACEMENT @ euler_zyx_trans(*x[base]))
    return model_from_dict(model_to_dict(model, x))


def _commands(model, n, seed):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-2.5, 2.5, size=(n, model.n_joints))
    q[:, 2] = np.sign(q[:, 2]) * np.clip(np.abs(q[:, 2]), 0.5, 2.5)  # elbow bent: away from the singularity
    q[:, 4] = np.sign(q[:, 4]) * np.clip(np.abs(q[:, 4]), 0.5, 2.5)  # wrist bent
    return q


def test_base_frame_of_a_urdf_robot_is_its_base_link():
    yourdfpy = pytest.importorskip("yourdfpy", reason="yourdfpy (test extra) computes the URDF's kinematics")
    model = load_model(DATA / "ur10_robot.urdf", chain={"tip": "tool0"})
    placed = _placed(model)
    np.testing.assert_allclose(base_transform(placed, placed.nominal), PLACEMENT, atol=1e-9)
    q_cmd = _commands(model, 12, seed=171)
    u = yourdfpy.URDF.load(str(DATA / "ur10_robot.urdf"), load_meshes=False, load_collision_meshes=False)
    targets = []
    for q in q_cmd:  # tool0 in base_link, by yourdfpy, in mm
        u.update_cfg(dict(zip(model.joint_names, q)))
        T = u.get_transform("tool0", "base_link").copy()
        T[:3, 3] *= 1000.0
        targets.append(T)
    c = compensate_targets(placed, placed.nominal, np.array(targets), seeds=q_cmd + 0.02, frame=Frame.BASE)
    assert c.reachable.all(), [r for r in c.reasons if r]
    np.testing.assert_allclose(c.q, q_cmd, atol=1e-8)


def test_base_frame_of_a_dh_table_is_the_tables_base_frame(ur10):
    """The UR10's DH table has d1 = 127.3 mm; the base frame is at the mounting face, not at d1."""
    table = read_yaml(builtin_robot_path("ur10"))
    assert model_from_dict(model_to_dict(ur10)).extra["mounting"] == ur10.extra["mounting"]
    placed = _placed(ur10)
    np.testing.assert_allclose(base_transform(placed, placed.nominal), PLACEMENT, atol=1e-9)
    q_cmd = _commands(ur10, 12, seed=172)
    # the table's own kinematics, plain matrices: the flange in the table's base frame (its base is identity)
    targets = np.array([plain_dh.fk(table["base"], table["links"], table["tool"], np.degrees(q)) for q in q_cmd])
    for model in (ur10, placed):
        c = compensate_targets(model, model.nominal, targets, seeds=q_cmd + 0.02, frame=Frame.BASE)
        assert c.reachable.all(), [r for r in c.reasons if r]
        np.testing.assert_allclose(c.q, q_cmd, atol=1e-8)
    # in the instrument frame the same targets sit where the placement puts them
    c = compensate_targets(placed, placed.nominal, PLACEMENT @ targets, seeds=q_cmd + 0.02)
    np.testing.assert_allclose(c.q, q_cmd, atol=1e-8)


def test_compensate_command_for_a_7_joint_arm(tmp_path):
    """``fgcal compensate`` on a Franka Panda result: seeds ``q1..q7`` in, ``pose,q1..q7`` out, and the
    commands bring the calibrated model to the targets, near the seeds."""
    import csv
    import subprocess
    import sys

    from fgcal.estimation.calibrate import CalibrationOptions, calibrate
    from fgcal.estimation.result import save_result
    from fgcal.measurements.dataset import Dataset, Noise
    from fgcal.measurements.pose import PoseObservations
    from fgcal.robots.model import Tooling
    from fgcal.robots.transforms import matrix_to_quaternion

    chain = {"base": "panda_link0", "tip": "panda_hand"}
    model = load_model(DATA / "panda.urdf", chain=chain)
    assert model.n_joints == 7
    rng = np.random.default_rng(5)
    lo, hi = model.joint_limits[:, 0], model.joint_limits[:, 1]
    inside = lambda n, margin: lo + margin * (hi - lo) + rng.uniform(size=(n, 7)) * (1 - 2 * margin) * (hi - lo)  # noqa: E731
    q_train = inside(40, 0.05)
    T = model.forward(model.nominal, q_train)
    ids = np.arange(1, 41)
    ds = Dataset(robot=str(DATA / "panda.urdf"), tooling=Tooling(0.0, {"F": np.zeros(3)}),
                 noise=Noise(cmm_sigma=0.01, joint_resolution=0.0, pose_position_sigma=0.01,
                             pose_orientation_sigma=float(np.degrees(1e-4))),
                 provenance={}, pose_ids=ids, joints_deg=model.joints_to_file_units(q_train), chain=chain,
                 poses=PoseObservations(ids, T[:, :3, 3] + rng.normal(0, 0.01, (40, 3)),
                                        np.array([matrix_to_quaternion(R) for R in T[:, :3, :3]])))
    result = calibrate(ds, model, CalibrationOptions())
    save_result(result, tmp_path / "result.json")
    slots = result.slot_vector(model)
    q_cmd = inside(6, 0.2)
    targets = model.forward(slots, q_cmd)
    seeds = np.degrees(q_cmd) + 0.5  # the nominal commands a user would have, half a degree off
    with open(tmp_path / "targets.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["pose", "x", "y", "z", "qw", "qx", "qy", "qz"] + [f"q{i}" for i in range(1, 8)])
        for k, (Tk, s) in enumerate(zip(targets, seeds), start=1):
            w.writerow([k, *Tk[:3, 3], *matrix_to_quaternion(Tk[:3, :3]), *s])
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "compensate", str(tmp_path / "result.json"),
                          str(tmp_path / "targets.csv"), "--frame", "instrument", "--out", str(tmp_path / "cmd.csv")],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    rows = list(csv.reader(open(tmp_path / "cmd.csv")))
    assert rows[0] == ["pose"] + [f"q{i}" for i in range(1, 8)]
    got = np.radians(np.array([[float(v) for v in r[1:]] for r in rows[1:]]))
    # Seven joints for six constraints: not q_cmd itself but a solution near the seed that reaches the target.
    reached = model.forward(slots, got)
    np.testing.assert_allclose(reached[:, :3, 3], targets[:, :3, 3], atol=1e-6)
    np.testing.assert_allclose(reached[:, :3, :3], targets[:, :3, :3], atol=1e-9)
    assert np.max(np.abs(np.degrees(got) - seeds)) < 10.0
