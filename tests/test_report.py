import json
import subprocess
import sys

import numpy as np
import pytest

from fgcal.estimation.calibrate import CalibrationOptions, calibrate
from fgcal.report.plots import plot_convergence, plot_correlation, plot_poses, plot_residuals, plot_sigmas
from fgcal.report.document import write_report
from fgcal.estimation.result import save_result
from fgcal.studies.simulate import SimulationSettings, simulate
from fgcal.report.accuracy import round_to_sigma
from fgcal.report.uncertainty import parameter_table, verdict


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
    assert run.returncode == 2 and "--tolerance must be a positive length" in run.stderr
    (tmp_path / "bad.json").write_text("{}")
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "report", str(tmp_path / "r.json"), "--verify",
                          str(tmp_path / "bad.json"), "--out", str(tmp_path / "rep2")], capture_output=True, text=True)
    assert run.returncode == 2 and "not an fgcal-verify/1 file" in run.stderr
