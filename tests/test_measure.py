import csv
import subprocess
import sys

import numpy as np
import pytest

from fgcal.io.dataset_io import load_dataset, save_dataset
from fgcal.measurements.dataset import Noise
from fgcal.measurements.measure import POSE_ROW, measure_probes
from fgcal.robots.kinematics import forward, tool_points
from fgcal.robots.model import SLOT_NAMES, slots_from_file_units
from fgcal.robots.transforms import quaternion_to_matrix, so3_log
from fgcal.studies.simulate import SimulationSettings, simulate


def _true_poses(ds):
    x = slots_from_file_units(np.array([ds.truth[n] for n in SLOT_NAMES]))
    return dict(zip(ds.pose_ids.tolist(), forward(x, ds.joints_rad)))


@pytest.fixture(scope="module")
def clean(puma):
    # exact joint readings, so the truth at the readings is the truth
    ds, _ = simulate(puma, np.random.default_rng(60), SimulationSettings(n_poses=150, noise=Noise(0.01, 0.0)))
    return ds


def test_centres_are_within_their_propagated_noise(clean):
    m = measure_probes(clean)
    truth = _true_poses(clean)
    chi = []
    for p, b, xyz, cov in zip(m.centres.pose, m.centres.ball, m.centres.xyz, m.centre_covariance):
        err = xyz - tool_points(truth[p][None], clean.tooling.balls[b])[0, 0]
        chi.append(err @ np.linalg.solve(cov, err))
    assert len(chi) >= 0.99 * 450
    assert 2.6 < np.mean(chi) < 3.4  # chi-square with 3 dof


@pytest.mark.parametrize("method", ["svd", "paper"])
def test_poses_are_within_their_propagated_error(clean, method):
    m = measure_probes(clean, method=method)
    truth = _true_poses(clean)
    chi = []
    for p, xyz, quat, cov in zip(m.poses.pose, m.poses.xyz, m.poses.quat, m.pose_covariance):
        T = truth[p]
        err = np.concatenate([so3_log(quaternion_to_matrix(quat) @ T[:3, :3].T), xyz - T[:3, 3]])
        chi.append(err @ np.linalg.solve(cov, err))
    assert len(chi) >= 145
    # svd: chi-square with 6 dof (the fit ignores the centres' anisotropy, so a little above)
    lo, hi = (5.0, 8.0) if method == "svd" else (5.0, 12.0)
    assert lo < np.mean(chi) < hi, np.mean(chi)


def test_planted_outliers_are_flagged(puma):
    ds, _ = simulate(puma, np.random.default_rng(61), SimulationSettings(n_poses=100, outlier_fraction=0.02,
                                                                         outlier_size=0.3))
    m = measure_probes(ds)
    flagged = {(q.pose, q.ball) for q in m.flagged() if q.ball != POSE_ROW}
    planted = {(p, b) for p, b, _ in ds.truth_outliers}
    assert len(planted) >= 10
    assert planted <= flagged
    assert len(flagged - planted) <= 2  # false alarms: nominal 0.1% of 300 balls
    rejected = {q.pose for q in m.quality if q.ball == POSE_ROW and q.status != "ok"}
    assert rejected == {p for p, _ in planted}
    assert set(m.poses.pose.tolist()).isdisjoint(rejected)


def test_measure_cli_writes_a_derived_dataset(puma, tmp_path):
    ds, _ = simulate(puma, np.random.default_rng(62), SimulationSettings(n_poses=12, outlier_fraction=0.05))
    save_dataset(ds, tmp_path / "d")
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "measure", str(tmp_path / "d")],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    out = tmp_path / "d-measured"
    derived = load_dataset(out)
    assert derived.probes is None and derived.centres is not None and derived.poses is not None
    np.testing.assert_allclose(np.linalg.norm(derived.poses.quat, axis=1), 1.0, atol=1e-12)
    with open(out / "quality.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == ["pose", "ball", "rms_residual_mm", "status"]
    ball_rows = [r for r in rows if r["ball"] != POSE_ROW]
    pose_rows = [r for r in rows if r["ball"] == POSE_ROW]
    assert len(ball_rows) == 36 and len(pose_rows) == 12  # every ball and every pose has its line
    assert sum(r["status"] == "ok" for r in pose_rows) == len(derived.poses)
    assert 0 < derived.noise.centre_sigma < 0.03
    again = subprocess.run([sys.executable, "-m", "fgcal.cli", "measure", str(tmp_path / "d")],
                           capture_output=True, text=True)
    assert again.returncode == 2 and "already exists" in again.stderr


def test_measure_without_probes_is_an_error(puma, tmp_path):
    ds, _ = simulate(puma, np.random.default_rng(63), SimulationSettings(n_poses=3, levels=("centres",)))
    save_dataset(ds, tmp_path / "c")
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "measure", str(tmp_path / "c")],
                         capture_output=True, text=True)
    assert run.returncode == 2 and "no probes.csv" in run.stderr and "Traceback" not in run.stderr
