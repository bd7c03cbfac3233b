"""The Python API (``fgcal.api``, exported by ``fgcal``) against the commands that call it.

A command's result is the function's (same dataset, same options: calibrate, verify, report),
every option default of a command is the function's, the README's Python example runs, and the
scripts of ``examples/`` run and check their own numbers. The warnings and notes a command prints
are the function's Python warnings.
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from hostile_util import call as run

import fgcal
from fgcal.api import calibration, compensation, planning, reporting, simulation, verification
from fgcal.cli import build_parser
from fgcal.cli.commands.common import default

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """A simulated PUMA 560 (16 poses) and 8 more poses of the same robot."""
    root = tmp_path_factory.mktemp("api")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fgcal.FgcalNote)
        fgcal.simulate("puma560", poses=16, seed=5, out=root / "ds")
        fgcal.simulate("puma560", poses=8, seed=6, truth=root / "ds" / "truth.yaml", out=root / "ver")
    return root


def test_calibrate_command_equals_function(data, tmp_path, capsys):
    code, out, _ = run(["calibrate", data / "ds", "--out", tmp_path / "cli.json", "--select", "odd"], capsys)
    assert code == 0
    result = fgcal.calibrate(data / "ds", poses="odd")
    result.save(tmp_path / "api.json")
    cli = json.loads((tmp_path / "cli.json").read_text())
    api = json.loads((tmp_path / "api.json").read_text())
    assert cli == api
    assert result.n_poses == 8
    # what the command prints is the function's summary of its result
    assert "\n".join(fgcal.calibration_summary(fgcal.CalibrationResult.load(tmp_path / "cli.json"))) in out
    # the same solve through the lower layer, without the API's checks and notes
    from fgcal.estimation.calibrate import calibrate as solve

    ds = fgcal.load_dataset(data / "ds")
    direct = solve(ds.select(ds.pose_ids[ds.pose_ids % 2 == 1]), fgcal.dataset_model(ds))
    np.testing.assert_allclose(direct.estimate, result.estimate, rtol=0, atol=1e-9)


def test_verify_and_report_commands_equal_functions(data, tmp_path, capsys):
    fgcal.calibrate(data / "ds").save(tmp_path / "r.json")
    code, out, _ = run(["verify", tmp_path / "r.json", data / "ver", "--out", tmp_path / "v.json"], capsys)
    assert code == 0
    ver = fgcal.verify(tmp_path / "r.json", data / "ver")
    assert json.loads((tmp_path / "v.json").read_text()) == json.loads(json.dumps(ver.to_dict()))
    assert "\n".join(fgcal.verification_summary(ver)) in out
    err = ver.to_dict()["truth"]["position_mm"]["max"]
    # report: the same files and the same verdict, passing and failing
    for tolerance, status in ((10 * err + 1.0, 0), (err / 10, 1)):
        cli_dir, api_dir = tmp_path / f"cli{status}", tmp_path / f"api{status}"
        code, out, _ = run(["report", tmp_path / "r.json", "--verify", tmp_path / "v.json", "--tolerance",
                            tolerance, "--out", cli_dir], capsys)
        written = fgcal.report(tmp_path / "r.json", api_dir, ver, tolerance=tolerance)
        assert code == status and written.passed is (status == 0)
        assert written.verdict.sentence() in out
        assert (cli_dir / "report.md").read_text() == (api_dir / "report.md").read_text()
        assert sorted(p.name for p in cli_dir.iterdir()) == sorted(p.name for p in api_dir.iterdir())


def test_the_face_exports_lazily():
    code = ("import sys, fgcal; heavy = [m for m in ('gtsam', 'matplotlib', 'scipy') if m in sys.modules]; "
            "assert not heavy, heavy; fgcal.calibrate; fgcal.Dataset; fgcal.simulate; "
            "assert 'gtsam' not in sys.modules and 'matplotlib' not in sys.modules; "
            "import fgcal.report.document; assert callable(fgcal.report); print(sorted(fgcal.__all__))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert out.returncode == 0, out.stderr
    names = set(eval(out.stdout))
    assert {"calibrate", "verify", "report", "simulate", "design", "compensate", "export_urdf",
            "CalibrationResult", "FgcalWarning"} <= names


def test_option_defaults_are_the_functions():
    """Each command's options, not given, parse to its function's defaults (read from the signature)."""
    import inspect

    parser = build_parser()
    commands = {"calibrate": (calibration.calibrate, ["ds", "--out", "r.json"]),
                "verify": (verification.verify, ["r.json", "ds"]),
                "report": (reporting.report, ["r.json", "--out", "rep"]),
                "simulate": (simulation.simulate, ["out"]),
                "design": (planning.design, ["--out", "plan.csv"]),
                "compensate": (compensation.compensate, ["r.json", "targets.csv"])}
    checked = 0
    for command, (function, argv) in commands.items():
        ns = vars(parser.parse_args([command, *argv]))
        for name, p in inspect.signature(function).parameters.items():
            if p.kind is not p.KEYWORD_ONLY or name in ("out", "force", "dataset", "progress", "title", "robot_ref",
                                                        "setup"):  # setup: built from the contact and station options
                continue
            if name == "exact_joints":
                assert ns[name] is p.default is False
            else:
                assert ns[name] == default(function, name), (command, name, ns[name])
            checked += 1
    assert checked >= 40


def test_readme_python_example_runs(tmp_path):
    text = (REPO / "README.md").read_text()
    section = text[text.index("## In Python"):]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    assert len([ln for ln in code.splitlines() if ln.strip()]) == 5
    assert "fgcal.calibrate" in code and "fgcal.verify" in code and "fgcal.report" in code
    env = dict(os.environ, PYTHONPATH=str(REPO))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, env=env,
                         timeout=600)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("PASS: the calibrated position error is within 0.2 mm at all 24")
    assert (tmp_path / "my-report" / "report.html").exists()


@pytest.mark.parametrize("script, expected", [
    ("own_robot_from_tracker_csv.py", r"PASS: the calibrated position error is within 0.1 mm at all 20"),
    ("custom_measurement_type.py", r"height gauge noise: declared 0.01 mm, estimated 0.0[23]\d* mm"),
    ("online_from_stream.py", r"online result from 25 poses; largest \|online - batch\| = [0-9.e-]+ batch sigma"),
])
def test_examples_run(script, expected, tmp_path):
    env = dict(os.environ, PYTHONPATH=str(REPO))
    out = subprocess.run([sys.executable, str(REPO / "examples" / script), str(tmp_path)], capture_output=True,
                         text=True, env=env, timeout=900)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]  # each script checks its own numbers
    assert re.search(expected, out.stdout), out.stdout[-2000:]


def test_warnings_and_notes_are_python_warnings(data, tmp_path, capsys):
    result = fgcal.calibrate(data / "ds")
    result.save(tmp_path / "r.json")
    with pytest.warns(fgcal.FgcalNote, match="16 of these poses were used in the calibration"):
        fgcal.verify(result, data / "ds")
    code, out, _ = run(["verify", tmp_path / "r.json", data / "ds"], capsys)
    assert code == 0 and "note: 16 of these poses were used in the calibration" in out
    # a unit mistake: radians in joints.csv is a warning of the function and of the command
    ds = fgcal.load_dataset(data / "ds")
    ds.joints_deg = np.radians(ds.joints_deg)
    fgcal.save_dataset(ds, tmp_path / "rad")
    with pytest.warns(fgcal.FgcalWarning, match="look like radians"):
        fgcal.check(tmp_path / "rad")
    code, _, err = run(["check", tmp_path / "rad"], capsys)
    assert code == 0 and "warning:" in err and "look like radians" in err


def test_bad_options_of_a_function_are_one_line_errors(data):
    cases = (({"noise": "guessed"}, "--noise 'guessed'"), ({"model": "neural"}, "--model"),
             ({"poses": "1-99"}, "spans more ids than the 16 poses"), ({"poses": [3, 99]}, "99 not in the dataset"),
             ({"payload": "a,b"}, "--payload"), ({"exclude": "j9.d"}, "--exclude"))
    for kwargs, words in cases:
        with pytest.raises(fgcal.FgcalError, match=re.escape(words)):
            fgcal.calibrate(data / "ds", **kwargs)


def test_simulate_keeps_the_simulators_own_call(puma):
    """``fgcal.simulate(model, rng, settings, truth=slots)`` (old scripts, the notebooks) is the simulator's call."""
    from fgcal.studies.simulate import SimulationSettings
    from fgcal.studies.simulate import simulate as simulator

    settings = SimulationSettings(n_poses=6)
    ds, notes = fgcal.simulate(puma, np.random.default_rng(3), settings)
    ref, _ = simulator(puma, np.random.default_rng(3), settings)
    np.testing.assert_array_equal(ds.joints_deg, ref.joints_deg)
    truth = puma.slots_from_file_units(np.array([ds.truth[n] for n in puma.slot_names]))
    again, _ = fgcal.simulate(puma, np.random.default_rng(4), settings, truth=truth)
    assert again.truth == ds.truth and not np.array_equal(again.joints_deg, ds.joints_deg)


def test_simulate_command_equals_function_with_contacts(tmp_path, capsys):
    """``fgcal simulate`` with two-socket plates and a tool ball writes what ``fgcal.simulate`` writes
    with the same :class:`~fgcal.studies.simulate_setup.SetupSimulation`: file for file."""
    from fgcal.studies.simulate_setup import SetupSimulation

    code, out, _ = run(["simulate", tmp_path / "cli", "--robot", "ur10", "--tool-ball", "0,0,40,5",
                        "--sockets", 1, "--configs", 6, "--seed", 7, "--joint-resolution", 0], capsys)
    assert code == 0 and "12 contacts" in out
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fgcal.FgcalNote)
        ds = fgcal.simulate("ur10", tool_ball="0,0,40,5", setup=SetupSimulation(placements=1, configs=6), seed=7,
                            joint_resolution=0.0, out=tmp_path / "api")
    assert len(ds.contacts) == 12
    for name in ("dataset.yaml", "joints.csv", "contacts.csv", "truth.yaml"):
        assert (tmp_path / "cli" / name).read_text() == (tmp_path / "api" / name).read_text(), name
