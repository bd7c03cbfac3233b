import subprocess
import sys

import numpy as np
import pytest

from fgcal.errors import DatasetError
from fgcal.io.dataset_io import load_dataset, save_dataset
from fgcal.measurements.dataset import Noise
from fgcal.studies.simulate import SimulationSettings, simulate


@pytest.fixture(scope="module")
def sample(puma, tmp_path_factory):
    ds, _ = simulate(puma, np.random.default_rng(21), SimulationSettings(
        n_poses=5, levels=("probes", "centres", "poses"), noise=Noise(0.01, 0.01)))
    path = tmp_path_factory.mktemp("ds") / "sample"
    save_dataset(ds, path)
    return ds, path


def test_round_trip(sample):
    ds, path = sample
    back = load_dataset(path)
    np.testing.assert_array_equal(back.pose_ids, ds.pose_ids)
    # exact to two units in the last place: a written number drops float noise (42.580000000000005, the
    # simulator's reading rounded to 0.01 deg, is written 42.58; fgcal.util.numbers)
    np.testing.assert_array_max_ulp(back.joints_deg, ds.joints_deg, maxulp=2)
    assert np.any(back.joints_deg != ds.joints_deg)  # some readings carried float noise: now clean
    for level in ("probes", "centres"):
        a, b = getattr(ds, level), getattr(back, level)
        np.testing.assert_array_max_ulp(a.xyz, b.xyz, maxulp=2)
        np.testing.assert_array_equal(a.ball, b.ball)
        np.testing.assert_array_equal(a.pose, b.pose)
    np.testing.assert_array_max_ulp(back.poses.xyz, ds.poses.xyz, maxulp=2)
    np.testing.assert_allclose(back.poses.quat, ds.poses.quat, atol=1e-15)
    assert back.truth == ds.truth
    assert back.noise == ds.noise and back.tooling.radius == ds.tooling.radius


def _copy(path, tmp_path):
    import shutil
    dst = tmp_path / "bad"
    shutil.copytree(path, dst)
    return dst


def _edit(file, old, new, count=1):
    text = file.read_text()
    assert old in text, old
    file.write_text(text.replace(old, new, count))


def _replace_line(file, lineno, new):
    lines = file.read_text().splitlines()
    lines[lineno - 1] = new
    file.write_text("\n".join(lines) + "\n")


BAD_CASES = {
    "missing joints": (lambda d: (d / "joints.csv").unlink(), r"joints\.csv: file not found"),
    "missing column": (lambda d: _edit(d / "joints.csv", "pose,q1,q2,q3,q4,q5,q6", "pose,q1,q2,q3,q4,q5"),
                       r"joints\.csv: line 2: 7 fields, expected 6"),
    "joint gap": (lambda d: _edit(d / "joints.csv", "pose,q1,q2,q3,q4,q5,q6", "pose,q1,q2,q3,q4,q5,q7"),
                  r"joints\.csv: line 1: joint columns must be q1\.\.qn without gaps"),
    "unknown ball": (lambda d: _replace_line(d / "centres.csv", 3, "1,Z,1,2,3"), r"centres\.csv: line 3: unknown ball 'Z'"),
    "pose without joints": (lambda d: _replace_line(d / "probes.csv", 2, "99,A,1,2,3"),
                            r"probes\.csv: line 2: pose 99 has no joint readings"),
    "nan": (lambda d: _replace_line(d / "probes.csv", 4, "1,A,nan,2,3"), r"probes\.csv: line 4: x is not finite"),
    "text in a number": (lambda d: _replace_line(d / "joints.csv", 3, "2,1,2,x3,4,5,6"),
                         r"joints\.csv: line 3: q3 is not a number: 'x3'"),
    "duplicate pose id": (lambda d: _replace_line(d / "joints.csv", 3, "1,1,2,3,4,5,6"),
                          r"joints\.csv: line 3: duplicate pose id 1 \(first on line 2\)"),
    "duplicate centre": (lambda d: _replace_line(d / "centres.csv", 3, (d / "centres.csv").read_text().splitlines()[1]),
                         r"centres\.csv: line 3: duplicate centre"),
    "unknown format": (lambda d: _edit(d / "dataset.yaml", "fgcal-dataset/1", "fgcal-dataset/9"),
                       r"dataset\.yaml: format 'fgcal-dataset/9' is not known"),
    "object tag": (lambda d: _edit(d / "dataset.yaml", "robot: puma560", "robot: !!python/object/apply:os.system ['echo hi']"),
                   r"dataset\.yaml: line \d+: refusing a YAML tag that builds objects"),
    "wrong field count": (lambda d: _replace_line(d / "joints.csv", 2, "1,2,3"), r"joints\.csv: line 2: 3 fields, expected 7"),
    "bad quaternion": (lambda d: _replace_line(d / "poses.csv", 2, "1,1,2,3,2,0,0,0"),
                       r"poses\.csv: line 2: quaternion \(qw, qx, qy, qz\) has norm 2"),
    "unknown truth parameter": (lambda d: _edit(d / "truth.yaml", "j2.beta", "j2.gamma"),
                                r"truth\.yaml: unknown parameter 'j2.gamma'"),
    "missing key": (lambda d: _edit(d / "dataset.yaml", "noise:", "noize:"), r"dataset\.yaml: missing key\(s\) noise"),
}


@pytest.mark.parametrize("case", list(BAD_CASES))
def test_bad_input_names_file_and_line(sample, tmp_path, case):
    _, path = sample
    make_bad, pattern = BAD_CASES[case]
    bad = _copy(path, tmp_path)
    make_bad(bad)
    with pytest.raises(DatasetError, match=pattern) as info:
        load_dataset(bad)
    assert "\n" not in str(info.value)


def test_cli_reports_bad_input_in_one_line(sample, tmp_path):
    _, path = sample
    bad = _copy(path, tmp_path)
    _replace_line(bad / "joints.csv", 3, "2,1,2,x3,4,5,6")
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "check", str(bad)], capture_output=True, text=True)
    assert run.returncode == 2
    assert run.stderr.count("\n") == 1 and "Traceback" not in run.stderr
    assert "joints.csv: line 3: q3 is not a number" in run.stderr


def test_cli_simulate_writes_nothing_on_error(tmp_path):
    out = tmp_path / "never"
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "simulate", str(out), "--plan", "paper", "--poses", "7"],
                         capture_output=True, text=True)
    assert run.returncode == 2 and "48 poses" in run.stderr and "Traceback" not in run.stderr
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_cli_simulate_then_check(tmp_path):
    out = tmp_path / "sim"
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "simulate", str(out), "--poses", "8", "--seed", "4",
                          "--cmm-sigma", "0", "--joint-resolution", "0"], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    ds = load_dataset(out)
    assert ds.n_poses == 8 and len(ds.probes) == 8 * 3 * 4 and ds.noise.cmm_sigma == 0
    again = subprocess.run([sys.executable, "-m", "fgcal.cli", "simulate", str(out)], capture_output=True, text=True)
    assert again.returncode == 2 and "already exists" in again.stderr
    check = subprocess.run([sys.executable, "-m", "fgcal.cli", "check", str(out)], capture_output=True, text=True)
    assert check.returncode == 0 and "rank 30 of 30" in check.stdout


def test_same_seed_same_dataset(puma):
    a, _ = simulate(puma, np.random.default_rng(5), SimulationSettings(n_poses=6))
    b, _ = simulate(puma, np.random.default_rng(5), SimulationSettings(n_poses=6))
    np.testing.assert_array_equal(a.probes.xyz, b.probes.xyz)
    np.testing.assert_array_equal(a.joints_deg, b.joints_deg)
