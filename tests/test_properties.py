"""Property-based tests over every file reader: any input ends in a value or one ``FgcalError`` line.

Each reader gets valid files mutated at random (lines replaced, cut, doubled; numbers turned into
NaN, 1e309, 2^64, text; bytes that are not UTF-8; YAML and JSON structure changed) and must
either return or raise :class:`~fgcal.errors.FgcalError` with a message of one bounded line;
any other exception (KeyError, OverflowError, IndexError, ...) fails the test with the input.
"""
import json
import re
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hostile_util import REPO, small_dataset
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fgcal.errors import FgcalError

SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                            HealthCheck.function_scoped_fixture])
TOKENS = ["nan", "inf", "-inf", "1e309", "-1e308", str(2**64), str(-(2**63) - 1), "", " ", "x", "0", "-0", "1e-320",
          "null", "[]", "{}", "'", '"', ",", ";", "\t", "True", "~", "*a", "&a", "!!python/object:os.system", "\x00",
          "é", "9" * 400, "[" * 300]


@st.composite
def mutated(draw, text: str):
    """``text`` (bytes of UTF-8) with a few random edits of lines, fields and bytes."""
    lines = text.splitlines()
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["token", "drop", "dup", "cut", "field", "bytes", "swap", "number"]))
        if not lines:
            lines = [""]
        k = draw(st.integers(0, len(lines) - 1))
        if op == "token":
            lines[k] = draw(st.sampled_from(TOKENS))
        elif op == "drop":
            del lines[k]
        elif op == "dup":
            lines.insert(k, lines[k])
        elif op == "cut":
            lines[k] = lines[k][:draw(st.integers(0, max(len(lines[k]) - 1, 0)))]
        elif op == "swap":
            j = draw(st.integers(0, len(lines) - 1))
            lines[k], lines[j] = lines[j], lines[k]
        elif op == "field":  # one number of the line replaced by a token
            nums = list(re.finditer(r"-?\d+(\.\d+)?(e-?\d+)?", lines[k]))
            if nums:
                m = nums[draw(st.integers(0, len(nums) - 1))]
                lines[k] = lines[k][:m.start()] + draw(st.sampled_from(TOKENS)) + lines[k][m.end():]
        elif op == "number":  # one number scaled or negated
            nums = list(re.finditer(r"-?\d+(\.\d+)?(e-?\d+)?", lines[k]))
            if nums:
                m = nums[draw(st.integers(0, len(nums) - 1))]
                v = float(m.group()) * draw(st.sampled_from([-1, 0, 1e6, 1e-9, 1e300]))
                lines[k] = lines[k][:m.start()] + repr(v) + lines[k][m.end():]
        else:
            lines[k] = lines[k] + draw(st.text(max_size=20))
    data = ("\n".join(lines) + ("\n" if draw(st.booleans()) else "")).encode("utf-8", "surrogatepass")
    if draw(st.integers(0, 9)) == 0:
        data += draw(st.binary(max_size=16))
    return data


def _one_line(exc: FgcalError) -> None:
    text = str(exc)
    assert "\n" not in text and len(text) < 2000, text[:300]


def _expect(f, *args, **kw):
    """``f(*args)``: a value, or an FgcalError of one line; anything else propagates (a failure)."""
    try:
        return f(*args, **kw)
    except FgcalError as exc:
        _one_line(exc)
        return None


def _read_mutated(examples, name, read, check=None) -> None:
    """Each of ``examples`` (bytes) written to a file ``name`` and read by ``read(path)``: a value
    (then ``check(value)``, when given) or an FgcalError of one line (:func:`_expect`)."""

    @SETTINGS
    @given(examples)
    def run(data):
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / name
            path.write_bytes(data)
            out = _expect(read, path)
            if out is not None and check is not None:
                check(out)

    run()


@pytest.fixture(scope="module")
def dataset(puma, tmp_path_factory):
    d = tmp_path_factory.mktemp("prop") / "ds"
    small_dataset(puma, d, n_poses=5, seed=1, levels=("probes", "centres", "poses"))
    return d


def _copy_with(dataset, name, data):
    tmp = Path(tempfile.mkdtemp(prefix="prop-"))
    shutil.copytree(dataset, tmp / "ds")
    (tmp / "ds" / name).write_bytes(data)
    return tmp


def _load_all(directory):
    from fgcal.io.dataset_io import dataset_model, load_dataset

    ds = load_dataset(directory)
    dataset_model(ds)
    return ds


@pytest.mark.parametrize("name", ["joints.csv", "probes.csv", "centres.csv", "poses.csv", "dataset.yaml"])
def test_dataset_files(dataset, name):
    text = (dataset / name).read_text()

    @SETTINGS
    @given(mutated(text))
    def check(data):
        tmp = _copy_with(dataset, name, data)
        try:
            _expect(_load_all, tmp / "ds")
        finally:
            shutil.rmtree(tmp)

    check()


def test_joints_reader(dataset):
    from fgcal.io.dataset_io import read_joints

    def check(out):
        ids, q = out
        assert np.all(np.isfinite(q)) and len(ids) == len(q) and len(set(ids.tolist())) == len(ids)

    _read_mutated(mutated((dataset / "joints.csv").read_text()), "j.csv", read_joints, check)


@pytest.mark.parametrize("robot", ["puma560", "ur10"])
def test_model_files(robot):
    from fgcal.robots.robot_file import load_model

    def check(m):
        assert np.all(np.isfinite(m.nominal)) and np.all(m.joint_limits[:, 0] < m.joint_limits[:, 1])

    _read_mutated(mutated((REPO / "datasets/robots" / f"{robot}.yaml").read_text()), "m.yaml", load_model, check)


@pytest.mark.parametrize("urdf", ["panda.urdf", "ur10_robot.urdf"])
def test_urdf(urdf):
    from fgcal.robots.urdf_import import model_from_urdf

    text = (REPO / "tests/data/urdf" / urdf).read_text()
    chain = {"panda.urdf": ("panda_link0", "panda_hand_tcp"), "ur10_robot.urdf": ("base_link", "tool0")}[urdf]

    @SETTINGS
    @given(mutated(text))
    def check(data):
        m = _expect(model_from_urdf, data.decode("utf-8", "replace"), "r.urdf", base=chain[0], tip=chain[1])
        if m is not None:
            assert np.all(np.isfinite(m.nominal)) and np.all(np.isfinite(m.joint_limits))

    check()


@pytest.fixture(scope="module")
def result_file(dataset, tmp_path_factory):
    from fgcal.cli import main

    out = tmp_path_factory.mktemp("propres") / "r.json"
    assert main(["calibrate", str(dataset), "--out", str(out)]) == 0
    return out


@st.composite
def json_edits(draw, d):
    """A result's JSON with a few values replaced: wrong types, non-finite numbers, keys removed."""
    d = json.loads(json.dumps(d))
    for _ in range(draw(st.integers(1, 3))):
        node, path = d, []
        while isinstance(node, (dict, list)) and node and draw(st.integers(0, 3)) > 0:
            key = draw(st.sampled_from(sorted(node) if isinstance(node, dict) else range(len(node))))
            path.append((node, key))
            node = node[key]
        if not path:
            continue
        parent, key = path[-1]
        op = draw(st.sampled_from(["value", "remove"]))
        if op == "remove" and isinstance(parent, dict):
            del parent[key]
        else:
            parent[key] = draw(st.sampled_from([None, "x", float("nan"), float("inf"), -1.0, 1e308, 2**64, [], {},
                                                [1.0], True, -0.0]))
    return json.dumps(d).encode()


def test_results(result_file):
    from fgcal.estimation.result import load_result

    d = json.loads(result_file.read_text())

    def check(r):
        assert np.all(np.isfinite(r.covariance)) and np.all(r.sigma >= 0)
        r.slot_vector()

    _read_mutated(st.one_of(json_edits(d), mutated(result_file.read_text())), "r.json", load_result, check)


@pytest.fixture(scope="module")
def checkpoint(dataset, tmp_path_factory):
    from fgcal.cli import main

    out = tmp_path_factory.mktemp("propck") / "r.json"
    assert main(["online", str(dataset), "--engine", "ekf", "--out", str(out)]) == 0
    return Path(f"{out}.ekf.checkpoint")


def test_checkpoints(checkpoint):
    from fgcal.online.checkpoint import read_checkpoint, read_snapshot

    text = checkpoint.read_text()
    entry = json.loads(text.splitlines()[1])

    def read(p):
        _expect(read_checkpoint, p)
        _expect(read_snapshot, p)  # a journal is no snapshot: refused in one line

    _read_mutated(st.one_of(mutated(text), json_edits(entry).map(lambda e: (text.splitlines()[0] + "\n").encode() + e
                                                                 + b"\n")), "c.ck", read)


def test_snapshots():
    from fgcal.online.checkpoint import read_snapshot

    snap = {"n": 2, "state": {"x": [0.0, 1.0], "P": [[1.0, 0.0], [0.0, 1.0]], "names": ["a", "b"], "setup": {}}}

    def check(s):
        assert len(s["state"]["P"]) == len(s["state"]["x"])

    _read_mutated(json_edits(snap), "s.snapshot", read_snapshot, check)


def test_streams(dataset):
    """The stream reader never raises: every bad line is a warning of one bounded line."""
    from fgcal.io.dataset_io import load_dataset
    from fgcal.online.stream import read_stream

    ds = load_dataset(dataset)
    lines = [f"joints,{p},{','.join(map(str, q))}" for p, q in zip(ds.pose_ids, ds.joints_deg, strict=True)]
    probes = [f"probe,{p},{b},{x},{y},{z}" for p, b, (x, y, z) in
              zip(ds.probes.pose, ds.probes.ball, ds.probes.xyz, strict=True)]
    text = "\n".join(lines[:2] + probes[:8] + ["end,1", "pose,2,1,2,3,1,0,0,0", "distance,2,B,100",
                                               "centre,2,B,1,2,3"])

    @SETTINGS
    @given(mutated(text))
    def check(data):
        warnings = []
        records = list(read_stream(data.split(b"\n"), list(ds.tooling.balls), warn=warnings.append))
        for w in warnings:
            assert "\n" not in w and len(w) < 400, w[:300]
        for r in records:
            assert np.all(np.isfinite(r.q)) and 0 <= r.pose <= 2**62

    check()


def test_import_tables():
    from fgcal.io.table_io import ColumnSpec, read_measurements

    text = "a,b,c,d,e,f,x,y,z\n" + "\n".join(f"{i},1,2,3,4,5,{100 + i},200.5,300" for i in range(8))
    from fgcal.io.table_io import AngleUnit

    spec = ColumnSpec(joints=("a", "b", "c", "d", "e", "f"), joint_unit=AngleUnit.DEG, point=("x", "y", "z"))

    def check(m):
        assert np.all(np.isfinite(m.joints_rad)) and np.all(np.isfinite(m.xyz))
        assert all(len(s) < 400 for s in m.skipped)

    _read_mutated(mutated(text), "t.csv", lambda p: read_measurements(p, spec), check)


def test_tum():
    from fgcal.io.tum import read_tum

    text = "\n".join(f"{i}.0 0.1 0.2 0.3 0 0 0 1" for i in range(6))

    def check(out):
        assert all(len(s) < 400 for s in out[4])

    _read_mutated(mutated(text), "t.txt", read_tum, check)


def test_targets(dataset):
    from fgcal.io.targets import read_targets

    _read_mutated(mutated((dataset / "poses.csv").read_text()), "t.csv", read_targets)
