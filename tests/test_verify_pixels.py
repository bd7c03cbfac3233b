"""``verify`` on a camera's held-out images: the reprojection error (px) and the tool-point error
implied (mm), against the simulated truth (tests/pixel_sim.py: a perturbed Panda, OpenCV's
projection). The held-out images are nearly noise-free (0.001 px), so each image's PnP is the true
target pose and the implied error must be the model's true error: eye-to-hand the distance of the
board's points (tool points) predicted less true in the camera frame, eye-in-hand that of the
camera's centre (on the tool) in the board's frame; both computed here from the truth and the
result's own prediction (tests/test_pixels_simulated.py's composition of the mount and board)."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("cv2")

from contact_sim import UrdfChain
from pixel_sim import camera_dataset, cv_project
from test_pixels_simulated import _board_points, _values

from fgcal.estimation.calibrate import CalibrationOptions, calibrate
from fgcal.estimation.verification import verify
from fgcal.io.dataset_io import dataset_model, load_dataset

DATA = Path(__file__).parent / "data" / "urdf"
PANDA = (DATA / "panda.urdf", {"base": "panda_link0", "tip": "panda_hand_tcp"})


def _held_out(tmp: Path, truth, rng, sigma_px=0.001) -> Path:
    """The held-out joint sets of ``truth`` as a dataset of their own (the calibration's files beside)."""
    out = tmp / "held"
    out.mkdir()
    for name in ("dataset.yaml", "robot.urdf"):
        shutil.copy(tmp / name, out / name)
    true = UrdfChain(truth.urdf, truth.chain.get("base"), truth.chain.get("tip"))
    header = "pose," + ",".join(f"q{k + 1}" for k in range(true.n))
    joints = [f"{p}," + ",".join(repr(float(v)) for v in true.to_readings(q))
              for p, q in enumerate(truth.held_out, start=1)]
    rows = []
    for p, q in enumerate(truth.held_out, start=1):
        uv = cv_project(truth.board_in_camera(true.fk(q)), truth.points, truth.k)
        uv = uv + rng.normal(scale=sigma_px, size=uv.shape)
        rows += [f"{p},left,r{i // 5}c{i % 5},{float(u)!r},{float(v)!r}" for i, (u, v) in enumerate(uv)]
    (out / "joints.csv").write_text("\n".join([header, *joints]) + "\n")
    (out / "pixels.csv").write_text("\n".join(["pose,camera,point,u,v", *rows]) + "\n")
    return out


def _rigid(X, Y):
    """``T`` (4, 4) with ``Y = R X + t`` (Kabsch)."""
    cx, cy = X.mean(axis=0), Y.mean(axis=0)
    U, _, Vt = np.linalg.svd((X - cx).T @ (Y - cy))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    T = np.eye(4)
    T[:3, :3] = Vt.T @ D @ U.T
    T[:3, 3] = cy - T[:3, :3] @ cx
    return T


@pytest.mark.parametrize("mode", ["eye-to-hand", "eye-in-hand"])
def test_tool_point_error_is_the_true_error(tmp_path, mode):
    truth = camera_dataset(tmp_path, *PANDA, np.random.default_rng(21), mode=mode, n_images=14, n_held_out=8)
    ds = load_dataset(tmp_path)
    model = dataset_model(ds)
    result = calibrate(ds, model, CalibrationOptions())
    held = load_dataset(_held_out(tmp_path, truth, np.random.default_rng(22)))
    v = verify(result, held, model)
    d = v.to_dict()
    assert d["tool_point"] == ("target points" if mode == "eye-to-hand" else "camera centre")
    true = UrdfChain(truth.urdf, truth.chain.get("base"), truth.chain.get("tip"))
    m = len(truth.points)
    pred = _board_points(result, model, truth, _values(result), truth.held_out).reshape(-1, m, 3)
    want = []
    for k, q in enumerate(truth.held_out):
        T_true = truth.board_in_camera(true.fk(q))
        if mode == "eye-to-hand":
            seen = truth.points @ T_true[:3, :3].T + T_true[:3, 3]
            want.append(np.mean(np.linalg.norm(pred[k] - seen, axis=1)))
        else:
            T_pred = _rigid(truth.points, pred[k])
            want.append(np.linalg.norm(np.linalg.inv(T_pred)[:3, 3] - np.linalg.inv(T_true)[:3, 3]))
    got = np.array([p["tool_point_mm"] for p in d["poses"]])
    # PnP of 20 corners at 0.001 px, the board 1.6 m away: its own error is ~0.006 mm
    np.testing.assert_allclose(got, want, rtol=0.05, atol=0.01)
    assert 0.02 < np.mean(want) < 1.0  # a real error, not a zero that anything would match
    assert d["tool_point_mm"]["rms"] < 0.5 * d["before"]["tool_point_mm"]["rms"]  # the nominal robot's is larger
    assert d["position_mm"]["rms"] < 0.5 * d["before"]["position_mm"]["rms"]  # px: the reprojection error too
