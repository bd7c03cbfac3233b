"""The HTML report rendered by a real browser (headless Chromium): tools/screenshot_report.py."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fgcal.estimation.calibrate import calibrate
from fgcal.report.document import write_report
from fgcal.studies.simulate import SimulationSettings, simulate

TOOL = Path(__file__).resolve().parents[1] / "tools" / "screenshot_report.py"
sys.path.insert(0, str(TOOL.parent))
from screenshot_report import find_chromium  # noqa: E402

FAIL_BANNER = np.array([0xfd, 0xe8, 0xe8])  # the .fail banner's background


@pytest.mark.skipif(find_chromium() is None,
                    reason="no chromium on this machine (apt-get install chromium, or set CHROMIUM=path)")
def test_report_in_a_browser(puma, tmp_path):
    from matplotlib.image import imread

    ds, _ = simulate(puma, np.random.default_rng(171), SimulationSettings(n_poses=12))
    result = calibrate(ds, puma)
    rng = np.random.default_rng(172)
    poses = [{"pose": i, "position_mm": float(e), "orientation_deg": 0.01, "before_position_mm": 5.0,
              "before_orientation_deg": 0.5, "xyz_mm": rng.uniform(0, 800, 3).tolist()}
             for i, e in enumerate(rng.uniform(0.01, 0.2, 30), start=1)]
    verification = {"format": "fgcal-verify/1", "n_poses": 30, "reference": "measured poses",
                    "position_mm": {"mean": 0.1, "rms": 0.1, "max": 0.2},
                    "orientation_deg": {"mean": 0.01, "rms": 0.01, "max": 0.01},
                    "before": {"position_mm": {"mean": 5, "rms": 5, "max": 5},
                               "orientation_deg": {"mean": 0.5, "rms": 0.5, "max": 0.5}}, "poses": poses}
    html = write_report(result, tmp_path / "report", verification, volume=puma.volume, tolerance=0.1)
    run = subprocess.run([sys.executable, str(TOOL), str(html), "--out", str(tmp_path / "shots"), "--width", "1000",
                          "--height", "2400", "--narrow", "480"], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    wide = imread(tmp_path / "shots" / "report-1000.png")[..., :3]
    narrow = imread(tmp_path / "shots" / "report-480.png")[..., :3]
    assert wide.shape[:2] == (2400, 1000) and narrow.shape[:2] == (2400, 480)
    for img in (wide, narrow):
        rgb = np.round(img * 255)
        # the FAIL banner is drawn near the top, styled by the page's CSS
        banner = np.all(np.abs(rgb[:600] - FAIL_BANNER) <= 2, axis=-1)
        assert banner.sum() > 5000
        # and the page is not blank: text, tables and figures cover a good part of it
        assert (rgb.min(axis=-1) < 200).mean() > 0.02
