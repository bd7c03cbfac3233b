"""Unit and convention mistakes at import are refused, naming the option that fixes them.

A simulated UR10 seen by a tracker (``test_import.simulated_ur10``: its real geometry 0.5 mm and
0.05 deg off the nominal) is exported as a tracker would write it, once right and once with each
mistake a user makes: metres read as millimetres, radians read as degrees, the wrong Euler
convention, the wrong quaternion order. The right export imports with a fit of millimetres and a
fraction of a degree; each wrong one ends in one line (exit status 2) naming the cause, and
``--accept-fit`` imports it anyway.
"""
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_import import JOINTS, simulated_ur10

from fgcal.errors import DatasetError
from fgcal.io.import_checks import MAX_POSITION_RMS_MM, check_fit
from fgcal.io.importer import to_datasets
from fgcal.io.table_io import ColumnSpec, read_measurements
from fgcal.robots.robot_file import load_model


def _export(path, q, T, *, euler=None, quat_order="xyzw", metres=True):
    """A plain CSV: joints in rad, positions in m (or mm), orientation as Euler angles or a quaternion."""
    rot = Rotation.from_matrix(T[:, :3, :3])
    if euler is not None:
        tail, names = rot.as_euler(euler, degrees=True), ["a", "b", "c"]
    else:
        xyzw = rot.as_quat()
        tail = xyzw if quat_order == "xyzw" else xyzw[:, [3, 0, 1, 2]]
        names = [f"q{c}" for c in quat_order]
    xyz = T[:, :3, 3] / (1000.0 if metres else 1.0)
    rows = [",".join(JOINTS + ["x", "y", "z"] + names)]
    rows += [",".join(repr(float(v)) for v in [*q[i], *xyz[i], *tail[i]]) for i in range(len(q))]
    path.write_text("\n".join(rows) + "\n")


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "fgcal.cli", *map(str, args)], capture_output=True, text=True)


def _import(tmp_path, name, *options, **export):
    _, _, q, T = robot_data = _ROBOT
    csv = tmp_path / f"{name}.csv"
    _export(csv, q, T, **export)
    pose = "x,y,z,a,b,c" if export.get("euler") else "x,y,z," + ",".join(f"q{c}" for c in export.get("quat_order", "xyzw"))
    return _cli("import", "csv", csv, tmp_path / name, "--robot", "ur10", "--joints", ",".join(JOINTS),
                "--pose", pose, *options), robot_data


_ROBOT = simulated_ur10(np.random.default_rng(7), 40)
RIGHT = ("--joint-unit", "rad", "--length-unit", "m")


def test_a_right_export_imports_with_a_fit_of_millimetres_and_tenths_of_a_degree(tmp_path):
    run, _ = _import(tmp_path, "right", *RIGHT)
    assert run.returncode == 0, run.stderr
    line = [s for s in run.stdout.splitlines() if "base and tool fitted" in s][0]
    rms_mm = float(line.split("RMS ")[1].split(" mm")[0])
    rms_deg = float(line.split("mm, ")[1].split(" deg")[0])
    assert 0.1 < rms_mm < 5.0 and 0.0 < rms_deg < 0.3  # the nominal UR10's misfit to the real one


@pytest.mark.parametrize("mistake, options, export, cause", [
    ("metres as mm", ("--joint-unit", "rad"), {}, "--length-unit m"),
    ("radians as degrees", ("--joint-unit", "deg", "--length-unit", "m"), {}, "--joint-unit rad"),
    ("wrong Euler convention", ("--joint-unit", "rad", "--length-unit", "m", "--euler-convention", "xyz"),
     {"euler": "ZYX"}, "--euler-convention"),
    ("wrong quaternion order", ("--joint-unit", "rad", "--length-unit", "m", "--quaternion-order", "xyzw"),
     {"quat_order": "wxyz"}, "--quaternion-order"),
])
def test_a_mistake_is_one_line_naming_its_option(tmp_path, mistake, options, export, cause):
    run, _ = _import(tmp_path, "wrong", *options, **export)
    assert run.returncode == 2, (mistake, run.stdout, run.stderr)
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in run.stderr
    assert "wrong.csv" in lines[0] and cause in lines[0] and "--accept-fit" in lines[0], lines[0]
    assert not (tmp_path / "wrong").exists()  # nothing written

    forced, _ = _import(tmp_path, "wrong", *options, "--accept-fit", **export)
    assert forced.returncode == 0, forced.stderr
    assert (tmp_path / "wrong" / "dataset.yaml").exists()


def test_check_fit_measures_what_it_reports(tmp_path):
    """The library check: its RMS values are those of the fitted model, computed here independently."""
    _, _, q, T = _ROBOT
    csv = tmp_path / "t.csv"
    _export(csv, q, T)
    pose = ("x", "y", "z", "qx", "qy", "qz", "qw")
    m = read_measurements(csv, ColumnSpec(joints=tuple(JOINTS), joint_unit="rad", pose=pose, length_unit="m",
                                          quaternion_order="xyzw"))
    r = to_datasets(m, "ur10")
    r.save(tmp_path / "ds")
    fitted = load_model(tmp_path / "ds" / "robot.yaml")
    check = check_fit(fitted, fitted.nominal, m.joints_rad, m.xyz, m.R)
    Tf = fitted.forward(fitted.nominal, m.joints_rad)
    pos = np.sqrt(np.mean(np.sum((Tf[:, :3, 3] - m.xyz) ** 2, axis=1)))
    ang = Rotation.from_matrix(np.einsum("nij,nkj->nik", Tf[:, :3, :3], m.R)).magnitude()
    assert check.ok and np.isclose(check.position_rms_mm, pos) and np.isclose(r.rms, pos, rtol=1e-6)
    assert np.isclose(check.rotation_rms_deg, np.degrees(np.sqrt(np.mean(ang**2))))
    assert np.isclose(r.rotation_rms_deg, check.rotation_rms_deg, rtol=1e-6)
    assert check.position_limit_mm >= MAX_POSITION_RMS_MM

    bad = read_measurements(csv, ColumnSpec(joints=tuple(JOINTS), joint_unit="rad", pose=pose, quaternion_order="xyzw"))
    with pytest.raises(DatasetError, match="--length-unit m"):
        to_datasets(bad, "ur10")
