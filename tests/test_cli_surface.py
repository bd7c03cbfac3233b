"""The frictions of a first hour on the commands' surface (issue 27), each reproduced and checked gone.

``report --tolerance`` without ``--verify``; help for every positional argument, a default and a
unit for every option; ``-v`` after the subcommand; ``q1..qn``; one rule for existing outputs;
negative zero and float noise in written files; ``fgcal demo`` writing into the working tree
without a verdict; the report of a joint-error result; ``calibrate --model compliance+map``'s
265 printed lines and its recommended model; log axes over narrow ranges and symlog ticks.
"""
from __future__ import annotations

import argparse
import json
import math
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from hostile_util import call as run

import fgcal
from fgcal.cli import build_parser
from fgcal.util.numbers import clean_number, format_number


def one_line(code, err, *words):
    assert code == 2 and "Traceback" not in err, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    for w in words:
        assert w in lines[0], err


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    root = tmp_path_factory.mktemp("surface")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fgcal.FgcalNote)
        fgcal.simulate("puma560", poses=12, seed=2, out=root / "ds")
    fgcal.calibrate(root / "ds").save(root / "r.json")
    return root


def _parsers(parser=None, prefix="fgcal"):
    """Every (sub)command's parser, nested ones (``import csv``) too."""
    parser = parser or build_parser()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, child in action.choices.items():
                yield f"{prefix} {name}", child
                yield from _parsers(child, f"{prefix} {name}")


def test_report_tolerance_without_verify_is_refused(calibrated, tmp_path, capsys):
    code, _, err = run(["report", calibrated / "r.json", "--tolerance", "0.2", "--out", tmp_path / "rep"], capsys)
    one_line(code, err, "--tolerance needs a verification", "--verify")
    assert not (tmp_path / "rep" / "report.html").exists()
    with pytest.raises(fgcal.FgcalError, match="needs a verification"):
        fgcal.report(calibrated / "r.json", tmp_path / "rep", tolerance=0.2)
    code, _, err = run(["report", calibrated / "r.json", "--tolerance", "-1", "--out", tmp_path / "rep"], capsys)
    one_line(code, err, "--tolerance", "out of range", "mm")  # the checked option type's refusal


def test_help_names_every_positional_default_and_unit():
    seen = 0
    for name, parser in _parsers():
        text = parser.format_help()
        assert "q1..q6" not in text, name
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction) or action.dest == "help":
                continue
            assert action.help, f"{name} {action.dest}: no help"
            helped = parser._get_formatter()._expand_help(action) if action.help else ""
            if action.option_strings and action.default not in (None, False, True, argparse.SUPPRESS):
                assert "default" in helped, f"{name} {action.option_strings[0]}: default not stated"
            seen += 1
    assert seen > 150
    helps = {n: p.format_help() for n, p in _parsers()}
    assert "iterated extended Kalman" in helps["fgcal online"]
    design = dict(_parsers())["fgcal design"]
    for option, unit in (("--cmm-sigma", "mm"), ("--joint-resolution", "deg"), ("--repeatability", "deg")):
        action = next(a for a in design._actions if option in a.option_strings)
        assert re.search(rf"\b{unit}\b", action.help), option
    assert "(default 0.01)" in " ".join(helps["fgcal design"].split())


def test_verbose_after_the_subcommand(calibrated, capsys):
    parser = build_parser()
    assert parser.parse_args(["check", str(calibrated / "ds"), "-v"]).verbose is True
    assert parser.parse_args(["-v", "check", str(calibrated / "ds")]).verbose is True
    assert parser.parse_args(["check", str(calibrated / "ds")]).verbose is False
    assert parser.parse_args(["import", "landgraf", "a.csv", "out", "-v"]).verbose is True
    code, out, _ = run(["check", calibrated / "ds", "-v"], capsys)
    assert code == 0 and "identifiability" in out


def test_outputs_are_replaced_only_with_force(calibrated, tmp_path, capsys):
    r, ds = calibrated / "r.json", calibrated / "ds"
    commands = {
        "calibrate": (["calibrate", ds, "--out", tmp_path / "r.json"], tmp_path / "r.json"),
        "verify": (["verify", r, ds, "--out", tmp_path / "v.json"], tmp_path / "v.json"),
        "export": (["export", r, "--urdf", tmp_path / "c.urdf"], tmp_path / "c.urdf"),
        "design": (["design", "--poses", "6", "--candidates", "40", "--out", tmp_path / "plan.csv"],
                   tmp_path / "plan.csv"),
    }
    for name, (argv, path) in commands.items():
        code, _, err = run(argv, capsys)
        assert code == 0 and path.exists(), (name, err)
        before = path.read_bytes()
        code, _, err = run(argv, capsys)
        one_line(code, err, str(path), "already exists", "--force")
        assert path.read_bytes() == before
        code, _, err = run([*argv, "--force"], capsys)
        assert code == 0, (name, err)
    code, _, err = run(["verify", r, ds, "--out", tmp_path / "v.json"], capsys)
    code, _, _ = run(["report", r, "--verify", tmp_path / "v.json", "--out", tmp_path / "rep"], capsys)
    assert code == 0
    code, _, err = run(["report", r, "--verify", tmp_path / "v.json", "--out", tmp_path / "rep"], capsys)
    one_line(code, err, "report.html", "already exists", "--force")
    code, _, err = run(["report", r, "--out", tmp_path / "rep", "--force"], capsys)
    assert code == 0
    # demo: a folder holding a demo's files is refused too
    (tmp_path / "demo").mkdir()
    (tmp_path / "demo" / "result.json").write_text("{}")
    code, _, err = run(["demo", "--out", tmp_path / "demo"], capsys)
    one_line(code, err, "result.json", "already exists", "--force")


def test_written_numbers_have_no_negative_zero_and_no_float_noise(calibrated, tmp_path):
    assert format_number(-0.0) == "0.0" and format_number(0.00731 * 1000 * -1) == "-7.31"
    assert format_number(275.6121 + 5.7e-14) == "275.6121" and format_number(1 / 3) == repr(1 / 3)
    assert format_number(float("nan")) == "nan" and format_number(1e-300) == "1e-300"
    # exact otherwise: random values are kept to the bit, any change is within two units of the last place
    rng = np.random.default_rng(0)
    values = np.concatenate([rng.normal(0, 1000, 5000), rng.uniform(-1, 1, 5000) * 10.0 ** rng.integers(-8, 8, 5000)])
    back = np.array([float(format_number(v)) for v in values])
    changed = back != values
    assert changed.sum() <= 2 and np.all(np.abs(back - values) <= 2 * np.array([math.ulp(v) for v in values]))
    assert clean_number(-0.0) == 0.0 and math.copysign(1, clean_number(-0.0)) == 1
    # the files: a URDF of the built-in robot, a model file, the deltas
    result = fgcal.CalibrationResult.load(calibrated / "r.json")
    text = fgcal.export_urdf(result)
    negative_zero = re.compile(r"(?<![\d.])-0(\.0*)?(?![\d.e])")
    assert "rpy=" in text and not negative_zero.search(text)
    fgcal.export(result, model=tmp_path / "m.yaml", deltas=tmp_path / "d.csv")
    for name in ("m.yaml", "d.csv"):
        assert not negative_zero.search((tmp_path / name).read_text()), name
    assert negative_zero.search('rpy="0.0 -0.0 0.0"') and negative_zero.search("base.theta: -0\n")
    from fgcal.io.dataset_io import write_csv

    write_csv(tmp_path / "x.csv", ["a", "b", "c"], [[-0.0, 0.00731 * 1000, 275.6121 + 5.7e-14]])
    assert (tmp_path / "x.csv").read_text().splitlines()[1] == "0.0,7.31,275.6121"


def test_demo_leaves_the_working_tree_alone_and_shows_the_verdict(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, out, err = run(["demo"], capsys)
    assert code == 0, err
    assert list(tmp_path.iterdir()) == []
    assert "PASS: the calibrated position error is within 0.2 mm at all 24 verification poses" in out
    folder = Path(out.split("results in ")[1].split("/\n")[0])
    assert (folder / "report" / "report.html").exists() and (folder / "verify.json").exists()


@pytest.fixture(scope="module")
def compliance(tmp_path_factory):
    """A UR10 with a known compliance and error map (tests/test_joint_errors.py's data), calibrated."""
    import sys

    sys.path.insert(0, str(Path(__file__).parent))
    from test_joint_errors import PHI, SPEC, _simulate

    root = tmp_path_factory.mktemp("compliance")
    ds, _ = _simulate(np.random.default_rng(21), 60, PHI, SPEC)
    fgcal.save_dataset(ds, root / "ds")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = fgcal.calibrate(root / "ds", model="compliance+map", exact_joints=True, folds=3, max_harmonics=3)
    result.save(root / "r.json")
    return root, result


def test_compliance_report_has_its_map_and_a_readable_correlation(compliance, tmp_path, monkeypatch):
    root, result = compliance
    n_block = len(result.joint_errors["names"])
    harmonics = result.joint_errors["spec"]["harmonics"]
    assert harmonics >= 1 and n_block == 2 + 6 * 2 * harmonics and len(result.names) == 30 + n_block
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        verification = fgcal.verify(result, root / "ds")
        written = fgcal.report(result, tmp_path / "rep", verification, tolerance=1.0)
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "could not be computed" not in md
    after = md.split("What next:", 1)[1].lstrip().splitlines()
    assert after[0].startswith("- ")  # "What next" has at least one item
    assert (tmp_path / "rep" / "joint_error_map.png").exists() and "joint_error_map.png" in md
    import fgcal.report.plots as plots

    assert plots.correlation_names(result) == result.names  # up to 60 labels all are shown
    monkeypatch.setattr(plots, "MAX_CORRELATION_LABELS", len(result.names) - 1)
    assert plots.correlation_names(result) == [n for n in result.names if n not in set(result.joint_errors["names"])]
    assert len(plots.plot_correlation(result).get_xticklabels()) == 30  # the geometry alone, not a smear
    # the map's curve is its coefficients' harmonic sum, computed here from the estimates
    curves = plots.joint_error_map_curves(result, n=5)
    q, corr, sigma = curves[1]
    est = {p.name: p.estimate for p in result.parameters}
    by_hand = sum(est[f"map.j1.sin{h}"] * np.sin(h * np.radians(q)) + est[f"map.j1.cos{h}"] * np.cos(h * np.radians(q))
                  for h in range(1, harmonics + 1))
    np.testing.assert_allclose(corr, by_hand, rtol=1e-12, atol=1e-12)
    assert np.all(sigma > 0) and q[0] == pytest.approx(result.joint_errors["joint_ranges_deg"][0][0])
    assert written.passed is not None


def test_compliance_summary_is_short_and_the_recommended_model_can_be_kept(compliance, tmp_path):
    root, result = compliance
    lines = fgcal.calibration_summary(result)
    n_block = len(result.joint_errors["names"])
    assert n_block > 12 and len(lines) < 30 + 40
    assert any(ln.startswith(f"  joint-error block: {n_block} parameters") for ln in lines)
    assert not any(ln.strip().startswith("map.j") for ln in lines)
    assert any(ln.strip().startswith("j2: compliance") for ln in lines)
    # geometric truth, compliance asked: the comparison recommends geometric; --keep recommended writes it
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fgcal.simulate("ur10", poses=40, seed=4, reflector="0,0,50", out=tmp_path / "geo")
        kept = fgcal.calibrate(tmp_path / "geo", model="compliance", keep="recommended", folds=3)
        asked = fgcal.calibrate(tmp_path / "geo", model="compliance", folds=3)
    selection = kept.joint_errors["selection"]
    assert selection["recommended"] == "geometric"
    assert not kept.joint_errors.get("names")
    assert {"j2.compliance", "j3.compliance"} <= set(asked.names) and "j2.compliance" not in kept.names
    assert any("--keep recommended writes the geometric one" in ln for ln in fgcal.calibration_summary(asked))


def test_axes_are_log_only_over_wide_ranges_and_symlog_ticks_do_not_touch():
    from fgcal.report.plots import plot_convergence, plot_error_distribution, plot_verification

    narrow = {"poses": [{"pose": i, "position_mm": 0.05 + 0.01 * i, "before_position_mm": 0.08 + 0.01 * i,
                         "orientation_deg": None, "before_orientation_deg": None} for i in range(10)]}
    assert plot_verification(narrow).get_yscale() == "linear"
    assert plot_error_distribution(narrow).get_xscale() == "linear"
    wide = {"poses": [{**p, "before_position_mm": 5.0 + p["pose"]} for p in narrow["poses"]]}
    assert plot_verification(wide).get_yscale() == "log"
    # convergence: mm and deg on one axis as final sigmas; symlog ticks 0, +-1, +-10, ... apart on screen
    n = np.arange(1, 31)
    est = np.stack([1.0 / n, 0.01 / n], axis=1)
    sig = np.stack([0.5 / np.sqrt(n), 0.002 / np.sqrt(n)], axis=1)
    ax = plot_convergence(n, est, sig, ["j2.a (mm)", "j2.alpha (deg)"])
    ax.figure.canvas.draw()
    assert ax.get_yscale() == "symlog" and "final sigma" in ax.get_ylabel()
    ticks = [t for t in ax.get_yticks() if ax.get_ylim()[0] <= t <= ax.get_ylim()[1]]
    assert 0.0 in ticks and 1.0 in ticks and -1.0 in ticks
    pixels = np.sort(ax.transData.transform(np.c_[np.zeros(len(ticks)), ticks])[:, 1])
    assert np.diff(pixels).min() > 12  # labels about 10 px tall do not overlap



def test_study_takes_a_robot(tmp_path, capsys):
    from fgcal.studies.study import run_trial, trials_for

    trials = trials_for("fig13", robot="ur10", trials=2, poses=12)
    assert [t.robot for t in trials] == ["ur10", "ur10"]
    row = run_trial(trials[0])
    assert row["robot"] == "ur10" and 0 < row["position_rms_mm"] < 0.5  # a UR10 calibrated from 12 poses
    assert trials_for("fig13", trials=1)[0].robot == "puma560"
    code, _, err = run(["study", "experiment", "--robot", "ur10", "--out", tmp_path / "st"], capsys)
    one_line(code, err, "PUMA 560 only")
    assert build_parser().parse_args(["study", "fig13", "--robot", "ur5"]).robot == "ur5"


def test_one_name_means_one_thing_across_the_commands(calibrated, tmp_path, capsys):
    """``--poses`` is a count (simulate, design, study), so calibrate and verify select with ``--select``;
    design's level is ``--levels`` as in simulate and calibrate; measure's unitless tolerance is
    ``--orthogonality-tolerance`` (report's ``--tolerance`` is mm). The old spellings still work, with
    a warning that names the new one; the two spellings give the same result."""
    ds = calibrated / "ds"
    code, _, err = run(["calibrate", ds, "--out", tmp_path / "new.json", "--select", "odd"], capsys)
    assert code == 0 and "warning: --poses" not in err
    code, _, err = run(["calibrate", ds, "--out", tmp_path / "old.json", "--poses", "odd"], capsys)
    assert code == 0 and "warning: --poses is now --select" in err
    new, old = (json.loads((tmp_path / f).read_text()) for f in ("new.json", "old.json"))
    assert new["parameters"] == old["parameters"] and new["n_poses"] == old["n_poses"] == 6

    parser = build_parser()
    sub = {a.dest: a for a in parser._actions if isinstance(a, argparse._SubParsersAction)}["command"].choices
    for command, new_name, old_name in (("calibrate", "--select", "--poses"), ("verify", "--select", "--poses"),
                                        ("design", "--levels", "--level"),
                                        ("measure", "--orthogonality-tolerance", "--tolerance")):
        actions = {s: a for a in sub[command]._actions for s in a.option_strings}
        assert actions[new_name].dest == actions[old_name].dest, command
        assert actions[old_name].help == argparse.SUPPRESS, command  # the old spelling is not advertised
    counted = [c for c in ("simulate", "design", "study")
               if any("--poses" in a.option_strings and a.type is not None for a in sub[c]._actions)]
    assert counted == ["simulate", "design", "study"]  # where --poses is shown, it is a count
