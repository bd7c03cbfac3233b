import csv
import subprocess
import sys

import numpy as np
import pytest

from fgcal.studies.study import RESULT_COLUMNS, run_trial, trials_for
from fgcal.studies.study_run import read_rows, run_study, study_figures


def test_trial_is_reproducible_and_sane():
    t = trials_for("fig13", trials=1, poses=12)[0]
    a, b = run_trial(t), run_trial(t)
    assert a["position_rms_mm"] == b["position_rms_mm"]
    assert 0.005 < a["position_rms_mm"] < 0.5 and a["position_max_mm"] >= a["position_rms_mm"]
    assert list(a) == RESULT_COLUMNS


def test_more_observations_calibrate_better():
    small = [run_trial(t)["position_rms_mm"] for t in trials_for("fig13", trials=6, poses=7, seed=1)]
    large = [run_trial(t)["position_rms_mm"] for t in trials_for("fig13", trials=6, poses=30, seed=1)]
    assert np.median(large) < 0.6 * np.median(small)


def test_resume_skips_finished_trials(tmp_path):
    trials = trials_for("fig13", trials=4, poses=10)
    calls = []

    def runner(t):
        calls.append(t.trial)
        return run_trial(t)

    run_study(trials[:2], tmp_path, workers=1, progress=False, runner=runner)
    rows = run_study(trials, tmp_path, workers=1, progress=False, runner=runner)
    assert sorted(calls) == [0, 1, 2, 3]  # trials 0 and 1 ran once
    assert sorted(r["trial"] for r in rows) == [0, 1, 2, 3]
    with open(tmp_path / "trials.csv") as fh:
        assert next(csv.reader(fh)) == RESULT_COLUMNS
    assert len(read_rows(tmp_path / "trials.csv")) == 4


def test_study_on_a_dask_cluster(tmp_path):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster:
        rows = run_study(trials_for("fig13", trials=4, poses=10), tmp_path, scheduler=cluster.scheduler_address,
                         progress=False)
    local = [run_trial(t) for t in trials_for("fig13", trials=4, poses=10)]
    by_trial = {r["trial"]: r["position_rms_mm"] for r in rows}
    assert by_trial == {r["trial"]: r["position_rms_mm"] for r in local}  # the same numbers wherever they ran


def test_cli_study_and_figures(tmp_path):
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "study", "experiment", "--trials", "1", "--workers", "2",
                          "--out", str(tmp_path)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    rows = read_rows(tmp_path / "trials.csv")
    assert sorted(r["n_poses"] for r in rows) == [7, 14, 21]
    assert (tmp_path / "experiment_position.png").stat().st_size > 5000
    assert "21 poses" in run.stdout
    figs = study_figures("fig13", [dict(r, study="fig13") for r in rows])
    assert "fig13" in figs
    bad = subprocess.run([sys.executable, "-m", "fgcal.cli", "study", "fig13", "--scheduler", "tcp://127.0.0.1:9",
                          "--out", str(tmp_path / "x"), "--trials", "1"], capture_output=True, text=True)
    assert bad.returncode == 2 and "cannot reach the Dask scheduler" in bad.stderr
