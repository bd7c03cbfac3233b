"""Corrupted online checkpoints (journal entries, snapshots) end in one line naming the file and
``--restart``; pose ids beyond 64 bits are refused in one line, never journalled."""
import json

import pytest
from hostile_util import call, one_line_error, small_dataset


@pytest.fixture(scope="module")
def run(puma, tmp_path_factory):
    d = tmp_path_factory.mktemp("ckpt")
    small_dataset(puma, d / "ds", n_poses=6, seed=11)
    from fgcal.cli import main
    assert main(["online", str(d / "ds"), "--engine", "ekf", "--out", str(d / "r.json")]) == 0
    return d


def _journal(run, tmp_path):
    ck = tmp_path / "r.json.ekf.checkpoint"
    ck.write_text((run / "r.json.ekf.checkpoint").read_text())
    return ck


def _edit_line(ck, k, f):
    lines = ck.read_text().splitlines()
    d = json.loads(lines[k])
    f(d)
    lines[k] = json.dumps(d)
    ck.write_text("\n".join(lines) + "\n")


JOURNAL = {
    "no accepted key": lambda d: d.pop("accepted"),
    "no pose key": lambda d: d.pop("pose"),
    "pose 2^64": lambda d: d.update(pose=2**64),
    "pose -1": lambda d: d.update(pose=-1),
    "pose string": lambda d: d.update(pose="1"),
    "history nan": lambda d: d["history"]["estimate"].__setitem__(0, float("nan")),
    "history short sigma": lambda d: d["history"].update(sigma=[1.0]),
    "record broken": lambda d: d.update(record={"pose": d["pose"], "q": "abc"}),
}


@pytest.mark.parametrize("name", JOURNAL)
def test_corrupted_journal_refused(run, tmp_path, capsys, name):
    ck = _journal(run, tmp_path)
    _edit_line(ck, 2, JOURNAL[name])
    code, _, err = call(["online", run / "ds", "--engine", "ekf", "--out", tmp_path / "r.json"], capsys)
    one_line_error(code, err, str(ck), "--restart")
    code, _, err = call(["online", run / "ds", "--engine", "ekf", "--out", tmp_path / "r.json", "--restart"], capsys)
    assert code == 0, err


def test_journal_line_not_a_mapping(run, tmp_path, capsys):
    ck = _journal(run, tmp_path)
    lines = ck.read_text().splitlines()
    lines[1] = "[1, 2, 3]"
    ck.write_text("\n".join(lines) + "\n")
    code, _, err = call(["online", run / "ds", "--engine", "ekf", "--out", tmp_path / "r.json"], capsys)
    one_line_error(code, err, "not a mapping", "--restart")


@pytest.mark.parametrize("state", [
    {"n": 1, "state": {"x": [1.0, 2.0], "P": [[1.0]]}},  # short P
    {"n": 1, "state": {"x": [float("nan")], "P": [[1.0]]}},
    {"n": "one", "state": {"x": [1.0], "P": [[1.0]]}},
    {"n": 1},
    [1, 2],
])
def test_corrupted_snapshot_refused(run, tmp_path, capsys, state):
    ck = _journal(run, tmp_path)
    (tmp_path / (ck.name + ".snapshot")).write_text(json.dumps(state))
    code, _, err = call(["online", run / "ds", "--engine", "ekf", "--out", tmp_path / "r.json"], capsys)
    one_line_error(code, err, "snapshot", "--restart")


def test_snapshot_not_json(run, tmp_path, capsys):
    ck = _journal(run, tmp_path)
    (tmp_path / (ck.name + ".snapshot")).write_text("{nope")
    code, _, err = call(["online", run / "ds", "--engine", "ekf", "--out", tmp_path / "r.json"], capsys)
    one_line_error(code, err, "snapshot", "not readable")
