"""Hostile YAML and model paths: aliases, duplicate keys, depth, odd files; no file content in messages."""
import os
import resource

import pytest
from hostile_util import call, copy_dataset, one_line_error, run_cli, small_dataset

from fgcal.errors import FgcalError
from fgcal.io.dataset_io import load_dataset
from fgcal.util.yamlio import read_yaml


@pytest.fixture(scope="module")
def base(puma, tmp_path_factory):
    path = tmp_path_factory.mktemp("yaml") / "ds"
    small_dataset(puma, path, n_poses=5)
    return path


def _meta(ds, text_from_old):
    f = ds / "dataset.yaml"
    f.write_text(text_from_old(f.read_text()))


LAUGHS = "".join(f"l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * 9)}]\n" for i in range(1, 10))


def test_billion_laughs_refused_within_memory(base, tmp_path):
    ds = copy_dataset(base, tmp_path / "ds")
    _meta(ds, lambda t: t.replace("provenance:", "laughs:\n  l0: &l0 [lol]\n" + "".join(
        "  " + ln + "\n" for ln in LAUGHS.splitlines()) + "provenance: [*l9]\nold_provenance:"))
    assert (ds / "dataset.yaml").stat().st_size < 2000

    def limit():  # 1 GB of address space: an expansion would die here
        resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))

    run = run_cli(["check", ds], preexec_fn=limit, timeout=120)
    one_line_error(run.returncode, run.stderr, "dataset.yaml: line", "aliases")


def test_duplicate_key_named_with_line(tmp_path):
    f = tmp_path / "m.yaml"
    f.write_text("format: fgcal-robot/1\nname: a\nbase: {}\nname: b\n")
    with pytest.raises(FgcalError, match=r"m\.yaml: line 4: .*duplicate key 'name' \(first on line 2\)"):
        read_yaml(f)


def test_nesting_depth_bounded(tmp_path):
    f = tmp_path / "deep.yaml"
    f.write_text("a: " + "[" * 5000 + "]" * 5000 + "\n")
    with pytest.raises(FgcalError, match="nested more than 64 levels"):
        read_yaml(f)


def test_scientific_notation_is_a_number(base, tmp_path):
    ds = copy_dataset(base, tmp_path / "ds")
    _meta(ds, lambda t: t.replace("cmm_sigma: 0.01", "cmm_sigma: 1e-2").replace("radius: 6.35", "radius: 635e-2"))
    loaded = load_dataset(ds)
    assert loaded.noise.cmm_sigma == pytest.approx(0.01) and loaded.tooling.radius == pytest.approx(6.35)
    f = tmp_path / "n.yaml"
    f.write_text("a: 5e2\nb: -1.5E+3\nc: 3\nd: .5\ne: 1e\n")
    assert read_yaml(f) == {"a": 500.0, "b": -1500.0, "c": 3, "d": 0.5, "e": "1e"}


BEYOND_FLOAT = str(10**400)  # YAML and JSON integers are unbounded: math.isfinite of it raises OverflowError


def test_an_integer_beyond_a_float_is_named_not_a_traceback(puma, base, tmp_path, capsys):
    """A dataset's noise, a model file's number and a result's estimate of 10**400 are each refused
    in one line (each raised an OverflowError from math.isfinite)."""
    import json

    import yaml

    from fgcal.robots.robot_file import model_to_dict

    ds = copy_dataset(base, tmp_path / "ds")
    _meta(ds, lambda t: t.replace("cmm_sigma: 0.01", f"cmm_sigma: {BEYOND_FLOAT}"))
    code, _, err = call(["check", ds], capsys)
    one_line_error(code, err, "dataset.yaml", "noise.cmm_sigma must be a finite number")

    doc = model_to_dict(puma)
    doc["tool"]["pz"] = 10**400
    ds_model = copy_dataset(base, tmp_path / "ds_model")
    (ds_model / "m.yaml").write_text(yaml.safe_dump(doc))
    _meta(ds_model, lambda t: t.replace("robot: puma560", "robot: m.yaml"))
    code, _, err = call(["check", ds_model], capsys)
    one_line_error(code, err, "m.yaml", "expected a finite number")

    res = tmp_path / "r.json"
    assert call(["calibrate", base, "--out", res], capsys)[0] == 0
    text = json.dumps({**json.loads(res.read_text()), "parameters": "PARAMETERS"})
    params = json.loads(res.read_text())["parameters"]
    body = json.dumps(params).replace(json.dumps(params[0]["estimate"]), BEYOND_FLOAT, 1)
    res.write_text(text.replace('"PARAMETERS"', body))
    code, _, err = call(["verify", res, base], capsys)
    one_line_error(code, err, "r.json")


SECRET = "root:x:0:0:hunter2:/root:/bin/bash\ndaemon:x:1:1:hunter2:/usr/sbin:/usr/sbin/nologin\n"


@pytest.mark.parametrize("robot, what", [
    ("/dev/zero", "unknown robot model"),
    ("zero.yaml", "not a regular file"),
    ("../secret", "unknown robot model"),
    ("../secret.yaml", "not an fgcal-robot/1 model file"),
    ("../secret2.yaml", "expected a mapping, got a text of 52 characters"),
    ("sub", "unknown robot model"),
    ("sub.yaml", "is a folder"),
    ("loop.yaml", "cannot read"),
    ("fifo.yaml", "not a regular file"),
    ("huge.yaml", "bytes, more than"),
])
def test_model_path_opens_only_sane_regular_files(base, tmp_path, capsys, robot, what):
    ds = copy_dataset(base, tmp_path / "ds")
    (tmp_path / "secret").write_text(SECRET)
    (tmp_path / "secret.yaml").write_text("hunter2: 1\nhunter3: 2\n")
    (tmp_path / "secret2.yaml").write_text("root hunter2 hunter2 hunter2 hunter2 hunter2 hunter2\n")
    (ds / "sub").mkdir()
    (ds / "sub.yaml").mkdir()
    os.symlink("loop.yaml", ds / "loop.yaml")
    os.mkfifo(ds / "fifo.yaml")
    os.symlink("/dev/zero", ds / "zero.yaml")
    with open(ds / "huge.yaml", "wb") as fh:
        fh.truncate(64 * 1024 * 1024)  # sparse: 64 MB that take no disk
    _meta(ds, lambda t: t.replace("robot: puma560", f"robot: {robot}"))
    code, out, err = call(["check", ds], capsys)
    one_line_error(code, err, what)
    assert "hunter2" not in err and "hunter2" not in out


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads every file")
def test_unreadable_model_file(base, tmp_path, capsys):
    ds = copy_dataset(base, tmp_path / "ds")
    (ds / "m.yaml").write_text("format: fgcal-robot/1\n")
    (ds / "m.yaml").chmod(0)
    _meta(ds, lambda t: t.replace("robot: puma560", "robot: m.yaml"))
    code, _, err = call(["check", ds], capsys)
    one_line_error(code, err, "m.yaml", "cannot read")
