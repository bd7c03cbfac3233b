"""``fgcal design --dataset`` with pixels (fgcal.studies.design_camera), on tests/pixel_sim.py's
independent simulation (a perturbed Panda, OpenCV's projection, 0.3 px): 10 of 36 recorded images
chosen for the predicted error of the board's points; calibrated on them, the board at 20 held-out
poses is nearer the truth than with the median of 8 random 10-image plans (the truth: pixel_sim's
own forward kinematics; the prediction: the calibration's mount and board composed as in
tests/test_pixels_simulated.py). Candidates given as joints are usable only with the board in view."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("cv2")

from contact_sim import UrdfChain
from pixel_sim import camera_dataset
from test_pixels_simulated import _board_points, _values

from fgcal.estimation.calibrate import CalibrationOptions, calibrate
from fgcal.io.dataset_io import dataset_model, load_dataset
from fgcal.studies.design_dataset import design_from_dataset

DATA = Path(__file__).parent / "data" / "urdf"
PANDA = (DATA / "panda.urdf", {"base": "panda_link0", "tip": "panda_hand_tcp"})


def _held_out_rms(ds, model, truth, ids) -> float:
    """RMS (mm) of the board's points in the camera frame at the held-out poses, calibrated on ``ids``."""
    res = calibrate(ds.select(np.asarray(ids)), model, CalibrationOptions())
    true = UrdfChain(truth.urdf, truth.chain.get("base"), truth.chain.get("tip"))
    ref = np.concatenate([truth.points @ T[:3, :3].T + T[:3, 3]
                          for T in (truth.board_in_camera(true.fk(q)) for q in truth.held_out)])
    pred = _board_points(res, model, truth, _values(res), truth.held_out)
    return float(np.sqrt(np.mean(np.sum((pred - ref) ** 2, axis=1))))


def test_designed_images_beat_random_ones(tmp_path):
    truth = camera_dataset(tmp_path, *PANDA, np.random.default_rng(51), n_images=36, n_held_out=20)
    ds = load_dataset(tmp_path)
    model = dataset_model(ds)
    plan = design_from_dataset(ds, model, 10, random_sets=50, rng=np.random.default_rng(52))
    assert len(plan.pose_ids) == 10 == len(set(plan.pose_ids.tolist())) and plan.levels == ("pixels",)
    assert plan.n_usable == plan.n_candidates == 36
    lo, med, hi = plan.random_quartiles()
    assert plan.values["pred"] < lo  # predicted: better than three quarters of the random plans
    rng = np.random.default_rng(53)
    designed = _held_out_rms(ds, model, truth, plan.pose_ids)
    random = [_held_out_rms(ds, model, truth, rng.choice(ds.pose_ids, 10, replace=False)) for _ in range(8)]
    assert designed < np.median(random), (designed, sorted(random))
    assert any(line.startswith("  predicted position error RMS") for line in plan.summary())


def test_candidates_out_of_view_are_not_usable(tmp_path):
    """Joint sets given as candidates: the images' own joints see the board; the same joints with the
    wrist turned half a turn do not (the board faces away), and are left out."""
    camera_dataset(tmp_path, *PANDA, np.random.default_rng(54), n_images=14, n_held_out=0)
    ds = load_dataset(tmp_path)
    model = dataset_model(ds)
    q = ds.joints_deg.copy()
    away = q.copy()
    away[:, 5] += np.where(away[:, 5] > 0, -180.0, 180.0)  # the board turned away from the camera
    ids = np.arange(1, 2 * len(q) + 1)
    plan = design_from_dataset(ds, model, 6, candidates=(ids, np.vstack([q, away])), random_sets=5)
    assert plan.n_candidates == 28 and plan.n_usable == 14
    assert set(plan.pose_ids.tolist()) <= set(range(1, 15))
