"""Hostile inputs of the contacts surfaces: ``fgcal import mukca``, ``fixtures:``/``constraints:`` and
``contacts.csv`` of a dataset, a result's ``setup`` section, and the other commands on a contacts
dataset (representative cases of ``tools/hostile_sweep.py --tag contacts``).

The import refusals use hole files written here (random joint sets of the test Panda URDF); the
calibrations use the MUKCa placements in ../shared/data when they are there."""
import json
import math
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from hostile_util import call, one_line_error

from fgcal.errors import FgcalError
from fgcal.estimation.result import load_result

REPO = Path(__file__).resolve().parent.parent
URDF = REPO / "tests" / "data" / "urdf" / "panda.urdf"
CHAIN = "panda_link0,panda_link8"
MUKCA = next((p / "shared" / "data" / "mukca-panda" for p in (REPO.parent, REPO.parent.parent)
              if (p / "shared" / "data" / "mukca-panda" / "panda_2").is_dir()),
             REPO.parent / "shared" / "data" / "mukca-panda")
needs_data = pytest.mark.skipif(not (MUKCA / "panda_2").is_dir(), reason=f"MUKCa data not found at {MUKCA}")


def _holes(root: Path, placements=("a", "b"), rows=5, seed=0) -> Path:
    """A MUKCa-like folder: each placement with hole_0.csv and hole_1.csv (radians, no header)."""
    rng = np.random.default_rng(seed)
    for p in placements:
        (root / p).mkdir(parents=True)
        for h in ("hole_0", "hole_1"):
            q = rng.uniform(-2.0, 2.0, size=(rows, 7))
            (root / p / f"{h}.csv").write_text("\n".join(",".join(f"{v:.6f}" for v in r) for r in q) + "\n")
    return root


def _imp(d, out, *extra):
    return ["import", "mukca", d, out, "--robot", URDF, "--chain", CHAIN, *extra]


def _line(path: Path, k: int, text: str):
    lines = path.read_text().splitlines()
    lines[k - 1] = text
    path.write_text("\n".join(lines) + "\n")


ROW = "0.1,0.2,0.3,-2.0,0.4,2.5,0.8"


@pytest.mark.parametrize("name, corrupt, words", [
    ("empty field", lambda d: _line(d / "a/hole_0.csv", 2, "0.1,,0.3,-2.0,0.4,2.5,0.8,0.1"), ("line 2", "empty field")),
    ("7 rad", lambda d: _line(d / "a/hole_0.csv", 3, ROW.replace("0.2", "7.0")), ("line 3", "joint 2", "degrees")),
    ("degrees", lambda d: (d / "a/hole_1.csv").write_text(
        "\n".join(",".join(repr(math.degrees(float(v))) for v in ln.split(","))
                  for ln in (d / "a/hole_1.csv").read_text().splitlines()) + "\n"), ("hole_1.csv", "radians")),
    ("nan", lambda d: _line(d / "a/hole_0.csv", 1, ROW.replace("0.3", "nan")), ("line 1", "joint 3", "finite")),
    ("6 columns", lambda d: _line(d / "b/hole_0.csv", 1, ROW.rsplit(",", 1)[0]), ("line 1", "6 values")),
    ("loop", lambda d: ((d / "a/hole_1.csv").unlink(), os.symlink("hole_1.csv", d / "a/hole_1.csv")),
     ("hole_1.csv", "symbolic links")),
    ("dangling", lambda d: ((d / "a/hole_1.csv").unlink(), os.symlink("nowhere.csv", d / "a/hole_1.csv")),
     ("hole_1.csv", "not found")),
    ("fifo", lambda d: ((d / "a/hole_0.csv").unlink(), os.mkfifo(d / "a/hole_0.csv")), ("hole_0.csv", "FIFO")),
    ("placement loop", lambda d: os.symlink("c", d / "c"), ("c", "symbolic links")),
    ("comma in a name", lambda d: (d / "a").rename(d / "a,1"), ("'a,1'", "commas")),
    ("newline in a name", lambda d: (d / "a").rename(d / "a\n1"), ("'a\\n1'", "control characters")),
    ("edge space", lambda d: (d / "a").rename(d / "a "), ("'a '", "edge spaces")),
])
def test_mukca_hole_files_refused(tmp_path, capsys, name, corrupt, words):
    d = _holes(tmp_path / "mk")
    corrupt(d)
    code, out, err = call(_imp(d, tmp_path / "out"), capsys)
    one_line_error(code, err, *words)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("args, words", [
    (("--holdout-placements", ","), ("--holdout-placements", "no placement named")),
    (("--holdout-placements", "a,b"), ("every placement is held out",)),
    (("--holdout-placements", "zz"), ("zz", "not among the placements")),
])
def test_mukca_holdout_refused(tmp_path, capsys, args, words):
    d = _holes(tmp_path / "mk")
    one_line_error(*call(_imp(d, tmp_path / "out", *args), capsys)[::2], *words)


def test_mukca_chain_and_outputs(tmp_path, capsys):
    d = _holes(tmp_path / "mk")
    # no --chain on a URDF with several leaves: the option is named, not dataset.yaml
    code, _, err = call(["import", "mukca", d, tmp_path / "o", "--robot", URDF], capsys)
    one_line_error(code, err, "more than one leaf", "--chain BASE,TIP")
    assert "dataset.yaml" not in err
    one_line_error(*call(["import", "mukca", d, tmp_path / "o", "--robot", URDF, "--chain", "a,b,c"], capsys)[::2],
                   "expected BASE,TIP")
    # OUT inside DIR, DIR inside OUT, OUT the robot's folder: refused before anything is written
    one_line_error(*call(_imp(d, d / "out"), capsys)[::2], "overlaps the input folder")
    one_line_error(*call(_imp(d, tmp_path, "--force"), capsys)[::2])
    robot_dir = tmp_path / "rob"
    robot_dir.mkdir()
    shutil.copy(URDF, robot_dir / "panda.urdf")
    code, _, err = call(["import", "mukca", d, robot_dir, "--robot", robot_dir / "panda.urdf", "--chain", CHAIN,
                         "--force"], capsys)
    one_line_error(code, err, "would replace the input")
    assert (robot_dir / "panda.urdf").read_bytes() == URDF.read_bytes()
    # OUT-holdout would replace DIR
    (d.parent / "x-holdout").mkdir()
    shutil.copytree(d / "a", d.parent / "x-holdout" / "a")
    shutil.copytree(d / "b", d.parent / "x-holdout" / "b")
    code, _, err = call(["import", "mukca", d.parent / "x-holdout", d.parent / "x", "--robot", URDF, "--chain", CHAIN,
                         "--holdout-placements", "a", "--force"], capsys)
    one_line_error(code, err, "OUT-holdout", "overlaps the input folder")
    assert (d.parent / "x-holdout" / "a" / "hole_0.csv").exists() and not (d.parent / "x").exists()


def test_mukca_says_what_it_ignores(tmp_path, capsys, caplog):
    d = _holes(tmp_path / "mk", placements=("a", "b", "c"))
    (d / "c/hole_1.csv").unlink()
    (d / "notes").mkdir()
    (d / "README.txt").write_text("hello\n")
    (d / "a/hole_2.csv").write_text(ROW + "\n")
    (d / "b/hole_0.csv").write_text(ROW + "\n")
    code, out, err = call(_imp(d, tmp_path / "out"), capsys)
    assert code == 0, err
    text = caplog.text
    assert "c: no hole_1.csv" in text and "no distance constraint" in text
    assert "notes/" in text and "README.txt" in text
    assert "hole_2.csv" in text
    assert "one joint set" in text and "b/hole_0" in text
    meta = (tmp_path / "out" / "dataset.yaml").read_text()
    assert "c/hole_0" in meta and "c/hole_1" not in meta
    assert meta.count("- [") == 2  # the distances of a and b only


def test_mukca_spaces_crlf_and_trailing_comma_read(tmp_path, capsys):
    d = _holes(tmp_path / "mk")
    a0 = d / "a/hole_0.csv"
    a0.write_bytes(a0.read_text().replace(",", " ").replace("\n", "\r\n").encode())
    _line(d / "b/hole_0.csv", 1, ROW + ",")
    code, out, err = call(_imp(d, tmp_path / "out"), capsys)
    assert code == 0, err
    assert "20 contacts at 4 sockets" in out


# ---------------------------------------------------------------- dataset.yaml's fixtures, contacts.csv

@pytest.fixture()
def cds(tmp_path, capsys):
    """A small contacts dataset (imported from synthetic hole files; its joints need not agree)."""
    d = _holes(tmp_path / "mk", placements=("a", "b", "c"))
    code, _, err = call(_imp(d, tmp_path / "cds"), capsys)
    assert code == 0, err
    return tmp_path / "cds"


def _edit(path: Path, old: str, new: str):
    t = path.read_text()
    assert old in t, (old, t)
    path.write_text(t.replace(old, new, 1))


@pytest.mark.parametrize("old, new, words", [
    ("  distances:\n", "  distances:\n  - [a/hole_0, a/hole_1, 50.0, 0.05]\n", ("distances[1]", "given already")),
    ("  distances:\n", "  distances:\n  - [a/hole_1, a/hole_0, 49.0, 0.05]\n", ("distances[1]", "given already")),
    ("  distances:\n", "  distances:\n  - [a/hole_0, a/hole_0, 5, 0.05]\n", ("two different fixtures",)),
    ("  distances:\n", "  distances:\n  - [a/hole_0, b/hole_0, -5, 0.05]\n", ("distances[0]",)),
    ("contact_sigma: 0.05", "contact_sigma: 0", ("noise.contact_sigma", "positive")),
    ("contact_sigma: 0.05", "contact_sigma: -1", ("noise.contact_sigma",)),
    ("a/hole_0: {type: point}", "a/hole_0: {type: cone}", ("a/hole_0", "type: point or type: plane")),
    ("a/hole_0: {type: point}", "a/hole_0: {type: point, position: [1, 2]}", ("a/hole_0", "[x, y, z]")),
    ("a/hole_0: {type: point}", "a/hole_0: {type: point, position: [.nan, 2, 3], sigma: 1}", ("finite",)),
    ("a/hole_0: {type: point}", "a/hole_0: {type: point, position: [1, 2, 3], sigma: 0}", ("sigma must be positive",)),
    ("a/hole_0: {type: point}", "a/hole_0: {type: point, fixed: true}", ("fixed needs",)),
    ("fixtures:\n", "fixtures:\n  t: {type: plane, normal: [0, 0, 0], offset: 1}\n", ("normal must not be zero",)),
    ("fixtures:\n", "fixtures:\n  'x,y': {type: point}\n", ("without commas",)),
])
def test_fixture_definitions_refused(cds, capsys, old, new, words):
    _edit(cds / "dataset.yaml", old, new)
    one_line_error(*call(["check", cds], capsys)[::2], "dataset.yaml", *words)


@pytest.mark.parametrize("row, words", [
    ("2,B,nowhere", ("line 3", "'nowhere' is not in")),
    ("1,B,a/hole_1", ("line 3", "has a contact already (line 2)")),
    ("9999,B,a/hole_0", ("line 3", "pose 9999")),
    ("2,Z,a/hole_0", ("line 3", "unknown ball")),
])
def test_contact_rows_refused(cds, capsys, row, words):
    _line(cds / "contacts.csv", 3, row)
    one_line_error(*call(["check", cds], capsys)[::2], "contacts.csv", *words)


def test_plane_normal_of_huge_numbers_is_a_direction(cds):
    from fgcal.io.dataset_io import load_dataset

    _edit(cds / "dataset.yaml", "fixtures:\n", "fixtures:\n  t: {type: plane, normal: [1e300, 0, 1e300], offset: 1, "
                                               "fixed: true}\n  u: {type: plane, normal: [0, 1e-6, 0], offset: 2}\n")
    ds = load_dataset(cds)
    assert np.allclose(ds.setup.fixtures["t"].value, [math.sqrt(0.5), 0, math.sqrt(0.5), 1])
    assert np.allclose(ds.setup.fixtures["u"].value, [0, 1, 0, 2])


def test_unused_fixtures_and_dropped_distances(cds, caplog):
    from fgcal.io.dataset_io import load_dataset

    _edit(cds / "dataset.yaml", "fixtures:\n", "fixtures:\n  spare: {type: point, position: [0, 0, 0], fixed: true}\n"
                                               "  alone: {type: point}\n")
    _edit(cds / "dataset.yaml", "  distances:\n", "  distances:\n  - [a/hole_0, spare, 20, 0.1]\n"
                                                  "  - [spare, alone, 20, 0.1]\n")
    ds = load_dataset(cds)
    assert "spare" in ds.setup.fixtures
    assert "distance between fixtures a/hole_0 and spare is not used: no contact is at spare" in caplog.text
    assert "alone is not used" not in caplog.text  # neither end seen: nothing is lost


def test_no_contacts_warning_names_contacts(cds, caplog):
    from fgcal.io.dataset_io import load_dataset

    (cds / "contacts.csv").write_text("pose,ball,fixture\n")
    load_dataset(cds)
    assert "contacts.csv" in caplog.text and "fixtures" in caplog.text


def test_outputs_never_replace_contacts_or_the_robot(cds, capsys):
    for target in ("contacts.csv", "robot.urdf"):
        before = (cds / target).read_bytes()
        one_line_error(*call(["calibrate", cds, "--out", cds / target], capsys)[::2], target)
        assert (cds / target).read_bytes() == before


# ---------------------------------------------------------------- the MUKCa placements: calibrate and the rest

@pytest.fixture(scope="module")
def mukca(tmp_path_factory):
    """Three placements of the real data imported (one held out), calibrated and verified."""
    from fgcal.cli import main

    root = tmp_path_factory.mktemp("mukca")
    for p in ("back_left", "front_center", "mid_left"):
        shutil.copytree(MUKCA / "panda_2" / p, root / "mk" / p)
    shutil.copy(MUKCA / "panda.urdf", root / "mk.urdf")
    steps = [["import", "mukca", root / "mk", root / "cds", "--robot", root / "mk.urdf", "--chain",
              "panda_link0,ball_link", "--holdout-placements", "mid_left"],
             ["calibrate", root / "cds", "--out", root / "cres.json"],
             ["verify", root / "cres.json", root / "cds-holdout", "--out", root / "cver.json"]]
    for s in steps:
        assert main([str(a) for a in s]) == 0, s
    return root


@needs_data
def test_plane_near_one_point_refused(mukca, tmp_path, capsys):
    cds = shutil.copytree(mukca / "cds", tmp_path / "cds")
    _edit(cds / "dataset.yaml", "fixtures:\n", "fixtures:\n  table: {type: plane}\n")
    lines = (cds / "contacts.csv").read_text().splitlines()
    lines[1:21] = [ln.rsplit(",", 1)[0] + ",table" for ln in lines[1:21]]  # one socket's contacts
    (cds / "contacts.csv").write_text("\n".join(lines) + "\n")
    one_line_error(*call(["calibrate", cds, "--out", tmp_path / "r.json"], capsys)[::2],
                   "plane table", "spread over an area", "it has 20")
    lines[1:21] = [ln.rsplit(",", 1)[0] + ",back_left/hole_0" for ln in lines[1:21]]
    lines[1:3] = [ln.rsplit(",", 1)[0] + ",table" for ln in lines[1:3]]
    (cds / "contacts.csv").write_text("\n".join(lines) + "\n")
    one_line_error(*call(["calibrate", cds, "--out", tmp_path / "r.json"], capsys)[::2], "plane table", "it has 2")


@needs_data
def test_contacts_result_report_export_verify(mukca, tmp_path, capsys):
    r = mukca / "cres.json"
    code, out, err = call(["report", r, "--verify", mukca / "cver.json", "--out", tmp_path / "rep"], capsys)
    assert code == 0, err
    assert (tmp_path / "rep" / "report.html").exists()
    code, out, err = call(["export", r, "--urdf", tmp_path / "c.urdf", "--model", tmp_path / "c.yaml"], capsys)
    assert code == 0, err
    assert "ball_link" in (tmp_path / "c.urdf").read_text()
    # verify against a dataset with other fixtures (renamed) and a plane among them
    other = shutil.copytree(mukca / "cds-holdout", tmp_path / "other")
    for f in ("dataset.yaml", "contacts.csv"):
        (other / f).write_text((other / f).read_text().replace("mid_left/hole_0", "elsewhere"))
    code, out, err = call(["verify", r, other], capsys)
    assert code == 0, err
    assert "contacts" in out
    # a result of another robot
    code, out, err = call(["verify", r, _probes_dataset(tmp_path)], capsys)
    one_line_error(code, err, "is not the robot of the result")


def _probes_dataset(tmp_path):
    from hostile_util import small_dataset

    from fgcal.robots.robot_file import load_model

    small_dataset(load_model("puma560"), tmp_path / "probes")
    return tmp_path / "probes"


SETUP_EDITS = {
    "not a mapping": (lambda d: d.__setitem__("setup", [1, 2]), "setup: must be a mapping"),
    "unknown key": (lambda d: d["setup"].__setitem__("surprise", 1), "unknown key(s) surprise"),
    "fixture type": (lambda d: d["setup"]["fixtures"]["back_left/hole_0"].__setitem__("type", "cone"),
                     "setup.fixtures.back_left/hole_0"),
    "estimated nan": (lambda d: d["setup"]["estimated"]["back_left/hole_0"].__setitem__("position", [None, 0, 0]),
                      "position must be three finite numbers"),
    "estimated 2 numbers": (lambda d: d["setup"]["estimated"]["back_left/hole_0"].__setitem__("position", [1, 2]),
                            "position must be three finite numbers"),
    "estimated unknown": (lambda d: d["setup"]["estimated"].__setitem__("x", {"type": "point", "position": [1, 2, 3]}),
                          "setup.estimated.x: not among setup.fixtures"),
    "estimated missing": (lambda d: d["setup"].pop("estimated"), "no value for fixture"),
    "distance garbage": (lambda d: d["setup"]["constraints"].__setitem__("distances", [["a"]]),
                         "setup.constraints.distances[0]"),
    "gauge number": (lambda d: d["setup"].__setitem__("gauge", 5), "setup.gauge"),
    "orphan parameter": (lambda d: [d["setup"][k].pop("back_left/hole_0") for k in ("fixtures", "estimated")]
                         + [d["setup"].pop("constraints")],
                         "parameter fixture.back_left/hole_0."),
    "setup removed": (lambda d: d.pop("setup"), "no point fixture"),
}


@needs_data
@pytest.mark.parametrize("edit", list(SETUP_EDITS))
def test_result_setup_edited_refused(mukca, tmp_path, capsys, edit):
    fn, words = SETUP_EDITS[edit]
    d = json.loads((mukca / "cres.json").read_text())
    fn(d)
    (tmp_path / "r.json").write_text(json.dumps(d))
    with pytest.raises(FgcalError, match="malformed result"):
        load_result(tmp_path / "r.json")
    for cmd in (["verify", tmp_path / "r.json", mukca / "cds-holdout"], ["export", tmp_path / "r.json", "--urdf",
                                                                       tmp_path / "c.urdf"]):
        one_line_error(*call(cmd, capsys)[::2], "malformed result", words)
    assert not (tmp_path / "c.urdf").exists()


def _result_or_one_line(code, err, out_file=None):
    """Either a result that kept the contacts, or one line on stderr and status 2; never a traceback."""
    assert "Traceback" not in err
    if code == 0:
        assert out_file is None or out_file.exists()
        return True
    one_line_error(code, "\n".join(ln for ln in err.splitlines() if not ln.lower().startswith("warning:")))
    return False


@needs_data
def test_online_on_contacts_keeps_them_or_refuses(mukca, tmp_path, capsys):
    for engine in ("isam2", "ekf"):
        out = tmp_path / f"{engine}.json"
        code, _, err = call(["online", mukca / "cds", "--engine", engine, "--out", out, "--checkpoint",
                             tmp_path / f"{engine}.ckpt"], capsys)
        if _result_or_one_line(code, err, out):
            res = load_result(out)  # an online result keeps the fixtures it estimated
            assert res.n_poses > 0 and res.setup.get("estimated"), "online dropped the contacts"
            assert any(n.startswith("fixture.") for n in res.names)
        else:
            assert "contacts" in err


@needs_data
def test_gtsam_design_simulate_on_contacts(mukca, tmp_path, capsys):
    pytest.importorskip("gtsam")
    out = tmp_path / "g.json"
    code, _, err = call(["calibrate", mukca / "cds", "--engine", "gtsam", "--out", out], capsys)
    if _result_or_one_line(code, err, out):
        assert "contacts" in load_result(out).levels


@needs_data
def test_design_and_simulate_on_contacts(mukca, tmp_path, capsys):
    plan = tmp_path / "p.csv"
    code, _, err = call(["design", "--dataset", mukca / "cds", "--out", plan, "--poses", "12"], capsys)
    _result_or_one_line(code, err, plan)
    code, _, err = call(["simulate", tmp_path / "s", "--robot", mukca / "cds" / "robot.urdf", "--chain",
                         "panda_link0,ball_link", "--levels", "contacts"], capsys)
    if _result_or_one_line(code, err, tmp_path / "s"):
        assert (tmp_path / "s" / "contacts.csv").exists()
