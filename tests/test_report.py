import subprocess
import sys

import numpy as np
import pytest

from fgcal.calibrate import CalibrationOptions, calibrate
from fgcal.plots import plot_convergence, plot_correlation, plot_poses, plot_residuals, plot_sigmas
from fgcal.report import write_report
from fgcal.result import save_result
from fgcal.simulate import SimulationSettings, simulate
from fgcal.uncertainty import parameter_table, verdict


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


def test_report_files(result, tmp_path):
    verification = {"format": "fgcal-verify/1", "n_poses": 2, "reference": "measured poses",
                    "position_mm": {"mean": 0.05, "rms": 0.05, "max": 0.06},
                    "orientation_deg": {"mean": 0.01, "rms": 0.01, "max": 0.02},
                    "before": {"position_mm": {"mean": 4, "rms": 4, "max": 5},
                               "orientation_deg": {"mean": 0.4, "rms": 0.4, "max": 0.5}},
                    "poses": [{"pose": 1, "position_mm": 0.05, "orientation_deg": 0.01, "before_position_mm": 4,
                               "before_orientation_deg": 0.4},
                              {"pose": 2, "position_mm": 0.06, "orientation_deg": 0.02, "before_position_mm": 5,
                               "before_orientation_deg": 0.5}]}
    html_path = write_report(result, tmp_path, verification, volume=np.array([[0, 0, 0], [1200, 1000, 800]]))
    text = html_path.read_text()
    assert "http" not in text and "src='data:image/png;base64," in text  # self-contained
    for name in ("sigma_lengths", "sigma_angles", "correlation", "residuals_probes_mm", "verify_position", "poses_3d"):
        assert (tmp_path / f"{name}.png").stat().st_size > 1000
    md = (tmp_path / "report.md").read_text()
    # every parameter's estimate is in both documents, as written in the result
    for p in result.parameters:
        line = next(ln for ln in md.splitlines() if ln.startswith(f"| {p.name} |"))
        assert f"{p.estimate:.10g}" in line and f"{p.sigma:.3g}" in line
        assert f">{p.name}<" in text
    assert "0.05 mm RMS" in md


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
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "report", str(tmp_path / "r.json"), "--out",
                          str(tmp_path / "rep")], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert (tmp_path / "rep" / "report.html").exists()
    (tmp_path / "bad.json").write_text("{}")
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "report", str(tmp_path / "r.json"), "--verify",
                          str(tmp_path / "bad.json"), "--out", str(tmp_path / "rep2")], capture_output=True, text=True)
    assert run.returncode == 2 and "not an fgcal-verify/1 file" in run.stderr
