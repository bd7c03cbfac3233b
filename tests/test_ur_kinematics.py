"""``export --ur-kinematics``: the kinematics file ur_description reads reproduces fgcal's forward
kinematics from base_link to tool0, checked by a URDF built in the test from the file (PyYAML and
yourdfpy, not fgcal's parser), for the built-in UR10 and an imported UR URDF, nominal and
perturbed; ``import ur-kinematics`` round trips it; the UR's URDF export uses its frame names."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from fgcal.estimation.result import save_result
from fgcal.robots.compensate import base_transform
from fgcal.robots.robot_file import load_model, save_model
from fgcal.robots.ur_kinematics import kinematics_text, ur_kinematics

yourdfpy = pytest.importorskip("yourdfpy", reason="yourdfpy (test extra) computes the URDF's kinematics")
DATA = Path(__file__).parent / "data" / "urdf"
NAMES = ("shoulder", "upper_arm", "forearm", "wrist_1", "wrist_2", "wrist_3")
JOINTS = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint")
PI = repr(np.pi)


def _origin(e) -> str:
    return f'<origin xyz="{e["x"]!r} {e["y"]!r} {e["z"]!r}" rpy="{e["roll"]!r} {e["pitch"]!r} {e["yaw"]!r}"/>'


def description_urdf(kinematics: dict) -> str:
    """The chain ur_description's ur_macro.xacro builds from a kinematics file (no meshes)."""
    k = kinematics["kinematics"]
    out = ['<robot name="ur">', '<link name="base_link"/>', '<link name="base_link_inertia"/>',
           '<joint name="base_link-base_link_inertia" type="fixed"><parent link="base_link"/>'
           f'<child link="base_link_inertia"/><origin xyz="0 0 0" rpy="0 0 {PI}"/></joint>']
    parent = "base_link_inertia"
    for name, joint in zip(NAMES, JOINTS, strict=True):
        child = f"{name}_link"
        out += [f'<link name="{child}"/>', f'<joint name="{joint}" type="revolute"><parent link="{parent}"/>'
                f'<child link="{child}"/>{_origin(k[name])}<axis xyz="0 0 1"/>'
                '<limit lower="-6.3" upper="6.3" effort="1" velocity="1"/></joint>']
        parent = child
    out += ['<link name="flange"/>', '<link name="tool0"/>',
            '<joint name="wrist_3-flange" type="fixed"><parent link="wrist_3_link"/><child link="flange"/>'
            f'<origin xyz="0 0 0" rpy="0 {-np.pi / 2!r} {-np.pi / 2!r}"/></joint>',
            '<joint name="flange-tool0" type="fixed"><parent link="flange"/><child link="tool0"/>'
            f'<origin xyz="0 0 0" rpy="{np.pi / 2!r} 0 {np.pi / 2!r}"/></joint>', "</robot>"]
    return "\n".join(out)


def _matrix(e) -> np.ndarray:
    """``Trans(x, y, z) Rz(yaw) Ry(pitch) Rx(roll)`` (mm) written out in numpy."""
    def R(axis, a):
        c, s = np.cos(a), np.sin(a)
        return {0: np.array([[1, 0, 0], [0, c, -s], [0, s, c]]), 1: np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
                2: np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]
    T = np.eye(4)
    T[:3, :3] = R(2, e["yaw"]) @ R(1, e["pitch"]) @ R(0, e["roll"])
    T[:3, 3] = 1000.0 * np.array([e["x"], e["y"], e["z"]])
    return T


def description_forward(text: str, q, tmp_path) -> np.ndarray:
    """tool0 in base_link (N, 4, 4; mm) by yourdfpy on the URDF built from the file ``text``."""
    kinematics = yaml.safe_load(text)
    path = tmp_path / "description.urdf"
    path.write_text(description_urdf(kinematics))
    u = yourdfpy.URDF.load(str(path), load_meshes=False, load_collision_meshes=False)
    out = []
    for qi in q:
        u.update_cfg(dict(zip(JOINTS, qi, strict=True)))
        T = u.get_transform("tool0", "base_link").copy()
        T[:3, 3] *= 1000.0
        out.append(T)
    return np.array(out)


def fgcal_forward(model, x, q, urdf_base: bool) -> np.ndarray:
    """fgcal's calibrated tool frame in ur_description's base_link (mm): the robot's own base frame is
    the UR's Base (base_link_inertia, Rz(pi) of base_link) for the table, base_link for the URDF."""
    flip = np.diag([-1.0, -1.0, 1.0, 1.0])
    own = np.linalg.inv(base_transform(model, x)) @ model.forward(x, q)
    return own if urdf_base else flip @ own


MODELS = {"ur10": ("ur10", None, False), "ur10-urdf": (DATA / "ur10_robot.urdf", {"tip": "tool0"}, True)}


def _perturbed(model, seed, tool=True):
    rng = np.random.default_rng(seed)
    x = model.nominal.copy()
    names = model.identifiable_names()
    if not tool:
        names = [n for n in names if not n.startswith("tool.")]
    for n in names:
        i = model.slot(n)
        x[i] += rng.normal(0.0, np.radians(0.2) if model.slot_is_angle[i] else 2.0)
    return x


@pytest.mark.parametrize("which", sorted(MODELS))
@pytest.mark.parametrize("perturb", ["nominal", "links", "all"])
def test_kinematics_file_reproduces_fgcal_base_link_to_tool0(which, perturb, tmp_path):
    robot, chain, urdf_base = MODELS[which]
    model = load_model(robot, chain=chain)
    x = model.nominal if perturb == "nominal" else _perturbed(model, 271, tool=perturb == "all")
    q = np.random.default_rng(272).uniform(-np.pi, np.pi, size=(25, 6))
    text = kinematics_text(ur_kinematics(model, x))
    tcp = _matrix(yaml.safe_load(text)["fgcal"]["tool_in_tool0"])
    ours = fgcal_forward(model, x, q, urdf_base)
    theirs = description_forward(text, q, tmp_path)
    assert np.abs(theirs @ tcp - ours).max() < 1e-6  # mm
    if perturb != "all":  # nothing of the tool moved: tool0 is fgcal's tool frame itself
        np.testing.assert_allclose(tcp, np.eye(4), atol=1e-9)
        assert np.abs(theirs - ours).max() < 1e-6
    else:
        assert np.abs(theirs - ours).max() > 0.1  # the TCP is needed: the check can fail
    # the corrected chain: no origin metres away (ur_calibration's point), the nominal is the UR10's DH
    k = yaml.safe_load(text)["kinematics"]
    assert max(np.linalg.norm([k[n][c] for c in "xyz"]) for n in NAMES) < 0.7
    if perturb == "nominal":
        # O_k = Tx(a_{k-1}) Rx(alpha_{k-1}) Rz(theta_k) Tz(d_k) of the UR10's DH table (m, rad)
        a, d = [0, -0.612, -0.5723, 0, 0], [0.1273, 0, 0, 0.163941, 0.1157, 0.0922]
        alpha = np.radians([90, 0, 0, 90, -90])
        for i, n in enumerate(NAMES):
            T = np.eye(4)
            if i:
                T[:3, :3] = _matrix({"x": 0, "y": 0, "z": 0, "roll": alpha[i - 1], "pitch": 0, "yaw": 0})[:3, :3]
                T[0, 3] = 1000 * a[i - 1]
            T = T @ _matrix({"x": 0, "y": 0, "z": d[i], "roll": 0, "pitch": 0, "yaw": 0})
            np.testing.assert_allclose(_matrix(k[n]), T, atol=2e-8, err_msg=n)


def test_import_round_trip_and_cli(ur10, tmp_path):
    """export -> import ur-kinematics -> export: the same chain; the imported file is a model fgcal reads."""
    from fgcal.estimation.calibrate import calibrate
    from fgcal.studies.simulate import SimulationSettings, simulate

    ds, _ = simulate(ur10, np.random.default_rng(274), SimulationSettings(n_poses=12))
    result = calibrate(ds, ur10)
    save_result(result, tmp_path / "r.json")
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "export", str(tmp_path / "r.json"), "--ur-kinematics",
                          str(tmp_path / "k.yaml"), "--urdf", str(tmp_path / "r.urdf")], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    text = (tmp_path / "k.yaml").read_text()
    x = result.slot_vector(ur10)
    q = np.random.default_rng(275).uniform(-np.pi, np.pi, size=(10, 6))
    tcp = _matrix(yaml.safe_load(text)["fgcal"]["tool_in_tool0"])
    assert np.abs(description_forward(text, q, tmp_path) @ tcp - fgcal_forward(ur10, x, q, False)).max() < 1e-6
    assert yaml.safe_load(text)["kinematics"]["hash"].startswith("fgcal_")
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "export", str(tmp_path / "r.json"), "--ur-kinematics",
                          str(tmp_path / "k2.yaml"), "--ur-hash", "calib_42"], capture_output=True, text=True)
    assert run.returncode == 0 and yaml.safe_load((tmp_path / "k2.yaml").read_text())["kinematics"]["hash"] == "calib_42"
    # the URDF of the UR10: ur_description's names, base_link at the mounting face
    u = yourdfpy.URDF.load(str(tmp_path / "r.urdf"), load_meshes=False, load_collision_meshes=False)
    assert tuple(u.actuated_joint_names) == JOINTS and "base_link_inertia" in u.link_map
    for qi in q[:3]:
        u.update_cfg(dict(zip(JOINTS, qi, strict=True)))
        T = u.get_transform("tool", "world").copy()
        T[:3, 3] *= 1000
        np.testing.assert_allclose(T, ur10.forward(x, qi)[0], atol=1e-9)
        B = u.get_transform("base_link", "world").copy()
        B[:3, 3] *= 1000
        np.testing.assert_allclose(B, base_transform(ur10, x) @ np.diag([-1.0, -1.0, 1.0, 1.0]), atol=1e-9)
    # import the file: a robot model with the UR's joint names; its base_link -> tool0 is the file's
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "import", "ur-kinematics", str(tmp_path / "k.yaml"),
                          str(tmp_path / "m.yaml"), "--like", "ur10"], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    imported = load_model(tmp_path / "m.yaml")
    assert imported.joint_names == JOINTS and imported.tooling is not None
    np.testing.assert_allclose(fgcal_forward(imported, imported.nominal, q, True),
                               description_forward(text, q, tmp_path), atol=1e-9)
    again = kinematics_text(ur_kinematics(imported, imported.nominal, hash="h"))
    np.testing.assert_allclose(description_forward(again, q, tmp_path), description_forward(text, q, tmp_path),
                               atol=1e-9)
    k1, k2 = yaml.safe_load(text)["kinematics"], yaml.safe_load(again)["kinematics"]
    for n in NAMES:  # the same origins, not only the same chain
        np.testing.assert_allclose(_matrix(k2[n]), _matrix(k1[n]), atol=1e-9, err_msg=n)
    # the factory hash is carried by an export of the imported model
    save_model(imported, tmp_path / "m2.yaml")
    assert load_model(tmp_path / "m2.yaml").extra["ur_kinematics"]["hash"] == k1["hash"]


def test_import_refuses_a_broken_file(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("kinematics:\n  shoulder: {x: 0, y: 0, z: 127.3, roll: 0, pitch: 0, yaw: 0}\n")
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "import", "ur-kinematics", str(bad),
                          str(tmp_path / "m.yaml")], capture_output=True, text=True)
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert "kinematics.shoulder" in run.stderr and "metres" in run.stderr


def test_urdf_export_of_a_table_says_which_frame_base_link_is(puma):
    from fgcal.robots.urdf import to_urdf

    text = to_urdf(puma, puma.nominal)
    assert "base_link is the robot's own base frame" in text and 'rpy="-0.0' not in text and '"-0.0 ' not in text


def test_urdf_export_names_joints_as_the_data_were_imported(puma, tmp_path):
    """A robot without joint names of its own exports the joint columns of ``import csv --joints``."""
    import xml.etree.ElementTree as ET

    from conftest import random_joints

    from fgcal.io.dataset_io import write_csv

    rng = np.random.default_rng(276)
    q = random_joints(puma, 40, 277)
    p = puma.forward(puma.nominal, q)[:, :3, :] @ np.array([0.0, 0.0, 60.0, 1.0]) + rng.normal(0, 0.01, (40, 3))
    names = ["waist", "shoulder", "elbow", "wrist_roll", "wrist_bend", "flange_roll"]
    write_csv(tmp_path / "m.csv", [*names, "X", "Y", "Z"], [[*np.degrees(qi), *pi] for qi, pi in zip(q, p, strict=True)])
    cli = [sys.executable, "-m", "fgcal.cli"]
    for args in (["import", "csv", str(tmp_path / "m.csv"), str(tmp_path / "ds"), "--robot", "puma560",
                  "--joints", ",".join(names), "--joint-unit", "deg", "--point", "X,Y,Z"],
                 ["calibrate", str(tmp_path / "ds"), "--out", str(tmp_path / "r.json")],
                 ["export", str(tmp_path / "r.json"), "--urdf", str(tmp_path / "r.urdf")]):
        run = subprocess.run(cli + args, capture_output=True, text=True, cwd=tmp_path)
        assert run.returncode == 0, run.stderr
    root = ET.parse(tmp_path / "r.urdf").getroot()
    moving = [j.get("name") for j in root.findall("joint") if j.get("type") != "fixed"]
    assert moving == names


def test_eigen_angles_read_as_ur_calibration_computed_them(ur10):
    """ur_calibration's writer gives Eigen's eulerAngles(0, 1, 2): R = Rx(roll) Ry(pitch) Rz(yaw)."""
    from scipy.spatial.transform import Rotation

    from fgcal.robots.ur_kinematics import parse_kinematics

    kin = ur_kinematics(ur10, _perturbed(ur10, 278))
    entries = {}
    for name, origin in zip(NAMES, kin.origins, strict=True):
        roll, pitch, yaw = Rotation.from_matrix(origin[:3, :3]).as_euler("XYZ")  # intrinsic: Rx Ry Rz
        entries[name] = dict(zip("xyz", (origin[:3, 3] / 1000).tolist(), strict=True)) | {
            "roll": float(roll), "pitch": float(pitch), "yaw": float(yaw)}
    eigen = parse_kinematics({"kinematics": entries}, angles="eigen")
    np.testing.assert_allclose(eigen.origins, kin.origins, atol=1e-9)
    urdf = parse_kinematics({"kinematics": entries}, angles="urdf")
    assert np.abs(urdf.origins[:, :3, :3] - kin.origins[:, :3, :3]).max() > 1e-6  # the conventions differ
