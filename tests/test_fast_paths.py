"""The speed paths of issue 25 give what the checked paths give: the column readers of joints.csv
and probes.csv, the vectorised ball variables of ``build_graph`` and the result writer."""
import json
import math

import numpy as np
import pytest

import fgcal.io.dataset_io as dio
import fgcal.io.dataset_tables as tables
from fgcal.errors import DatasetError
from fgcal.estimation.build import _points_by_pose, _rows_of
from fgcal.estimation.result import _dumps, _json_safe, load_result, save_result
from fgcal.io.fast_tables import float_columns, int_column, read_columns
from fgcal.studies.simulate import SimulationSettings, simulate


@pytest.fixture(scope="module")
def dataset(puma, tmp_path_factory):
    ds, _ = simulate(puma, np.random.default_rng(25), SimulationSettings(n_poses=12))
    path = tmp_path_factory.mktemp("fast") / "ds"
    dio.save_dataset(ds, path)
    return path


def _checked(monkeypatch, fn, *args):
    """``fn(*args)`` with the fast paths switched off: the row-by-row reader alone."""
    with monkeypatch.context() as m:
        m.setattr(tables, "_fast_point_table", lambda *a: None)
        m.setattr(tables, "_fast_joints", lambda *a: None)
        return fn(*args)


def _same_points(a, b):
    for k in ("pose", "ball", "xyz", "line"):
        x, y = getattr(a, k), getattr(b, k)
        assert x.dtype == y.dtype and np.array_equal(x, y), k


def test_fast_readers_equal_checked(dataset, monkeypatch):
    ds = dio.load_dataset(dataset)
    assert tables._fast_point_table(dataset / "probes.csv", set(ds.pose_ids.tolist()),
                                 {b: i for i, b in enumerate(ds.tooling.balls)}) is not None  # it was taken
    slow = _checked(monkeypatch, dio.load_dataset, dataset)
    _same_points(ds.probes, slow.probes)
    assert np.array_equal(ds.joints_deg, slow.joints_deg) and np.array_equal(ds.pose_ids, slow.pose_ids)


def _rewrite(src, dst, edit):
    import shutil

    shutil.copytree(src, dst)
    for name in ("probes.csv", "joints.csv"):
        text = (dst / name).read_text()
        (dst / name).write_text(edit(name, text), newline="")
    return dst


@pytest.mark.parametrize("edit", [
    lambda name, t: t.rstrip("\n"),  # no line end after the last row
    lambda name, t: t.replace("\n", "\r\n"),  # Windows line ends: still the fast path
    lambda name, t: t.replace("\n", "\n\n", 3),  # blank lines: the checked path skips them
    lambda name, t: t.replace(",", ' ,', 7),  # spaces around cells
    lambda name, t: t.replace(",B,", ',"B",') if name == "probes.csv" else t,  # quoted cells
    lambda name, t: "\n".join(t.splitlines()[:1] + t.splitlines()[:0:-1]) + "\n",  # rows reversed
], ids=["no-end", "crlf", "blank", "spaces", "quoted", "reversed"])
@pytest.mark.parametrize("chunk", [None, 97])
def test_unusual_files_read_alike(dataset, tmp_path, monkeypatch, edit, chunk):
    """Also read in chunks of 97 characters (a large file's way: lines and CRLFs cut at every place)."""
    if chunk:
        import fgcal.io.fast_tables as ft

        monkeypatch.setattr(ft, "CHUNK_CHARS", chunk)
    path = _rewrite(dataset, tmp_path / "ds", edit)
    fast, slow = dio.load_dataset(path), _checked(monkeypatch, dio.load_dataset, path)
    _same_points(fast.probes, slow.probes)
    assert np.array_equal(fast.joints_deg, slow.joints_deg) and np.array_equal(fast.pose_ids, slow.pose_ids)


@pytest.mark.parametrize("file, old, new", [
    ("probes.csv", ",B,", ",Q,"),  # unknown ball
    ("probes.csv", "\n1,", "\n999,"),  # pose without joints
    ("probes.csv", "\n1,", "\n1.5,"),  # not an integer id
    ("probes.csv", ".", "x"),  # not a number
    ("joints.csv", "\n2,", "\n1,"),  # duplicate pose id
    ("joints.csv", ".", ".5e9"),  # beyond the joint limit
    ("joints.csv", ",", ",,"),  # ragged row
], ids=["ball", "pose", "id", "number", "duplicate", "large", "ragged"])
def test_bad_cells_raise_the_checked_message(dataset, tmp_path, monkeypatch, file, old, new):
    path = _rewrite(dataset, tmp_path / "ds", lambda name, t: t.replace(old, new, 1) if name == file else t)
    with pytest.raises(DatasetError) as slow:
        _checked(monkeypatch, dio.load_dataset, path)
    with pytest.raises(DatasetError) as fast:
        dio.load_dataset(path)
    assert str(fast.value) == str(slow.value) and "line" in str(fast.value)


def test_column_helpers():
    assert read_columns.__module__ == "fgcal.io.fast_tables"
    assert int_column(["1", " 2", "3 "]).tolist() == [1, 2, 3] and int_column(["1", "2.0"]) is None
    assert float_columns([["1", "2"], ["3", "nan"]], 1e9) is None
    assert float_columns([["1", "2e10"]], 1e9) is None
    assert float_columns([["1", "-2.5"], ["3", "4"]], 10).tolist() == [[1, 3], [-2.5, 4]]


def test_points_by_pose_as_the_per_ball_loop():
    """The base fit's points: poses in the order of their first finite ball, balls in variable order."""
    rng = np.random.default_rng(3)
    ball_pose = rng.integers(0, 6, 40)
    offsets = rng.normal(size=(40, 3))
    centre = rng.normal(size=(40, 3))
    centre[rng.random(40) < 0.3] = np.nan
    expected = {}
    for j in range(40):  # the loop build_graph had
        if np.all(np.isfinite(centre[j])):
            o, c = expected.get(int(ball_pose[j]), (np.zeros((0, 3)), np.zeros((0, 3))))
            expected[int(ball_pose[j])] = (np.vstack([o, offsets[j]]), np.vstack([c, centre[j]]))
    got = _points_by_pose(ball_pose, offsets, centre)
    assert list(got) == list(expected)
    for k in expected:
        assert np.array_equal(got[k][0], expected[k][0]) and np.array_equal(got[k][1], expected[k][1])
    ids = np.array([7, 3, 9, 1])
    assert _rows_of(ids, np.array([9, 7, 1, 1, 3])).tolist() == [2, 0, 3, 3, 1]


@pytest.mark.parametrize("n_rows", [0, 1, 45])
def test_centres_world_points_as_the_per_row_loop(n_rows):
    """A centres level's points for the base fit: poses in the order of their first row, rows in file order."""
    from fgcal.measurements.base import Terms
    from fgcal.measurements.point import POINT

    rng = np.random.default_rng(4)
    pose = rng.integers(0, 9, n_rows)
    offsets, xyz = rng.normal(size=(n_rows, 3)), rng.normal(size=(n_rows, 3))
    expected: dict = {}
    for i, o, w in zip(pose.tolist(), offsets, xyz):  # the loop PointMeasurement.world_points had
        a, b = expected.get(i, (np.zeros((0, 3)), np.zeros((0, 3))))
        expected[i] = (np.vstack([a, o]), np.vstack([b, w]))
    got = POINT.world_points(Terms(pose, (offsets, xyz)))
    assert list(got) == list(expected)
    for k in expected:
        assert np.array_equal(got[k][0], expected[k][0]) and np.array_equal(got[k][1], expected[k][1])


def test_result_text_holds_the_same_values(dataset, tmp_path):
    from fgcal.estimation.calibrate import calibrate

    ds = dio.load_dataset(dataset)
    result = calibrate(ds, dio.dataset_model(ds))
    save_result(result, tmp_path / "r.json")
    text = (tmp_path / "r.json").read_text()
    assert json.loads(text) == json.loads(json.dumps(_json_safe(result.to_dict()), indent=1))
    odd = {"odd": [1.0, math.inf, -math.inf, math.nan, np.float64(2.5), 3], "row": [0.1, 2], "none": []}
    assert json.loads(_dumps(odd)) == {"odd": [1.0, "Infinity", "-Infinity", None, 2.5, 3], "row": [0.1, 2],
                                       "none": []}
    back = load_result(tmp_path / "r.json")
    assert back.pose_residuals == result.pose_residuals
    assert np.array_equal(back.covariance, result.covariance)
    assert _dumps({"a": [1.5, 2], "b": ["\0" + "0\0"]}) == '{\n "a": [1.5, 2],\n "b": [\n  "\\u00000\\u0000"\n ]\n}'


def test_chunked_point_table_is_taken_and_equals_checked(dataset, monkeypatch):
    """A probe file read in chunks of whole lines (as one beyond MAX_FAST_BYTES is) takes the fast
    path and gives the checked reader's arrays."""
    import fgcal.io.fast_tables as ft

    ds = _checked(monkeypatch, dio.load_dataset, dataset)
    monkeypatch.setattr(ft, "CHUNK_CHARS", 97)
    chunks = list(ft.read_column_chunks(dataset / "probes.csv", dio.POINT_COLUMNS))
    assert len(chunks) > 10 and None not in chunks
    fast = tables._fast_point_table(dataset / "probes.csv", set(ds.pose_ids.tolist()),
                                 {b: i for i, b in enumerate(ds.tooling.balls)})
    assert fast is not None
    _same_points(fast, ds.probes)
