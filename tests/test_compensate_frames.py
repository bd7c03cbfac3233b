"""``compensate --frame base``: targets in the robot's own base frame (a URDF's base link, a DH
table's base frame at the mounting face), checked against forward kinematics computed without
fgcal (yourdfpy on the URDF; plain matrices on the DH table)."""
from pathlib import Path

import numpy as np
import pytest

import plain_dh
from fgcal.io.yamlio import read_yaml
from fgcal.io.resources import builtin_robot_path
from fgcal.robots.compensate import Frame, base_transform, compensate_targets
from fgcal.robots.robot_file import load_model, model_from_dict, model_to_dict
from fgcal.robots.transforms import euler_zyx_trans, to_euler_zyx_trans

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
