"""Nothing silent: dropped poses named, empty results refused, unit mistakes named, options validated."""
import numpy as np
import pytest
from hostile_util import call, copy_dataset, one_line_error, small_dataset

from fgcal.io.dataset_io import load_dataset, save_dataset


@pytest.fixture(scope="module")
def base(puma, tmp_path_factory):
    path = tmp_path_factory.mktemp("silent") / "ds"
    small_dataset(puma, path, n_poses=9, seed=5)
    return path


def test_calibrate_names_poses_it_does_not_use(base, tmp_path, capsys):
    ds = load_dataset(base)
    ds.joints_deg = np.vstack([ds.joints_deg, ds.joints_deg[:2] + 1.0])  # two poses nobody measured
    ds.pose_ids = np.r_[ds.pose_ids, 101, 102]
    save_dataset(ds, tmp_path / "ds")
    code, out, err = call(["calibrate", tmp_path / "ds", "--out", tmp_path / "r.json"], capsys)
    assert code == 0, err
    assert "2 of 11 poses not used, no measurement at levels probes: pose(s) 101, 102" in out
    assert "from 9 poses" in out


def test_measure_with_no_measurable_pose_is_an_error(base, tmp_path, capsys):
    d = copy_dataset(base, tmp_path / "ds")
    lines = (d / "probes.csv").read_text().splitlines()
    kept = [lines[0]] + [ln for i, ln in enumerate(lines[1:]) if i % 4 < 2]  # two points a ball
    (d / "probes.csv").write_text("\n".join(kept) + "\n")
    code, _, err = call(["measure", d, "--out", tmp_path / "m"], capsys)
    one_line_error(code, err, "no pose could be measured", "too few probe points")
    assert not (tmp_path / "m").exists()


def _scaled(base, tmp_path, joints=1.0, xyz=1.0):
    ds = load_dataset(base)
    ds.joints_deg = ds.joints_deg * joints
    ds.probes.xyz = ds.probes.xyz * xyz
    ds.truth = None
    save_dataset(ds, tmp_path / "ds")
    return tmp_path / "ds"


def test_joints_in_radians_are_named(base, tmp_path, capsys):
    d = _scaled(base, tmp_path, joints=np.pi / 180)
    code, out, err = call(["check", d], capsys)
    assert code == 0 and "look like radians" in err and "joints.csv" in err


def test_positions_in_metres_are_named(base, tmp_path, capsys):
    d = _scaled(base, tmp_path, xyz=1e-3)
    code, out, err = call(["check", d], capsys)
    assert code == 0 and "look like metres" in err and "probes.csv" in err


def test_plausible_dataset_has_no_unit_warning(base, capsys):
    code, _, err = call(["check", base], capsys)
    assert code == 0 and "warning" not in err


def test_absurd_magnitude_is_an_error(base, tmp_path, capsys):
    d = copy_dataset(base, tmp_path / "ds")
    lines = (d / "probes.csv").read_text().splitlines()
    pose, ball, _, y, z = lines[3].split(",")
    lines[3] = ",".join([pose, ball, "1e308", y, z])
    (d / "probes.csv").write_text("\n".join(lines) + "\n")
    code, _, err = call(["check", d], capsys)
    one_line_error(code, err, "probes.csv: line 4: x = 1e308", "absurdly large")


@pytest.mark.parametrize("args, words", [
    (["--exclude", "j9.zz"], ["--exclude", "j9.zz", "unknown parameter"]),
    (["--exclude", "j1.theta"], ["not among the estimated parameters"]),
    (["--extra", "nope"], ["--extra", "nope"]),
    (["--select", "first:-3"], ["first:-3", "at least 1"]),
    (["--select", "last:0"], ["last:0", "at least 1"]),
    (["--select", "first:99"], ["only 9 poses"]),
    (["--select", "5-3"], ["range 5-3 is empty"]),
    (["--select", "1-999999999999"], ["spans more ids"]),
    (["--levels", "centres"], ["has no centres"]),
])
def test_calibrate_options_validated(base, tmp_path, capsys, args, words):
    code, _, err = call(["calibrate", base, "--out", tmp_path / "r.json", *args], capsys)
    one_line_error(code, err, *words)
    assert not (tmp_path / "r.json").exists()


@pytest.mark.parametrize("args, words", [
    (["simulate", "x", "--cmm-sigma", "nan"], ["--cmm-sigma", "not a finite number"]),
    (["simulate", "x", "--poses", "0"], ["--poses", ">= 1"]),
    (["simulate", "x", "--balls", "-1"], ["--balls"]),
    (["simulate", "x", "--seed", "-4"], ["--seed"]),
    (["measure", "ds", "--orthogonality-tolerance", "nan"], ["--orthogonality-tolerance", "not a finite number"]),
    (["measure", "ds", "--threshold", "-1"], ["--threshold", "> 0"]),
    (["design", "--out", "p.csv", "--candidates", "0"], ["--candidates"]),
    (["study", "fig13", "--trials", "0"], ["--trials"]),
    (["study", "fig13", "--workers", "-2"], ["--workers"]),
    (["online", "ds", "--interval", "inf"], ["--interval"]),
    (["import", "landgraf", "a.csv", "out", "--holdout", "nan"], ["--holdout"]),
])
def test_numeric_options_validated(tmp_path, capsys, monkeypatch, args, words):
    monkeypatch.chdir(tmp_path)
    code, _, err = call(args, capsys)
    one_line_error(code, err, *words)
    assert list(tmp_path.iterdir()) == []
