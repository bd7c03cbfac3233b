import numpy as np
import pytest
from plain_dh import fk_from_truth

from fgcal.errors import FgcalError
from fgcal.io.dataset_io import load_dataset, save_dataset
from fgcal.measurements.dataset import Noise
from fgcal.robots.kinematics import forward
from fgcal.studies.plans import ball_access
from fgcal.studies.simulate import SimulationSettings, simulate

EXACT = Noise(cmm_sigma=0.0, joint_resolution=0.0)


def _centre(ds, pose, ball):
    row = int(np.nonzero(ds.pose_ids == pose)[0][0])
    T = fk_from_truth(ds.truth, ds.joints_deg[row])
    return T[:3, :3] @ ds.tooling.balls[ball] + T[:3, 3]


@pytest.mark.parametrize("plan", ["random", "paper"])
def test_exact_data_is_reproduced_by_an_independent_implementation(puma, tmp_path, plan):
    ds, notes = simulate(puma, np.random.default_rng(11),
                         SimulationSettings(n_poses=12 if plan == "random" else None, plan=plan, noise=EXACT,
                                            levels=("probes", "centres", "poses")))
    assert notes == []
    save_dataset(ds, tmp_path / "d")
    back = load_dataset(tmp_path / "d")  # from the files, as another program would read them
    for p, b, xyz in zip(back.probes.pose, back.probes.ball, back.probes.xyz):
        assert abs(np.linalg.norm(xyz - _centre(back, p, b)) - back.tooling.radius) < 1e-6
    for p, b, xyz in zip(back.centres.pose, back.centres.ball, back.centres.xyz):
        np.testing.assert_allclose(xyz, _centre(back, p, b), atol=1e-6)
    for p, xyz in zip(back.poses.pose, back.poses.xyz):
        row = int(np.nonzero(back.pose_ids == p)[0][0])
        np.testing.assert_allclose(xyz, fk_from_truth(back.truth, back.joints_deg[row])[:3, 3], atol=1e-6)


def test_paper_plan_has_48_poses_within_limits_and_volume(puma):
    ds, notes = simulate(puma, np.random.default_rng(12), SimulationSettings(plan="paper"))
    assert ds.n_poses == 48 and notes == []
    assert puma.in_limits(ds.joints_rad).all()
    counts = {p: len(set(ds.probes.ball[ds.probes.pose == p])) for p in ds.pose_ids}
    assert set(counts.values()) == {3}
    assert np.all(ds.probes.xyz >= puma.volume[0]) and np.all(ds.probes.xyz <= puma.volume[1])
    # wrist joints exercised: each spans most of its range
    span = np.ptp(ds.joints_rad[:, 3:], axis=0) / np.ptp(puma.joint_limits[3:], axis=1)
    assert np.all(span > 0.6)


def test_random_plan_respects_limits_and_access(puma):
    ds, _ = simulate(puma, np.random.default_rng(13), SimulationSettings(n_poses=30, noise=EXACT))
    assert ds.n_poses == 30 and puma.in_limits(ds.joints_rad).all()
    x = np.array([ds.truth[n] for n in __import__("fgcal.robots.model", fromlist=["SLOT_NAMES"]).SLOT_NAMES])
    from fgcal.robots.model import slots_from_file_units
    ok, _, _ = ball_access(forward(slots_from_file_units(x), ds.joints_rad), puma.tooling, puma.volume)
    assert np.all(ok.sum(axis=1) >= 3)


def test_noise_has_the_requested_size(puma):
    noise = Noise(cmm_sigma=0.01, joint_resolution=0.01)
    ds, _ = simulate(puma, np.random.default_rng(14), SimulationSettings(n_poses=200, noise=noise,
                                                                         levels=("centres",)))
    # joint readings are on the 0.01 deg grid
    np.testing.assert_allclose(ds.joints_deg * 100, np.round(ds.joints_deg * 100), atol=1e-6)
    # centre errors against the truth at the *readings*: the rounding (sigma 0.0029 deg on each
    # joint, ~1 m lever arms) adds several times the CMM's own noise
    err = np.array([xyz - _centre(ds, p, b) for p, b, xyz in zip(ds.centres.pose, ds.centres.ball, ds.centres.xyz)])
    assert 0.02 < err.std() < 0.08
    exact, _ = simulate(puma, np.random.default_rng(14), SimulationSettings(
        n_poses=200, noise=Noise(cmm_sigma=0.01, joint_resolution=0.0), levels=("centres",)))
    err = np.array([xyz - _centre(exact, p, b) for p, b, xyz in zip(exact.centres.pose, exact.centres.ball,
                                                                    exact.centres.xyz)])
    assert abs(err.std() - 0.01) < 0.0008 and abs(err.mean()) < 0.001


def test_truth_deviates_as_requested(puma):
    from fgcal.robots.model import SLOT_NAMES, slots_to_file_units
    devs = []
    for seed in range(40):
        ds, _ = simulate(puma, np.random.default_rng(seed), SimulationSettings(n_poses=1))
        devs.append([ds.truth[n] for n in SLOT_NAMES])
    devs = np.array(devs) - slots_to_file_units(puma.nominal)
    idx = {n: i for i, n in enumerate(SLOT_NAMES)}
    assert 0.3 < devs[:, idx["j2.a"]].std() < 0.75            # 0.5 mm
    assert 3.0 < devs[:, idx["base.px"]].std() < 7.5          # 5 mm
    assert np.all(devs[:, idx["j1.theta"]] == 0)              # absorbed slots stay nominal


def test_outliers_are_planted_and_recorded(puma):
    ds, _ = simulate(puma, np.random.default_rng(15), SimulationSettings(
        n_poses=20, noise=EXACT, outlier_fraction=0.1, outlier_size=1.0))
    assert 5 <= len(ds.truth_outliers) <= 50
    flagged = set(ds.truth_outliers)
    seen = {}
    for p, b, xyz in zip(ds.probes.pose, ds.probes.ball, ds.probes.xyz):
        k = seen.get((p, b), 0)
        seen[(p, b)] = k + 1
        off = abs(np.linalg.norm(xyz - _centre(ds, p, b)) - ds.tooling.radius)
        assert (off > 0.01) == ((int(p), str(b), k) in flagged)


def test_repeatability_moves_the_arm_off_its_readings(puma):
    ds, _ = simulate(puma, np.random.default_rng(16), SimulationSettings(
        n_poses=50, noise=Noise(0.0, 0.0, repeatability=0.01), levels=("centres",)))
    err = np.array([xyz - _centre(ds, p, b) for p, b, xyz in zip(ds.centres.pose, ds.centres.ball, ds.centres.xyz)])
    assert 0.02 < np.sqrt((err ** 2).sum(axis=1).mean()) < 0.5


def test_paper_plan_rejects_a_pose_count(puma):
    with pytest.raises(FgcalError, match="48 poses"):
        simulate(puma, np.random.default_rng(0), SimulationSettings(plan="paper", n_poses=20))
