"""Results against the wrong data: study resumed with other settings, verify/report of another robot."""
import json
from dataclasses import asdict

import numpy as np
import pytest
from hostile_util import call, one_line_error, small_dataset

from fgcal.errors import FgcalError
from fgcal.estimation.result import CalibrationResult, ParameterEstimate, save_result
from fgcal.robots.robot_file import model_to_dict
from fgcal.studies.study import RESULT_COLUMNS, trials_for
from fgcal.studies.study_run import run_study


def _fake_runner(t):
    """A study row with the trial's settings and a made-up error: the bookkeeping is under test."""
    row = {k: v for k, v in asdict(t).items() if k in RESULT_COLUMNS}
    row.update({k: 0.1 for k in RESULT_COLUMNS if k not in row})
    return {k: row[k] for k in RESULT_COLUMNS}


@pytest.mark.parametrize("change, named", [({"seed": 1}, "seed 0 there, 1 now"),
                                           ({"poses": 12}, "n_poses 10 there, 12 now")])
def test_study_refuses_to_resume_other_settings(tmp_path, change, named):
    first = trials_for("fig13", trials=3, poses=10, seed=0)
    rows = run_study(first, tmp_path, workers=1, progress=False, runner=_fake_runner)
    assert len(rows) == 3
    kw = {"trials": 3, "poses": 10, "seed": 0, **change}
    calls = []
    with pytest.raises(FgcalError, match=named) as err:
        run_study(trials_for("fig13", **kw), tmp_path, workers=1, progress=False,
                  runner=lambda t: calls.append(t) or _fake_runner(t))
    assert "refusing to resume" in str(err.value) and not calls


def test_study_with_fewer_trials_reports_only_those(tmp_path):
    run_study(trials_for("fig13", trials=4, poses=10), tmp_path, workers=1, progress=False, runner=_fake_runner)
    rows = run_study(trials_for("fig13", trials=2, poses=10), tmp_path, workers=1, progress=False,
                     runner=_fake_runner)
    assert sorted(r["trial"] for r in rows) == [0, 1]


def _result_of(model, robot_name):
    """A result of ``model`` at its nominal geometry (what a calibration of a perfect robot gives)."""
    slots = dict(zip(model.slot_names, map(float, model.slots_to_file_units(model.nominal))))
    params = [ParameterEstimate(n, "mm", slots[n], slots[n], 0.01) for n in model.identifiable_names()]
    return CalibrationResult(robot=robot_name, n_poses=6, parameters=params, covariance=np.eye(len(params)) * 1e-4,
                             slots=slots, robot_model=model_to_dict(model))


def test_verify_refuses_a_result_of_another_robot(puma, ur10, tmp_path, capsys):
    small_dataset(puma, tmp_path / "puma-ds", n_poses=4)
    save_result(_result_of(ur10, "ur10"), tmp_path / "ur10.json")
    code, _, err = call(["verify", tmp_path / "ur10.json", tmp_path / "puma-ds"], capsys)
    one_line_error(code, err, "robot puma560 is not the robot of the result (ur10)")
    save_result(_result_of(puma, "puma560"), tmp_path / "puma.json")
    code, out, err = call(["verify", tmp_path / "puma.json", tmp_path / "puma-ds", "--out", tmp_path / "v.json"],
                          capsys)
    assert code == 0, err
    # the nominal result verifies exactly as the nominal model does
    v = json.loads((tmp_path / "v.json").read_text())
    assert v["robot"] == "puma560" and v["position_mm"]["rms"] == pytest.approx(v["before"]["position_mm"]["rms"])
    code, _, err = call(["report", tmp_path / "ur10.json", "--verify", tmp_path / "v.json", "--out",
                         tmp_path / "rep"], capsys)
    one_line_error(code, err, "a verification of a puma560 result", "for ur10")
