"""Large inputs: memory linear in the rows with a small constant; check's analysis in constant memory."""
import tracemalloc

import numpy as np
from conftest import random_joints

from fgcal.io.dataset_io import _point_table
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
