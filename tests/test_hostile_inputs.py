"""One notion of the inputs of a run (``fgcal.cli.commands.inputs``): no output replaces, or lies in a
replaced folder with, a dataset's files, the robot file its dataset.yaml names (resolved against
the dataset's folder, suffix in any case), a robot given by option, a result or a side table."""
import csv
import hashlib
import json
import shutil

import pytest
from hostile_util import REPO, call, one_line_error, small_dataset

from fgcal.cli.commands.inputs import dataset_files, run_inputs
from fgcal.io.dataset_io import write_csv


def _digest(p):
    return hashlib.sha256(p.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def ds(puma, tmp_path_factory):
    """A puma dataset whose dataset.yaml names its own robot file, arm.yaml; and a result of it."""
    d = tmp_path_factory.mktemp("inputs")
    small_dataset(puma, d / "ds", n_poses=8, seed=2)
    shutil.copy(REPO / "datasets/robots/puma560.yaml", d / "ds" / "arm.yaml")
    y = d / "ds" / "dataset.yaml"
    y.write_text(y.read_text().replace("robot: puma560", "robot: arm.yaml"))
    from fgcal.cli import main
    assert main(["calibrate", str(d / "ds"), "--out", str(d / "r.json")]) == 0
    return d


def test_dataset_files_include_its_robot(ds):
    files = dataset_files(ds / "ds")
    assert ds / "ds" in files and ds / "ds" / "dataset.yaml" in files and ds / "ds" / "arm.yaml" in files
    assert run_inputs(robots=["puma560"]) == []  # a built-in name reads no file


@pytest.mark.parametrize("args", [
    ["calibrate", "{ds}", "--out", "{ds}/arm.yaml"],
    ["verify", "{r}", "{ds}", "--out", "{ds}/arm.yaml"],
    ["online", "{ds}", "--out", "{ds}/arm.yaml"],
    ["online", "{ds}", "--checkpoint", "{ds}/arm.yaml"],
    ["online", "{ds}", "--checkpoint", "{ds}/joints.csv"],
    ["calibrate", "{ds}", "--out", "{ds}/joints.csv"],
    ["calibrate", "{ds}", "--verification", "{ds}", "--out", "{ds}/probes.csv"],
])
def test_output_over_an_input_refused(ds, capsys, monkeypatch, tmp_path, args):
    monkeypatch.chdir(tmp_path)  # the robot file resolved against the dataset's folder, not here
    before = {p.name: _digest(p) for p in (ds / "ds").iterdir() if p.is_file()}
    code, _, err = call([a.format(ds=ds / "ds", r=ds / "r.json") for a in args], capsys)
    one_line_error(code, err, "input")
    assert {p.name: _digest(p) for p in (ds / "ds").iterdir() if p.is_file()} == before


def test_robot_suffix_in_capitals_is_the_datasets(ds, tmp_path, capsys, monkeypatch):
    """robot: ARM.YAML is read from the dataset's folder (it was looked up in the current folder)."""
    d = tmp_path / "ds"
    shutil.copytree(ds / "ds", d)
    (d / "arm.yaml").rename(d / "ARM.YAML")
    (d / "dataset.yaml").write_text((d / "dataset.yaml").read_text().replace("robot: arm.yaml", "robot: ARM.YAML"))
    monkeypatch.chdir(tmp_path.parent)
    code, out, err = call(["check", d], capsys)
    assert code == 0, err
    code, _, err = call(["calibrate", d, "--out", d / "ARM.YAML"], capsys)
    one_line_error(code, err, "input of this run")


def test_import_force_into_the_folder_of_its_robot(ds, tmp_path, capsys):
    out = tmp_path / "OUT"
    out.mkdir()
    shutil.copy(REPO / "datasets/robots/ur10.yaml", out / "myrobot.yaml")
    (tmp_path / "t.csv").write_text("a,b,c,d,e,f,x,y,z\n" + "1,2,3,4,5,6,100,200,300\n" * 3)
    code, _, err = call(["import", "csv", tmp_path / "t.csv", out, "--force", "--robot", out / "myrobot.yaml",
                         "--joints", "a,b,c,d,e,f", "--joint-unit", "deg", "--point", "x,y,z"], capsys)
    one_line_error(code, err, "myrobot.yaml")
    assert (out / "myrobot.yaml").exists()


@pytest.fixture(scope="module")
def joint_error_result(ur10, tmp_path_factory):
    d = tmp_path_factory.mktemp("jerr")
    small_dataset(ur10, d / "ds", n_poses=30, seed=4, levels=("poses",))
    from fgcal.cli import main
    assert main(["calibrate", str(d / "ds"), "--out", str(d / "cm.json"), "--model", "compliance+map",
                 "--max-harmonics", "1"]) == 0
    assert json.loads((d / "cm.json").read_text())["joint_errors"].get("names")
    return d


def test_export_side_table_is_checked(joint_error_result, capsys):
    d = joint_error_result
    side = d / "M.urdf.joint_errors.csv"
    shutil.copy(d / "cm.json", side)  # an input of that name: the result itself
    code, _, err = call(["export", side, "--urdf", d / "M.urdf"], capsys)
    one_line_error(code, err, "joint-error table", "input of this run")
    assert not (d / "M.urdf").exists()


def test_write_csv_quotes_text(tmp_path):
    rows = [["j1,odd", "deg", 1.5, 'say "hi"'], ["plain", "mm", 2.0, "a\nb"]]
    write_csv(tmp_path / "t.csv", ["name", "unit", "v", "note"], rows)
    back = list(csv.reader((tmp_path / "t.csv").open(newline="")))
    assert back[1] == ["j1,odd", "deg", "1.5", 'say "hi"'] and back[2] == ["plain", "mm", "2.0", "a\nb"]


def test_export_deltas_wraps_angles(ds, tmp_path, capsys):
    d = json.loads((ds / "r.json").read_text())
    k = next(i for i, p in enumerate(d["parameters"]) if p["unit"] == "deg")
    d["parameters"][k]["nominal"], d["parameters"][k]["estimate"] = 179.9, -179.93  # 0.17 deg across +-180
    (tmp_path / "r.json").write_text(json.dumps(d))
    code, _, err = call(["export", tmp_path / "r.json", "--deltas", tmp_path / "d.csv"], capsys)
    assert code == 0, err
    rows = {r["name"]: r for r in csv.DictReader((tmp_path / "d.csv").open(newline=""))}
    assert float(rows[d["parameters"][k]["name"]]["delta"]) == pytest.approx(0.17, abs=1e-9)
    assert all(-180 < float(r["delta"]) <= 180 for r in rows.values() if r["unit"] == "deg")
