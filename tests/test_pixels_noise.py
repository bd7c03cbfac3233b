"""Each camera's pixel noise estimated on its own (fgcal.estimation.group_noise): two cameras at
one mount see the same board on a Panda's tool (tests/pixel_sim.py twice from one seed: the same
robot, joints and corners, OpenCV's projection), one with 0.2 px of noise, the other with 0.6 px;
both declared 0.4 px. The estimate of each is within 10 % of its truth (about 2.5 of its own
relative sigma, 1/sqrt(2 x 600 corners x 0.96)), the sigmas used are the estimated ones, and the
corners are weighted by them (the better camera's reprojection residuals are the smaller)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

pytest.importorskip("cv2")

from pixel_sim import camera_dataset

from fgcal.api.calibration import calibration_summary
from fgcal.estimation.calibrate import CalibrationOptions, calibrate
from fgcal.estimation.result import load_result
from fgcal.io.dataset_io import dataset_model, load_dataset

DATA = Path(__file__).parent / "data" / "urdf"
PANDA = (DATA / "panda.urdf", {"base": "panda_link0", "tip": "panda_hand_tcp"})
TRUE = {"left": 0.2, "right": 0.6}


def _two_cameras(tmp: Path) -> Path:
    for name, sigma in TRUE.items():
        camera_dataset(tmp / name, *PANDA, np.random.default_rng(41), n_images=30, n_held_out=0, pixel_sigma=sigma)
    meta = yaml.safe_load((tmp / "left" / "dataset.yaml").read_text())
    cam = meta["cameras"]["left"]
    meta["cameras"] = {n: yaml.safe_load(yaml.safe_dump({**cam, "pixel_sigma": 0.4})) for n in TRUE}  # no aliases
    out = tmp / "both"
    out.mkdir()
    (out / "dataset.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    for f in ("joints.csv", "robot.urdf"):
        (out / f).write_bytes((tmp / "left" / f).read_bytes())
    rows = ["pose,camera,point,u,v"]
    for name in TRUE:
        rows += [r.replace(",left,", f",{name},", 1) for r in (tmp / name / "pixels.csv").read_text().split()[1:]]
    (out / "pixels.csv").write_text("\n".join(rows) + "\n")
    return out


def test_each_camera_has_its_own_noise(tmp_path):
    ds = load_dataset(_two_cameras(tmp_path))
    model = dataset_model(ds)
    res = calibrate(ds, model, CalibrationOptions())
    res.save(tmp_path / "r.json")
    back = load_result(tmp_path / "r.json")
    assert back.noise_groups == res.noise_groups  # the round trip
    for name, sigma in TRUE.items():
        n = res.noise_groups[f"pixels.{name}"]
        assert n.declared == pytest.approx(0.4) and n.unit == "px" and n.note == "estimated"
        assert n.estimated == pytest.approx(sigma, rel=0.10), (name, n.estimated)
        assert n.used == pytest.approx(n.estimated, rel=0.02)
    lines = "\n".join(calibration_summary(res))
    assert "pixels.left" in lines and "pixels.right" in lines  # reported per camera
    d = np.column_stack([res.residuals["pixels_du_px"], res.residuals["pixels_dv_px"]])
    cam = np.asarray(res.residuals["pixels_camera"]).astype(int)
    rms = [float(np.sqrt(np.mean(d[cam == k] ** 2))) for k in range(2)]
    assert rms[0] < 0.5 * rms[1]
    # with --noise declared the cameras keep their declared 0.4 px
    flat = calibrate(ds, model, CalibrationOptions(noise="declared"))
    assert flat.noise_groups["pixels.left"].used == pytest.approx(0.4)
