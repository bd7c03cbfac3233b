"""Large inputs: memory linear in the rows with a small constant; check's analysis in constant memory."""
import tracemalloc

import numpy as np
import pytest
from conftest import random_joints

from fgcal.errors import DatasetError
from fgcal.io.dataset_tables import _point_table
from fgcal.robots.identifiability import analyse, compact_jacobian, identification_jacobian


def test_probe_table_memory_per_row_is_small(tmp_path):
    n = 60_000
    rng = np.random.default_rng(1)
    xyz = rng.normal(500.0, 100.0, size=(n, 3))
    poses = np.arange(n) // 12 + 1
    balls = np.array(["A", "B", "C"])[(np.arange(n) // 4) % 3]
    path = tmp_path / "probes.csv"
    with open(path, "w") as fh:
        fh.write("pose,ball,x,y,z\n")
        fh.writelines(f"{p},{b},{x!r},{y!r},{z!r}\n" for p, b, (x, y, z) in zip(poses, balls, xyz.tolist()))
    known = set(range(1, poses.max() + 1))
    tracemalloc.start()
    obs = _point_table(path, known, {"A": 0, "B": 0, "C": 0})
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    np.testing.assert_array_equal(obs.xyz, xyz)
    np.testing.assert_array_equal(obs.ball, balls)
    np.testing.assert_array_equal(obs.pose, poses)
    assert obs.line[0] == 2 and obs.line[-1] == n + 1
    # the arrays themselves take 8 (pose) + 4 (ball) + 24 (xyz) + 8 (line) = 44 bytes a row; a list of
    # dicts took about 1000. The known-pose set is shared with the caller and counted here too.
    assert peak / n < 200, peak / n


def test_compact_jacobian_analyses_like_the_full_one(puma):
    q = random_joints(puma, 40, seed=2)
    offsets = np.array([[60.0, 0, 0], [0, 60.0, 0], [0, 0, 60.0]])
    for params in (puma.parameters(), puma.parameters(extra=["j1.theta"])):
        J = identification_jacobian(params, q, measurement=offsets)
        R = compact_jacobian(params, q, measurement=offsets, chunk=7)
        assert R.shape == (len(params.names), len(params.names))
        full, small = analyse(J, params.names), analyse(R, params.names)
        np.testing.assert_allclose(small.singular_values, full.singular_values, rtol=1e-9,
                                   atol=1e-9 * full.singular_values[0])
        assert small.rank == full.rank and small.redundant == full.redundant


def test_batch_size_limit_refuses_calibrate_and_bounds_check(puma, tmp_path, capsys, monkeypatch):
    from hostile_util import call, one_line_error, small_dataset

    import fgcal.api.calibration as calibrate_command
    import fgcal.api.checking as check_command

    small_dataset(puma, tmp_path / "ds", n_poses=6)
    for command in (calibrate_command, check_command):  # 6 poses x 3 balls x 4 points = 72 rows
        monkeypatch.setattr(command, "MAX_BATCH_ROWS", 50)
    code, _, err = call(["calibrate", tmp_path / "ds", "--out", tmp_path / "r.json"], capsys)
    one_line_error(code, err, "72 measurement rows (6 poses)", "--select")
    code, out, err = call(["check", tmp_path / "ds"], capsys)
    assert code == 0 and "72 rows are more than the 50" in out and "rank 30 of 30" in out


def test_checked_table_paths_give_the_fast_paths_arrays(tmp_path):
    """joints.csv and poses.csv read row by row into typed arrays (a cell in quotes sends a file to the
    checked path) equal the whole-column read; a repeated pose is named with both lines."""
    from fgcal.io.dataset_tables import _measurement_table, read_joints_and_stations
    from fgcal.measurements.pose import POSE

    rng = np.random.default_rng(265)
    q = rng.uniform(-170, 170, (50, 6))
    quat = rng.normal(size=(50, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    xyz = rng.uniform(-900, 900, (50, 3))
    joints = "pose,q1,q2,q3,q4,q5,q6\n" + "".join(f"{i + 1}," + ",".join(map(repr, r.tolist())) + "\n"
                                                  for i, r in enumerate(q))
    poses = "pose,x,y,z,qw,qx,qy,qz\n" + "".join(f"{i + 1}," + ",".join(map(repr, [*p.tolist(), *u.tolist()])) + "\n"
                                                 for i, (p, u) in enumerate(zip(xyz, quat)))
    results = []
    for quoted in (False, True):
        (tmp_path / "j.csv").write_text(joints.replace("\n1,", '\n"1",') if quoted else joints)
        (tmp_path / "p.csv").write_text(poses.replace("\n1,", '\n"1",') if quoted else poses)
        ids, qq, _ = read_joints_and_stations(tmp_path / "j.csv")
        obs = _measurement_table(tmp_path / "p.csv", POSE, set(range(1, 51)), {})
        results.append((ids, qq, obs.pose, obs.xyz, obs.quat))
    for fast, checked in zip(*results):
        np.testing.assert_array_equal(fast, checked)
    np.testing.assert_array_equal(results[1][1], q)
    (tmp_path / "j.csv").write_text(joints.replace("\n7,", "\n3,"))  # pose 3 again on line 8
    with pytest.raises(DatasetError, match=r"j.csv: line 8: duplicate pose id 3 \(first on line 4\)"):
        read_joints_and_stations(tmp_path / "j.csv")
    (tmp_path / "p.csv").write_text(poses.replace("\n9,", "\n2,"))
    with pytest.raises(DatasetError, match=r"p.csv: line 10: duplicate .* 2 \(first on line 3\)"):
        _measurement_table(tmp_path / "p.csv", POSE, set(range(1, 51)), {})


def test_import_table_is_streamed(tmp_path):
    """read_measurements holds one line of text at a time and the numbers in typed arrays: its peak is
    below the file's size (the whole text and a list of its lines took about 2.5 times it)."""
    from fgcal.io.table_io import ColumnSpec, read_measurements

    n = 8_000
    rng = np.random.default_rng(266)
    quat = rng.normal(size=(n, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    table = np.column_stack([rng.uniform(-3, 3, (n, 6)), rng.uniform(-1, 1, (n, 3)), quat])
    path = tmp_path / "log.csv"
    with open(path, "w") as fh:
        fh.write("q1,q2,q3,q4,q5,q6,x,y,z,qx,qy,qz,qw\n")
        np.savetxt(fh, table, fmt="%.12f", delimiter=",")
    spec = ColumnSpec(joints=tuple(f"q{i}" for i in range(1, 7)), joint_unit="rad", length_unit="m",
                      pose=("x", "y", "z", "qx", "qy", "qz", "qw"))
    tracemalloc.start()
    m = read_measurements(path, spec)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    np.testing.assert_allclose(m.joints_rad, table[:, :6], atol=1e-12)
    np.testing.assert_allclose(m.xyz, table[:, 6:9] * 1000.0, atol=1e-9)
    assert peak < path.stat().st_size, (peak, path.stat().st_size)


def test_an_overlong_line_is_refused_unread(tmp_path, monkeypatch):
    """A table line beyond the bound (1 MiB) is one error naming the line, read no further than the bound
    (a 2 GB line would have been split into a list of a billion fields)."""
    import fgcal.io.table_io as table_io

    monkeypatch.setattr(table_io, "MAX_TABLE_LINE", 1000)
    (tmp_path / "t.csv").write_text("a,b\n1,2\n" + "3," * 600 + "4\n")
    with pytest.raises(DatasetError, match=r"t.csv: line 3: longer than 1000 bytes"):
        table_io.read_columns(tmp_path / "t.csv", ["a", "b"])
