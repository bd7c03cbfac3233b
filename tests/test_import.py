"""From a tracker export to a calibrated robot: ``fgcal import csv`` on a simulated UR10.

The simulated tracker stands 2.5 m from the robot, at a bearing of 120 deg and turned by 120 deg;
its export holds joints in radians (as ROS logs them), positions in metres and ``xyzw``
quaternions, with semicolons and decimal commas. One command imports it; calibrate and verify
then recover the simulated robot within the reported uncertainty.
"""
import json
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fgcal.estimation.calibrate import CalibrationOptions, calibrate
from fgcal.estimation.result import load_result
from fgcal.io.dataset_io import dataset_model, load_dataset
from fgcal.io.table_io import ColumnSpec, read_measurements
from fgcal.robots.kinematics import forward
from fgcal.robots.model import SLOT_NAMES, slot, slots_to_file_units
from fgcal.robots.robot_file import load_model
from fgcal.robots.transforms import to_euler_zyx_trans

JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]
SIGMA_MM, SIGMA_DEG = 0.02, 0.005
ANGLES = ("theta", "alpha", "beta", "phi", "psi")


def _place(slots, part, T):
    slots[[slot(f"{part}.{f}") for f in ("phi", "theta", "psi", "px", "py", "pz")]] = to_euler_zyx_trans(T)


def simulated_ur10(rng, n):
    """``(model, truth slots (37,), q (n, 6) rad, measured T (n, 4, 4) mm)`` of a UR10 seen by a tracker."""
    model = load_model("ur10")
    truth = model.nominal.copy()
    for name in model.identifiable_names():
        angle = name.split(".")[1] in ANGLES
        truth[slot(name)] += rng.normal() * (np.radians(0.05) if angle else 0.5)
    base = np.eye(4)  # the robot seen from the tracker: 2.5 m away at 120 deg, turned by 120 deg, 0.4 m lower
    base[:3, :3] = Rotation.from_euler("zyx", [120, 0.3, -0.2], degrees=True).as_matrix()
    base[:3, 3] = [2500 * np.cos(np.radians(120)), 2500 * np.sin(np.radians(120)), -400]
    tool = np.eye(4)  # a 6-DoF probe 180 mm out on the flange
    tool[:3, :3] = Rotation.from_euler("zyx", [90, 2, -1], degrees=True).as_matrix()
    tool[:3, 3] = [25, -15, 180]
    _place(truth, "base", base)
    _place(truth, "tool", tool)
    lo = np.array([-np.pi, -2.6, -2.4, -np.pi, -np.pi, -np.pi])
    hi = np.array([np.pi, -0.5, 2.4, np.pi, np.pi, np.pi])
    q = rng.uniform(lo, hi, size=(n, 6))
    T = forward(truth, q)
    T[:, :3, 3] += rng.normal(size=(n, 3)) * SIGMA_MM
    dR = Rotation.from_rotvec(rng.normal(size=(n, 3)) * np.radians(SIGMA_DEG)).as_matrix()
    T[:, :3, :3] = dR @ T[:, :3, :3]
    return model, truth, q, T


def _comma(v, digits):
    return f"{v:.{digits}f}".replace(".", ",")


def tracker_export(path, q, T):
    """A tracker's export: ``;``, decimal commas, joints in rad, metres, xyzw quaternions; two bad rows."""
    quat = Rotation.from_matrix(T[:, :3, :3]).as_quat()  # x, y, z, w
    lines = ["stamp;" + ";".join(JOINTS) + ";x;y;z;qx;qy;qz;qw"]
    for i in range(len(q)):
        lines.append(";".join([_comma(1700000000 + 0.5 * i, 3)] + [_comma(v, 9) for v in q[i]]
                              + [_comma(v / 1000, 8) for v in T[i, :3, 3]] + [_comma(v, 9) for v in quat[i]]))
    lines.insert(4, lines[3].rsplit(";", 1)[0] + ";")  # line 5: qw missing
    bad = lines[6].split(";")
    bad[-1] = "0,2"  # line 7: not a unit quaternion
    lines[6] = ";".join(bad)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return {5: "missing or unreadable qw", 7: "quaternion norm"}


def _cli(*args):
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", *map(str, args)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    return run.stdout


def test_tracker_csv_to_calibrated_ur10(tmp_path):
    model, truth, q, T = simulated_ur10(np.random.default_rng(150), 80)
    export = tmp_path / "tracker.csv"
    bad = tracker_export(export, q, T)
    out = _cli("import", "csv", export, tmp_path / "ur10", "--robot", "ur10", "--joints", ",".join(JOINTS),
               "--joint-unit", "rad", "--pose", "x,y,z,qx,qy,qz,qw", "--length-unit", "m", "--holdout", "0.25",
               "--sigma", SIGMA_MM, "--orientation-sigma", SIGMA_DEG)
    for line, reason in bad.items():
        assert f"line {line}: {reason}" in out
    calib, held = load_dataset(tmp_path / "ur10"), load_dataset(tmp_path / "ur10-holdout")
    assert calib.n_poses + held.n_poses == 79 and set(calib.pose_ids).isdisjoint(held.pose_ids)
    assert calib.poses is not None and calib.noise.pose_position_sigma == SIGMA_MM

    _cli("calibrate", tmp_path / "ur10", "--out", tmp_path / "result.json")
    _cli("verify", tmp_path / "result.json", tmp_path / "ur10-holdout", "--out", tmp_path / "verify.json")
    result = json.loads((tmp_path / "result.json").read_text())
    assert result["converged"] and result["held"] == []
    truth_file = dict(zip(SLOT_NAMES, slots_to_file_units(truth)))
    z = np.array([(p["estimate"] - truth_file[p["name"]]) / p["sigma"] for p in result["parameters"]])
    assert len(z) == 30
    assert np.abs(z).max() < 4.0 and 0.5 < np.sqrt(np.mean(z**2)) < 1.6  # the sigmas are honest

    # At the held-out poses: the fitted-base-and-tool model is mm off, the calibrated one at the noise.
    v = json.loads((tmp_path / "verify.json").read_text())
    assert v["n_poses"] == held.n_poses
    assert v["before"]["position_mm"]["rms"] > 0.5
    assert v["position_mm"]["rms"] < 3 * np.sqrt(3) * SIGMA_MM
    assert v["orientation_deg"]["rms"] < 3 * np.sqrt(3) * SIGMA_DEG
    cal = load_result(tmp_path / "result.json").slot_vector()
    err = np.linalg.norm(forward(cal, held.joints_rad)[:, :3, 3] - forward(truth, held.joints_rad)[:, :3, 3], axis=1)
    assert np.sqrt(np.mean(err**2)) < 0.03  # the calibrated robot, not only its residuals


def test_position_only_import_of_a_reflector(tmp_path):
    """Tab-separated, degrees, millimetres, one reflector: the base and its offset are found from the points."""
    model, truth, q, T = simulated_ur10(np.random.default_rng(151), 60)
    path = tmp_path / "points.txt"
    rows = ["j1\tj2\tj3\tj4\tj5\tj6\tX\tY\tZ"]
    rows += ["\t".join([f"{v:.7f}" for v in np.degrees(qi)] + [f"{v:.5f}" for v in Ti[:3, 3]]) for qi, Ti in zip(q, T)]
    path.write_text("\n".join(rows) + "\n")
    out = _cli("import", "csv", path, tmp_path / "refl", "--robot", "ur10", "--joints", "j1,j2,j3,j4,j5,j6",
               "--joint-unit", "deg", "--point", "X,Y,Z", "--sigma", SIGMA_MM, "--holdout", "0.2")
    assert "0 row(s) skipped" in out and "positions" in out
    ds, held = load_dataset(tmp_path / "refl"), load_dataset(tmp_path / "refl-holdout")
    assert ds.poses is None and len(ds.centres) == ds.n_poses == 48
    assert ds.tooling.radius == 0.0 and list(ds.tooling.balls) == ["P"]
    # The fitted start already places the reflector: its offset on the flange is the simulated one.
    start = dataset_model(ds).nominal
    bare = truth.copy()
    bare[[slot(f"tool.{f}") for f in ("phi", "theta", "psi", "px", "py", "pz")]] = 0.0
    qh = held.joints_rad
    at = np.einsum("nij,nj->ni", np.linalg.inv(forward(bare, qh)), np.c_[forward(start, qh)[:, :3, 3], np.ones(len(qh))])
    np.testing.assert_allclose(at[:, :3], np.tile([25, -15, 180], (len(qh), 1)), atol=5.0)

    r = calibrate(ds, dataset_model(ds), CalibrationOptions())
    held_names = {h["name"] for h in r.held}  # a point shows 3 of the tool's 6 parameters
    assert r.converged and len(held_names) == 3 and all(n.startswith("tool.") for n in held_names)
    err = np.linalg.norm(forward(r.slot_vector(), qh)[:, :3, 3] - forward(truth, qh)[:, :3, 3], axis=1)
    before = np.linalg.norm(forward(start, qh)[:, :3, 3] - forward(truth, qh)[:, :3, 3], axis=1)
    assert np.sqrt(np.mean(before**2)) > 0.5 and np.sqrt(np.mean(err**2)) < 0.05
    assert np.sqrt(np.mean(np.sum((held.centres.xyz - forward(r.slot_vector(), qh)[:, :3, 3]) ** 2, axis=1))) < \
        3 * np.sqrt(3) * SIGMA_MM


@pytest.mark.parametrize("order", ["wxyz", "xyzw"])
def test_quaternion_orders_and_euler_conventions_agree(tmp_path, order):
    rng = np.random.default_rng(152)
    R = Rotation.random(5, random_state=rng.integers(1 << 31))
    xyzw = R.as_quat()
    quat = xyzw if order == "xyzw" else xyzw[:, [3, 0, 1, 2]]
    eul_in, eul_ex = R.as_euler("XYZ", degrees=True), R.as_euler("zyx", degrees=True)
    lines = ["a,b,x,y,z,r1,r2,r3,r4,i1,i2,i3,e1,e2,e3"]
    lines += [",".join(repr(float(v)) for v in [0.1, 0.2, 1.0, 2.0, 3.0, *qq, *ei, *ee]) for qq, ei, ee in zip(quat, eul_in, eul_ex)]
    path = tmp_path / "t.csv"
    path.write_text("\n".join(lines) + "\n")
    common = dict(joints=("a", "b"), joint_unit="rad")
    mq = read_measurements(path, ColumnSpec(pose=("x", "y", "z", "r1", "r2", "r3", "r4"), quaternion_order=order,
                                            length_unit="m", **common))
    mi = read_measurements(path, ColumnSpec(pose=("x", "y", "z", "i1", "i2", "i3"), euler_convention="XYZ", **common))
    me = read_measurements(path, ColumnSpec(pose=("x", "y", "z", "e1", "e2", "e3"), euler_convention="zyx", **common))
    for m in (mq, mi, me):
        np.testing.assert_allclose(m.R, R.as_matrix(), atol=1e-12)
    np.testing.assert_allclose(mq.xyz[0], [1000, 2000, 3000])
    np.testing.assert_allclose(mi.xyz[0], [1, 2, 3])


def test_tum_trajectory_joined_with_a_joint_log(tmp_path):
    """evo's TUM format (s, m, xyzw) plus a 50 Hz joint log: nearest reading within the tolerance, others named."""
    from fgcal.io.tum import read_tum_with_joint_log

    rng = np.random.default_rng(153)
    _, truth, q, T = simulated_ur10(rng, 12)
    t_pose = 100.0 + 2.0 * np.arange(12)
    quat = Rotation.from_matrix(T[:, :3, :3]).as_quat()
    tum = ["# timestamp tx ty tz qx qy qz qw"]
    tum += [" ".join(f"{v:.9f}" for v in [t, *(p / 1000), *qq]) for t, p, qq in zip(t_pose, T[:, :3, 3], quat)]
    (tmp_path / "traj.tum").write_text("\n".join(tum) + "\n")
    # The log samples the robot standing still at each pose, 3 ms off the tracker's clock; pose 5 has no reading.
    log = ["time,j1,j2,j3,j4,j5,j6"]
    for i in range(12):
        if i != 4:
            log += [",".join(f"{v:.9f}" for v in [t_pose[i] + dt, *q[i]]) for dt in (-0.497, -0.003, 0.503)]
    (tmp_path / "joints.csv").write_text("\n".join(log) + "\n")
    m = read_tum_with_joint_log(tmp_path / "traj.tum", tmp_path / "joints.csv", [f"j{k}" for k in range(1, 7)],
                                tolerance=0.01)
    keep = np.arange(12) != 4
    assert m.skipped == ["line 6: no joint reading within 0.01 (nearest 1.5 away)"]
    np.testing.assert_array_equal(m.line, np.arange(2, 14)[keep])
    np.testing.assert_allclose(m.joints_rad, q[keep], atol=1e-9)
    np.testing.assert_allclose(m.xyz, T[keep, :3, 3], atol=1e-6)
    np.testing.assert_allclose(m.R, T[keep, :3, :3], atol=1e-8)
    out = _cli("import", "tum", tmp_path / "traj.tum", tmp_path / "ds", "--robot", "ur10", "--joint-log",
               tmp_path / "joints.csv", "--joints", "j1,j2,j3,j4,j5,j6")
    assert "line 6: no joint reading" in out
    assert load_dataset(tmp_path / "ds").n_poses == 11


def test_landgraf_series_without_std_columns(tmp_path):
    """Series A has no measurement-std columns: read with the default noise, same poses as with them."""
    from fgcal.io.landgraf import read_series, series_to_datasets

    _, _, q, T = simulated_ur10(np.random.default_rng(154), 10)
    eul = Rotation.from_matrix(T[:, :3, :3]).as_euler("XYZ", degrees=True)
    header = ("Timestamp;Goal x;Goal y;Goal z;Goal roll;Goal pitch;Goal yaw;" + ";".join(JOINTS)
              + ";measurement_temperature;measurement_x;measurement_y;measurement_z;measurement_rx;measurement_ry;"
              "measurement_rz")
    lines = [header] + [";".join(["2,02E+13"] + [_comma(v, 9) for v in [i, 0, 0, 0, 0, 0, *q[i], 21.5, *T[i, :3, 3],
                                                                        *eul[i]]]) for i in range(10)]
    (tmp_path / "a.csv").write_text("\n".join(lines) + "\n")
    s = read_series(tmp_path / "a.csv")
    assert s.position_std is None and s.rotation_std_deg is None and s.skipped == []
    np.testing.assert_allclose(s.T[:, :3, 3], T[:, :3, 3], atol=1e-8)
    np.testing.assert_allclose(s.T[:, :3, :3], T[:, :3, :3], atol=1e-8)
    calib, _, robot, rms = series_to_datasets(s, "a.csv")
    assert calib.n_poses == 10 and calib.noise.pose_position_sigma == 0.02 and robot["name"] == "ur10-landgraf"
    assert rms < 10.0  # nominal links, fitted base and tool: the simulated deviations only


@pytest.mark.parametrize("text, expected", [
    ("a;b;c\n1,5;2;3\n", (";", True)), ("a;b;c\n1.5;2;3\n", (";", False)), ("a,b,c\n1.5,2,3\n", (",", False)),
    ("a\tb\tc\n1,5\t2\t3\n", ("\t", True)), ("a b  c\n1.5 2 3\n", (" ", False)), ("a b c\n1,5 2 3\n", (" ", True))])
def test_delimiter_and_decimal_comma_are_detected(text, expected):
    from fgcal.io.table_io import detect_format

    assert detect_format(text.splitlines()) == expected


def test_bad_input_is_one_line_naming_the_file(tmp_path, capsys):
    from fgcal.cli import main

    path = tmp_path / "t.csv"
    path.write_text("q1;q2;x;y;z\n1;2;3;4;5\n")

    def run(*args):
        code = main(["import", "csv", str(path), str(tmp_path / "o"), "--robot", "ur10", *args])
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1 and err.startswith("fgcal: error: ")
        return err

    assert "missing column(s) q3" in run("--joints", "q1,q3", "--joint-unit", "deg", "--point", "x,y,z")
    assert "2 joint columns, robot ur10 has 6" in run("--joints", "q1,q2", "--joint-unit", "deg", "--point", "x,y,z")
    assert "--euler-convention" in run("--joints", "q1,q2", "--joint-unit", "deg", "--pose", "x,y,z,q1,q2,x")
    assert "--quaternion-order" in run("--joints", "q1,q2", "--joint-unit", "deg", "--pose", "x,y,z,q1,q2,x,y")
    assert str(path) in run("--joints", "q1,q2", "--joint-unit", "deg", "--point", "x,y,z")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("points", [False, True])
def test_base_and_tool_fits_recover_exact_data(points):
    """Noise-free data of the nominal links: the fitted base and tool reproduce the simulated ones."""
    from fgcal.measurements.handeye import fit_base_and_point, fit_base_and_tool

    model, truth, q, _ = simulated_ur10(np.random.default_rng(155), 30)
    nominal_links = model.nominal.copy()
    for part in ("base", "tool"):
        idx = [slot(f"{part}.{f}") for f in ("phi", "theta", "psi", "px", "py", "pz")]
        nominal_links[idx] = truth[idx]
    T = forward(nominal_links, q)
    if points:
        x, rms = fit_base_and_point(model, q, T[:, :3, 3])
        got = forward(x, q)[:, :3, 3]
        np.testing.assert_allclose(got, T[:, :3, 3], atol=1e-6)
    else:
        x, rms = fit_base_and_tool(model, q, T)
        np.testing.assert_allclose(x, nominal_links, atol=1e-7)
    assert rms < 1e-6


def test_group_columns_keep_repeats_on_one_side_of_the_holdout(tmp_path):
    _, _, q, T = simulated_ur10(np.random.default_rng(156), 20)
    goal = np.repeat(np.arange(10), 2)  # every configuration measured twice
    lines = ["goal,a1,a2,a3,a4,a5,a6,px,py,pz"]
    lines += [",".join(str(float(v)) for v in [g, *q[g * 2], *T[g * 2, :3, 3]]) for g in goal]
    (tmp_path / "g.csv").write_text("\n".join(lines) + "\n")
    spec = ColumnSpec(joints=tuple(f"a{k}" for k in range(1, 7)), joint_unit="rad", point=("px", "py", "pz"),
                      group=("goal",))
    m = read_measurements(tmp_path / "g.csv", spec)
    np.testing.assert_array_equal(m.groups(), goal)
    from fgcal.io.importer import to_datasets

    r = to_datasets(m, "ur10", holdout=0.3, rng=np.random.default_rng(0))
    line_goal = dict(zip(m.line, goal))
    assert r.holdout.n_poses == 6
    assert {line_goal[p] for p in r.calibration.pose_ids}.isdisjoint({line_goal[p] for p in r.holdout.pose_ids})
