import json
import subprocess
import sys

import numpy as np
import pytest

from fgcal.estimation.calibrate import CalibrationOptions, calibrate
from fgcal.estimation.result import save_result
from fgcal.report.accuracy import round_to_sigma
from fgcal.report.document import write_report
from fgcal.report.plots import plot_convergence, plot_correlation, plot_poses, plot_residuals, plot_sigmas
from fgcal.report.uncertainty import parameter_table, verdict
from fgcal.studies.simulate import SimulationSettings, simulate


@pytest.fixture(scope="module")
def result(puma):
    ds, _ = simulate(puma, np.random.default_rng(80), SimulationSettings(n_poses=15))
    return calibrate(ds, puma, CalibrationOptions(extra=("j1.d",)))


def test_table_matches_the_result(result):
    rows = parameter_table(result)
    assert [r.name for r in rows[:30]] == result.names and rows[30].name == "j1.d"
    for row, p in zip(rows, result.parameters):
        assert row.estimate == p.estimate and row.sigma == p.sigma
        assert row.deviation == pytest.approx(p.estimate - p.nominal)
        lo, hi = row.interval95
        assert lo == pytest.approx(p.estimate - 1.96 * p.sigma, rel=1e-3) and hi > p.estimate
        assert row.z == pytest.approx((p.estimate - p.nominal) / p.sigma)
    held = rows[30]
    assert held.sigma is None and "not identifiable" in held.flags[0] and "base.pz" in held.flags[0]
    assert any("j1.d" in v for v in verdict(result))


def test_flags_correlation_and_implausible(result):
    import copy
    r = copy.deepcopy(result)
    r.parameters[10].estimate += 20.0  # j2.a off by 20 mm: not a manufacturing error
    rows = {row.name: row for row in parameter_table(r, correlation_limit=0.5)}
    assert any("plausible" in f for f in rows["j2.a"].flags)
    assert any("strongly correlated" in f for row in rows.values() for f in row.flags)


def _verification(n=2):
    rng = np.random.default_rng(81)
    poses = []
    for i in range(n):
        vec = rng.normal(0, 0.03, 3)
        poses.append({"pose": i + 1, "position_mm": float(np.linalg.norm(vec)), "orientation_deg": 0.01,
                      "before_position_mm": 4.0 + i, "before_orientation_deg": 0.4, "error_xyz_mm": vec.tolist(),
                      "before_error_xyz_mm": [4.0 + i, 0, 0], "xyz_mm": rng.uniform(0, 800, 3).tolist()})
    e = [p["position_mm"] for p in poses]
    return {"format": "fgcal-verify/1", "n_poses": n, "reference": "measured poses",
            "position_mm": {"mean": float(np.mean(e)), "rms": float(np.sqrt(np.mean(np.square(e)))),
                            "max": float(np.max(e))},
            "orientation_deg": {"mean": 0.01, "rms": 0.01, "max": 0.02},
            "before": {"position_mm": {"mean": 4, "rms": 4, "max": 5},
                       "orientation_deg": {"mean": 0.4, "rms": 0.4, "max": 0.5}}, "poses": poses}


def test_report_files(result, tmp_path):
    verification = _verification(40)
    verification["poses"][5]["position_mm"] = 2.0  # an outlier
    verification["poses"][6].update(position_mm=9.0, before_position_mm=5.0)  # worse than nominal
    html_path = write_report(result, tmp_path, verification, volume=np.array([[0, 0, 0], [1200, 1000, 800]]),
                             tolerance=1.0)
    text = html_path.read_text()
    assert "http" not in text and "src='data:image/png;base64," in text  # self-contained
    for name in ("sigma_lengths", "sigma_angles", "correlation", "residuals_probes_mm", "verify_position",
                 "verify_workspace", "verify_distribution", "poses_3d"):
        assert (tmp_path / f"{name}.png").stat().st_size > 1000
    md = (tmp_path / "report.md").read_text()
    assert "FAIL: 2 of 40 verification poses are beyond 1 mm" in md and "poses 7, 6" in md
    assert "class='banner fail'" in text
    row = next(ln for ln in md.splitlines() if ln.startswith("| 6 |"))
    assert "outlier" in row and "beyond the tolerance" in row
    row = next(ln for ln in md.splitlines() if ln.startswith("| 7 |"))
    assert "worse than the nominal model" in row
    # every parameter's estimate is in both documents, to the digits its sigma supports
    for p in result.parameters:
        line = next(ln for ln in md.splitlines() if ln.startswith(f"| {p.name} |"))
        est, sig = round_to_sigma(p.estimate, p.sigma)
        assert f"| {est} | {sig} |" in line and abs(float(est) - p.estimate) <= 0.05 * p.sigma
        assert f">{p.name}<" in text
    # captions are sentences, not file stems
    captions = [c.split("</figcaption>")[0] for c in text.split("<figcaption>")[1:]]
    assert len(captions) == len(list(tmp_path.glob("*.png"))) and all(c.endswith(".") and " " in c for c in captions)
    assert "verification pose (id)" not in text  # 40 poses: ranked, one tick per pose would be a smear


def test_report_passes_and_says_what_next(result, tmp_path):
    verification = _verification(12)
    write_report(result, tmp_path, verification, tolerance=1.0)
    md = (tmp_path / "report.md").read_text()
    assert "**PASS: the calibrated position error is within 1 mm at all 12 verification poses" in md
    write_report(result, tmp_path / "no", None)
    md = (tmp_path / "no" / "report.md").read_text()
    assert "No verdict" in md and "fgcal verify" in md
    # j1.d is held: redundant with base.pz, it costs nothing (over random joints when verify gives none)
    assert "j1.d (0.5 mm) costs nothing measurable" in md and "Over 200 random joint sets" in md


def test_plot_api_returns_axes(result):
    from matplotlib.figure import Figure
    fig = Figure()
    ax = fig.add_subplot()
    assert plot_sigmas(result, "mm", ax=ax) is ax
    for fn in (plot_correlation, lambda r: plot_residuals(r, "probes_mm"), plot_poses):
        assert fn(result).figure is not None
    ax = plot_convergence([1, 2, 3], np.ones((3, 2)), np.ones((3, 2)) * 0.1, ["a", "b"])
    assert len(ax.lines) >= 2


def test_cli_report(result, tmp_path):
    save_result(result, tmp_path / "r.json")
    (tmp_path / "v.json").write_text(json.dumps(_verification(5)))
    # exit status 0 on pass, 1 on fail (the report is written either way), 2 on bad input
    for tol, status, word in (("1", 0, "PASS"), ("0.001", 1, "FAIL")):
        run = subprocess.run([sys.executable, "-m", "fgcal.cli", "report", str(tmp_path / "r.json"), "--verify",
                              str(tmp_path / "v.json"), "--tolerance", tol, "--out", str(tmp_path / tol)],
                             capture_output=True, text=True)
        assert run.returncode == status and word in run.stdout, run.stderr
        assert word in (tmp_path / tol / "report.html").read_text()
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "report", str(tmp_path / "r.json"), "--tolerance", "-1",
                          "--out", str(tmp_path / "rep4")], capture_output=True, text=True)
    assert run.returncode == 2 and "--tolerance" in run.stderr and "must be > 0" in run.stderr
    (tmp_path / "bad.json").write_text("{}")
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "report", str(tmp_path / "r.json"), "--verify",
                          str(tmp_path / "bad.json"), "--out", str(tmp_path / "rep2")], capture_output=True, text=True)
    assert run.returncode == 2 and "not an fgcal-verify/1 file" in run.stderr


def test_pose_residuals_at_the_readings_are_kept_and_name_the_outlier(puma, tmp_path, capsys):
    """Per-pose training residuals: at the readings (against plain forward kinematics here), after the
    joints moved, saved and loaded, and a pose with a wrong joint reading named an outlier."""
    from fgcal.estimation.result import load_result
    from fgcal.report.report_sections import build_content, training_flags
    from fgcal.robots.kinematics import tool_points

    ds, _ = simulate(puma, np.random.default_rng(31), SimulationSettings(n_poses=18, levels=("centres",)))
    bad = int(ds.pose_ids[7])
    ds.joints_deg[ds.row_of([bad])[0], 1] += 0.2  # the controller reported joint 2 0.2 deg off
    r = calibrate(ds, puma)
    assert [p.pose for p in r.pose_residuals] == r.pose_ids
    # at the readings: the calibrated chain's centres at the reported joints against the measured ones
    c = ds.centres
    q = puma.joints_to_internal(ds.joints_deg[ds.row_of(c.pose)])
    offsets = np.array([ds.tooling.balls[b] for b in c.ball])[:, None, :]
    d = np.linalg.norm(tool_points(puma.forward(r.slot_vector(), q), offsets)[:, 0] - c.xyz, axis=1)
    kept = np.ones(len(c), dtype=bool)
    kept[[o.index for o in r.outliers]] = False
    assert {o.pose for o in r.outliers} <= {bad}  # the wrong reading may make a centre look gross
    for p in r.pose_residuals:
        m = (c.pose == p.pose) & kept
        assert p.n == m.sum() and p.excluded == np.sum(c.pose == p.pose) - m.sum() and p.rotation_deg is None
        assert p.rms_mm == pytest.approx(np.sqrt(np.mean(d[m] ** 2)), rel=1e-9, abs=1e-12)
        assert p.max_mm == pytest.approx(d[m].max(), rel=1e-9, abs=1e-12)
        assert p.nominal_mm > p.rms_mm
    worst = max(r.pose_residuals, key=lambda p: p.rms_mm)
    # 0.2 deg at ~0.8 m is ~3 mm at the reading; the joint variable absorbs it after the solve
    assert worst.pose == bad and worst.rms_mm > 1.0 and worst.moved_mm < 0.1 * worst.rms_mm
    save_result(r, tmp_path / "r.json")
    back = load_result(tmp_path / "r.json")
    assert back.pose_residuals == r.pose_residuals
    flags = {f.pose: f.flags for f in training_flags(back)}
    assert any(x.startswith("outlier") for x in flags[bad])
    assert [p for p, fl in flags.items() if any(x.startswith("outlier") for x in fl)] == [bad]
    section = next(s for s in build_content(back).sections if s.title == "Residuals at the calibration poses")
    text = " ".join(b.text for b in section.blocks)
    assert f"Outlier poses (residual at the readings more than 3.5 robust sigma above the median): {bad}." in text
    table = next(b for b in section.blocks if b.kind == "table")
    assert table.rows[0][0] == str(bad) and "outlier" in table.rows[0][-1]
    from fgcal.api.calibration import calibration_summary

    text = "\n".join(calibration_summary(back))  # what `fgcal calibrate` prints
    assert f"outlier poses (residual at the joint readings): {bad} ({worst.rms_mm:.3g} mm)" in text


def _first_verdict(result, verification):
    from fgcal.report.report_sections import build_content

    top = build_content(result, verification).sections[0]
    items = next(b.items for b in top.blocks if b.kind == "ul")
    return items[0]


def test_the_verdict_budget_includes_the_joint_readings(puma):
    """Purely geometric data whose joints are rounded to 0.05 deg: the error at new poses is what the
    parameters, the tracker and the rounding explain. Without the joint readings in the budget
    (the previous verdict) the same error would be blamed on the model."""
    import copy

    from fgcal.estimation.verification import verify
    from fgcal.measurements.dataset import Noise
    from fgcal.report.budget import error_budget

    noise = Noise(cmm_sigma=0.005, joint_resolution=0.05)
    settings = SimulationSettings(n_poses=40, noise=noise)
    ds, _ = simulate(puma, np.random.default_rng(82), settings)
    truth = puma.slots_from_file_units(np.array([ds.truth[n] for n in puma.slot_names]))
    ver, _ = simulate(puma, np.random.default_rng(83), SimulationSettings(n_poses=30, noise=noise), truth=truth)
    result = calibrate(ds, puma)
    v = verify(result, ver, puma).to_dict()
    first = _first_verdict(result, v)
    assert "is what the parameters' uncertainty" in first and "joint readings" in first, first
    joints = puma.joints_to_internal(np.array([p["joints_deg"] for p in v["poses"]]))
    b = error_budget(result, joints, None)
    # the rounding's share dominates the tracker's: sigma_q = 0.05/sqrt(12) deg through a ~1 m arm
    assert b.joints_mm > 3 * b.instrument_mm
    assert v["position_mm"]["rms"] > 2 * b.instrument_mm  # so the previous budget could not explain it
    no_joints = copy.deepcopy(result)
    del no_joints.noise["joints"]
    assert _first_verdict(no_joints, v).startswith("The model, not the noise")
