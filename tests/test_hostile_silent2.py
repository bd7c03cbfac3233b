"""Issue 26's remaining silent classes, each closed by one mechanism: stream records read by the
file readers' parsers, a joint reading used by one pose only, ..."""
import numpy as np
import pytest

from fgcal.online.stream import read_stream


@pytest.mark.parametrize("bad, words", [
    ("distance,1,A,-250", "length must be positive"),
    ("distance,1,A,0", "length must be positive"),
    ("probe,1,A,1,2,1e300", "absurdly large"),
    ("centre,1,A,nan,2,3", "not finite"),
    ("pose,1,0,0,0,2,0,0,0", "norm 2"),
])
def test_stream_refuses_what_the_files_refuse(bad, words):
    """A stream record is read by its measurement type's own parser (the one the dataset's files use)."""
    warnings = []
    lines = ["joints,1,0,0,0,0,0,0", bad, "distance,1,A,250.5", "end,1"]
    recs = list(read_stream(lines, {"A": [0, 0, 0]}, warn=warnings.append))
    assert len(warnings) == 1 and "line 2 skipped" in warnings[0] and words in warnings[0], warnings
    assert recs[0].distances == [("A", 250.5)]
    assert not recs[0].probes and not recs[0].centres and recs[0].T is None


def _tum_case(tmp_path, log_times, log_q, n_poses=8):
    """A TUM file of ``n_poses`` poses 2 s apart (t = 100, 102, ...) and a joint log of the given readings."""
    rng = np.random.default_rng(261)
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (n_poses, 1))
    xyz = rng.uniform(-1, 1, (n_poses, 3))
    t = 100.0 + 2.0 * np.arange(n_poses)
    (tmp_path / "t.tum").write_text("".join(" ".join(f"{v:.17g}" for v in [ti, *p, *qq]) + "\n"
                                            for ti, p, qq in zip(t, xyz, quat)))
    (tmp_path / "j.csv").write_text("time,a,b\n" + "".join(f"{ti:.17g},{a:.17g},{b:.17g}\n" for ti, (a, b) in
                                                          zip(log_times, log_q)))
    return tmp_path / "t.tum", tmp_path / "j.csv"


def test_a_joint_reading_is_one_pose_only(tmp_path):
    """Readings at every other pose's time under a wide tolerance: each reading joins its own pose only,
    the poses between are named (before, the reading was copied into both)."""
    from fgcal.io.tum import read_tum_with_joint_log

    q = np.random.default_rng(262).uniform(-1, 1, (4, 2))
    tum, log = _tum_case(tmp_path, 100.0 + 4.0 * np.arange(4), q)
    m = read_tum_with_joint_log(tum, log, ["a", "b"], tolerance=5.0)
    np.testing.assert_array_equal(m.line, [1, 3, 5, 7])
    np.testing.assert_allclose(m.joints_rad, q)
    assert len(m.skipped) == 4 and all("taken by line" in s for s in m.skipped), m.skipped
    assert m.skipped[0] == "line 2: its nearest joint reading (j.csv line 2) is taken by line 1, nearer in time " \
                           "(one reading, one pose)"


def test_repeated_log_timestamps_are_named(tmp_path):
    """A log whose readings share one timestamp: the first is kept, the others named, and it joins one pose."""
    from fgcal.io.tum import read_tum_with_joint_log

    q = np.random.default_rng(263).uniform(-1, 1, (8, 2))
    tum, log = _tum_case(tmp_path, [100.0] * 8, q)
    m = read_tum_with_joint_log(tum, log, ["a", "b"], tolerance=100.0)
    np.testing.assert_array_equal(m.line, [1])
    np.testing.assert_allclose(m.joints_rad, q[:1])
    assert sum("repeats an earlier reading" in s for s in m.skipped) == 7
    assert sum("taken by line 1" in s for s in m.skipped) == 7


def test_online_taking_no_pose_writes_nothing(tmp_path):
    """A ballbar run of 8 poses refuses every pose (its pivot unknown): no result of 'n_poses 0' is written,
    and such a file is refused on loading."""
    import dataclasses

    from hostile_util import run_cli

    from fgcal.errors import FgcalError
    from fgcal.estimation.result import load_result, save_result

    run = run_cli(["simulate", tmp_path / "bb", "--levels", "distances", "--poses", "8", "--seed", "4"])
    assert run.returncode == 0, run.stderr
    run = run_cli(["online", tmp_path / "bb", "--engine", "ekf", "--out", tmp_path / "r.json"])
    err = [ln for ln in run.stderr.splitlines() if ln.strip()]
    assert run.returncode == 2 and len(err) == 1 and "no pose taken (8 rejected; pose 1: " in err[0], run.stderr
    assert not (tmp_path / "r.json").exists()
    assert run_cli(["simulate", tmp_path / "p", "--poses", "8", "--seed", "4"]).returncode == 0
    run = run_cli(["calibrate", tmp_path / "p", "--out", tmp_path / "b.json"])
    assert run.returncode == 0, run.stderr
    empty = dataclasses.replace(load_result(tmp_path / "b.json"), n_poses=0)
    with pytest.raises(FgcalError, match="not written: the result is from no pose"):
        save_result(empty, tmp_path / "e.json")
    text = (tmp_path / "b.json").read_text().replace('"n_poses": 8', '"n_poses": 0', 1)
    (tmp_path / "e.json").write_text(text)
    with pytest.raises(FgcalError, match="n_poses: 0, a result from no pose"):
        load_result(tmp_path / "e.json")


def test_compliance_without_masses_is_refused(tmp_path):
    """--model compliance with every mass zero: no torque, no compliance; refused, not the geometric model
    under the compliance name."""
    from hostile_util import REPO, run_cli

    text = (REPO / "datasets/robots/ur10.yaml").read_text()
    import re

    (tmp_path / "z.yaml").write_text(re.sub(r"mass: [0-9.]+", "mass: 0", text))
    run = run_cli(["simulate", tmp_path / "d", "--robot", tmp_path / "z.yaml", "--poses", "12", "--seed", "2",
                   "--levels", "poses"])
    assert run.returncode == 0, run.stderr
    run = run_cli(["calibrate", tmp_path / "d", "--model", "compliance", "--out", tmp_path / "r.json"])
    err = [ln for ln in run.stderr.splitlines() if ln.strip()]
    assert run.returncode == 2 and len(err) == 1, run.stderr
    assert "no revolute joint's gravity torque varies by 1 N m" in err[0] and "--model geometric" in err[0]
    assert not (tmp_path / "r.json").exists()


@pytest.mark.parametrize("change", ["truncated", "rewritten"])
def test_follow_refuses_a_dataset_changed_under_it(puma, tmp_path, change):
    """--follow takes appended poses only: joints.csv cut back (or a taken pose's probe rows rewritten,
    as a rotated log would) ends the run naming the poses, instead of going on with rows no longer there."""
    import io

    from fgcal.errors import FgcalError
    from fgcal.io.dataset_io import load_dataset, save_dataset
    from fgcal.online.display import Display, follow
    from fgcal.online.run import OnlineRun
    from fgcal.studies.simulate import SimulationSettings, simulate

    ds, _ = simulate(puma, np.random.default_rng(264), SimulationSettings(n_poses=10))
    live = tmp_path / "live"
    save_dataset(ds.select(ds.pose_ids[:8]), live)
    run = OnlineRun(load_dataset(live), puma, "ekf")
    polls = []

    def stop():  # after the first poll (8 poses taken), the dataset is changed under the run
        polls.append(1)
        if len(polls) == 2:
            assert len(run.processed) == 8
            cut = ds.select(ds.pose_ids[:5]) if change == "truncated" else ds.select(ds.pose_ids[:10])
            if change == "rewritten":
                cut.probes = cut.probes.subset(cut.probes.pose != ds.pose_ids[2])
            save_dataset(cut, live, overwrite=True)
        return len(polls) > 4

    with pytest.raises(FgcalError, match="already taken" + (" are gone" if change == "truncated" else " changed")):
        follow(run, Display(run, stream=io.StringIO()), interval=0.0, settle=0.0, stop=stop)
    assert len(run.processed) == 8


def test_a_holdout_fraction_holding_out_nothing_is_refused():
    """--holdout 0.01 of 40 row groups rounds to none: refused with the least fraction that holds one out."""
    from fgcal.errors import FgcalError
    from fgcal.io.importer import to_datasets
    from fgcal.io.table_io import Measurements

    m = Measurements(line=np.arange(2, 42), joints_rad=np.zeros((40, 6)), xyz=np.zeros((40, 3)), source="s.csv")
    with pytest.raises(FgcalError, match=r"--holdout 0.01 of 40 row group\(s\) holds out none; give at least 0.0125"):
        to_datasets(m, "ur10", holdout=0.01)
