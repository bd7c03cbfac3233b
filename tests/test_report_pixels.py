"""The report's reprojection residuals per image and over the image plane, on data simulated by
tests/pixel_sim.py (OpenCV's projection, 0.3 px): with the intrinsics given right the residuals are
the noise everywhere on the image; with a distortion error planted in the given intrinsics (k3
0.3 off, nothing estimated to absorb it) they grow towards the corners, and the report says so."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("cv2")

from pixel_sim import camera_dataset

from fgcal.estimation.calibrate import CalibrationOptions, calibrate
from fgcal.estimation.result import load_result
from fgcal.io.dataset_io import dataset_model, load_dataset
from fgcal.report.camera_report import CORNER_RATIO, image_plane_residuals
from fgcal.report.document import render_markdown, write_report
from fgcal.report.report_sections import build_content

DATA = Path(__file__).parent / "data" / "urdf"
PANDA = (DATA / "panda.urdf", {"base": "panda_link0", "tip": "panda_hand_tcp"})


def _result(tmp: Path, k3_error: float):
    camera_dataset(tmp, *PANDA, np.random.default_rng(31), n_images=30, n_held_out=0)
    if k3_error:
        text = (tmp / "dataset.yaml").read_text()
        k3 = float(re.search(r"k3: ([-0-9.e]+)", text).group(1))
        (tmp / "dataset.yaml").write_text(text.replace(f"k3: {k3!r}", f"k3: {k3 + k3_error!r}"))
    ds = load_dataset(tmp)
    model = dataset_model(ds)
    res = calibrate(ds, model, CalibrationOptions(noise="declared"))
    res.save(tmp / "r.json")  # the residuals' places survive the round trip
    return load_result(tmp / "r.json"), ds


def _radial_rms(ds, res, ip):
    """The residuals' RMS (px) of the corners nearest and farthest from the principal point (a third each)."""
    cx, cy = ds.setup.fixtures["left"].intrinsics[2:4]
    r = np.hypot(ip.u - cx, ip.v - cy)
    d2 = np.sum(ip.d**2, axis=1)
    lo, hi = np.quantile(r, [1 / 3, 2 / 3])
    return np.sqrt(d2[r <= lo].mean()), np.sqrt(d2[r >= hi].mean())


def test_a_planted_distortion_error_shows_at_the_corners(tmp_path):
    good, ds = _result(tmp_path / "good", 0.0)
    bad, _ = _result(tmp_path / "bad", 0.3)
    (g,), (b,) = image_plane_residuals(good), image_plane_residuals(bad)
    assert g.grid_n.sum() == b.grid_n.sum() == len(ds.pixels) and (g.grid_n[[0, 0, 2, 2], [0, 2, 0, 2]] > 0).all()
    # right intrinsics: the noise (0.3 px per coordinate, 0.42 px per corner) in every region
    assert np.nanmax(g.grid_rms) < 0.6 and g.corner_ratio < CORNER_RATIO
    # the planted error: residuals growing with the radius (measured: the outer third's RMS 2.9 times
    # the inner third's), so the corner regions' exceed the centre's (measured 2.85 times)
    near, far = _radial_rms(ds, bad, b)
    assert far > 2.0 * near
    assert b.corner_ratio > 2.0 and b.grid_rms[1, 1] < b.grid_rms[[0, 0, 2, 2], [0, 2, 0, 2]].min()
    per_image = {p: rms for p, _, rms, _ in b.per_image}
    assert sorted(per_image) == sorted(ds.pose_ids.tolist())
    d2 = np.sum(b.d**2, axis=1)
    first = int(ds.pose_ids[0])
    assert per_image[first] == pytest.approx(np.sqrt(d2[np.asarray(bad.residuals["pixels_pose"]) == first].mean()))
    out = write_report(bad, tmp_path / "rep")
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "Reprojection residuals: camera left" in md and "a lens distortion the model misses" in md
    assert (tmp_path / "rep" / "image_plane_left.png").stat().st_size > 1000 and out.exists()
    md = render_markdown(build_content(good))  # the same content, without drawing the figures
    assert "Reprojection residuals: camera left" in md and "no sign of a distortion the model misses" in md
