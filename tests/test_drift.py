"""Following a drifting robot (fgcal.online.drift): a UR10 whose geometry drifts during the session,
simulated with the independent kinematics of tests/plain_dh.py; the one-step-ahead prediction
beats the batch model trained on the first 60%, and the filter tracks the drifting truth."""

import json

import numpy as np
import pytest
from plain_dh import fk_from_truth

from fgcal.errors import FgcalError
from fgcal.estimation.calibrate import CalibrationOptions, calibrate
from fgcal.estimation.joint_errors import JointErrorSpec
from fgcal.estimation.verification import verify
from fgcal.measurements.dataset import Dataset, Noise, PoseObservations
from fgcal.online.drift import DriftLevels, choose_drift, follow_drift
from fgcal.online.drift_result import DriftResult, load_drift_result, save_drift_result
from fgcal.robots.model import Tooling
from fgcal.robots.robot_file import load_model
from fgcal.robots.transforms import matrix_to_quaternion

UR10 = load_model("ur10")
LOW = np.radians([-170, -170, -160, -170, -170, -170])
HIGH = np.radians([170, -10, 160, 170, 170, 170])
SPEC = JointErrorSpec(harmonics=1, map_joints=(2, 3), map_sigma=200e-6)
N = 240
DRIFT = {"j2.theta": 0.03, "j3.a": 0.4}  # deg, mm over the session (a warming arm)
MAP = {2: 60e-6, 3: -40e-6}  # rad: the true error sin(q_J) of joints 2 and 3
SIGMA_POS, SIGMA_ROT = 0.01, 0.001  # mm, deg


def _rot(axis, a):
    c, s = np.cos(a), np.sin(a)
    i, j = [(1, 2), (0, 2), (0, 1)][axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s if axis != 1 else s, s if axis != 1 else -s, c
    return R


def _session(seed, drift=True):
    """A time-ordered session: the truth (file units) at pose k is the start plus k/(N-1) of DRIFT."""
    rng = np.random.default_rng(seed)
    start = dict(zip(UR10.slot_names, UR10.slots_to_file_units(UR10.nominal)))
    for n in start:  # a calibrated-sized deviation of every slot
        start[n] += rng.normal(0, 0.02 if n.endswith(("theta", "alpha", "beta", "phi", "psi")) else 0.2)
    q = rng.uniform(LOW, HIGH, (N, 6))
    T = np.empty((N, 4, 4))
    truths = []
    for k in range(N):
        truth = dict(start)
        if drift:
            for n, total in DRIFT.items():
                truth[n] += total * k / (N - 1)
        truths.append(truth)
        q_act = q[k].copy()
        for j, c in MAP.items():
            q_act[j - 1] += c * np.sin(q[k, j - 1])
        T[k] = fk_from_truth(truth, np.degrees(q_act))
        T[k, :3, 3] += rng.normal(0, SIGMA_POS, 3)
        w = rng.normal(0, np.radians(SIGMA_ROT), 3)
        T[k, :3, :3] = _rot(0, w[0]) @ _rot(1, w[1]) @ _rot(2, w[2]) @ T[k, :3, :3]
    ids = np.arange(1, N + 1)
    noise = Noise(cmm_sigma=SIGMA_POS, pose_position_sigma=SIGMA_POS, pose_orientation_sigma=SIGMA_ROT)
    ds = Dataset(robot="ur10", tooling=Tooling(0.0, {"P": np.zeros(3)}), noise=noise, provenance={}, pose_ids=ids,
                 joints_deg=np.degrees(q))
    ds.poses = PoseObservations(ids, T[:, :3, 3], matrix_to_quaternion(T[:, :3, :3]))
    return ds, truths


@pytest.fixture(scope="module")
def drifting():
    return _session(3)


BASE = DriftLevels(length_mm=1e-3, angle_deg=1e-4, map_urad=0.3)


def test_drift_following_beats_the_batch_and_tracks_the_truth(drifting):
    ds, truths = drifting
    train = int(0.6 * N)
    levels, nf, table = choose_drift(ds, UR10, SPEC, train, BASE, factors=(0.0, 1.0, 3.0, 10.0), noise_factors=(1.0,))
    assert levels.length_mm > 0 and levels.map_urad == 0  # the geometry drifts, the map does not
    f = follow_drift(ds, UR10, SPEC, levels, nf)
    online = np.array([s.error_mm for s in f.steps[train:]])
    batch = calibrate(ds.select(ds.pose_ids[:train]), UR10, CalibrationOptions(joint_errors=SPEC))
    later = verify(batch, ds.select(ds.pose_ids[train:]), UR10).after.position_mm
    print(f"later 40%: online {online.mean():.4f} mm (max {online.max():.4f}), batch {later.mean():.4f} "
          f"(max {later.max():.4f}); drift x{levels.length_mm / BASE.length_mm:g}")
    assert online.mean() < 0.5 * later.mean()
    assert online.max() < later.max()
    # the drifting parameters at the end: the truth's, within 3 sigma, far from where they started
    names, est, sig = f.estimate()
    for n in DRIFT:
        k = names.index(n)
        assert abs(est[k] - truths[-1][n]) < 3 * sig[k], n
        assert abs(truths[0][n] - truths[-1][n]) > 5 * sig[k], n
    for j, c in MAP.items():  # the map's coefficients
        k = names.index(f"map.j{j}.sin1")
        assert abs(est[k] - c * 1e6) < 3 * sig[k]
    # the one-step-ahead covariance is not overconfident (every parameter drifts in the filter, two
    # in the truth: it is cautious), and every later pose is taken
    nis = np.array([s.nis for s in f.steps[train:]])
    assert nis.mean() < 6 * 1.5 and all(s.taken for s in f.steps[train:])


def test_without_drift_the_likelihood_keeps_the_parameters_still():
    ds, _ = _session(4, drift=False)
    levels, _, table = choose_drift(ds, UR10, SPEC, int(0.6 * N), BASE, factors=(0.0, 10.0), noise_factors=(1.0,))
    assert levels == DriftLevels()
    assert table[0]["loglik"] > max(t["loglik"] for t in table[1:])


def test_result_round_trip_and_bad_files(drifting, tmp_path):
    ds, _ = drifting
    f = follow_drift(ds, UR10, SPEC, BASE, 1.0, stop_after=30)
    res = DriftResult.of(f, "compliance+map", SPEC.to_dict(), train=20, choice=[{"geometry": 1.0}], dataset="d")
    path = tmp_path / "drift.json"
    save_drift_result(res, path)
    back = load_drift_result(path)
    assert back.to_dict() == res.to_dict()
    assert back.summary()["n"] == 10 and back.summary()["mean"] == pytest.approx(res.errors(20).mean())
    d = json.loads(path.read_text())
    d["steps"][3]["error_mm"] = -1.0
    path.write_text(json.dumps(d))
    with pytest.raises(FgcalError, match=r"drift.json: pose 4: error_mm"):
        load_drift_result(path)
    d["format"] = "other"
    path.write_text(json.dumps(d))
    with pytest.raises(FgcalError, match="not an fgcal-drift/1 file"):
        load_drift_result(path)


@pytest.mark.parametrize("spec", [SPEC, JointErrorSpec(compliance=(2, 3), harmonics=1, map_joints=(2,))])
def test_the_block_jacobian_matches_finite_differences(drifting, spec):
    ds, _ = drifting
    f = follow_drift(ds, UR10, spec, BASE, 1.0, stop_after=0)
    from fgcal.online.drift import _records

    rec = _records(ds, UR10)[5]
    rng = np.random.default_rng(0)
    x = f.x + rng.normal(0, 1e-4, len(f.x))
    x[f.n_geometric:] = rng.normal(0, 30e-6, len(x) - f.n_geometric)  # rad, rad/Nm
    _, H, _, _, _ = f._rows(rec, x)
    h = 1e-7
    for k in list(range(3)) + list(range(len(x) - 4, len(x))):
        d = np.zeros(len(x))
        d[k] = h
        num = (f._rows(rec, x + d)[0] - f._rows(rec, x - d)[0]) / (2 * h)
        np.testing.assert_allclose(H[:, k], num, rtol=1e-5, atol=1e-6 * max(1.0, np.abs(num).max()))


def test_bad_drift_levels_are_refused():
    with pytest.raises(FgcalError, match="drift length_mm"):
        DriftLevels(length_mm=-1.0)


def test_the_command_writes_the_series_and_refuses_what_it_does_not_do(drifting, tmp_path, capsys):
    from fgcal.cli import main
    from fgcal.io.dataset_io import save_dataset

    ds, _ = drifting
    path = tmp_path / "session"
    save_dataset(ds.select(ds.pose_ids[:60]), path)
    out = tmp_path / "drift.json"
    from fgcal.estimation.result import save_result

    batch = calibrate(ds.select(ds.pose_ids[:30]), UR10, CalibrationOptions(joint_errors=SPEC))
    save_result(batch, tmp_path / "batch.json")
    rc = main(["online", str(path), "--model", "compliance+map", "--harmonics", "1", "--drift", "0.003", "0.0003",
               "--map-drift", "0.1", "--train", "0.5", "--out", str(out), "--baseline", str(tmp_path / "batch.json")])
    printed = capsys.readouterr().out
    assert rc == 0, printed
    res = load_drift_result(out)
    assert res.train == 30 and len(res.steps) == 60 and res.levels.length_mm == 0.003
    assert res.names[-2:] == ["map.j6.sin1", "map.j6.cos1"] and "j2.compliance" in res.names
    assert f"mean {res.summary()['mean']:.4f} mm" in printed
    later = verify(batch, ds.select(ds.pose_ids[30:60]), UR10).after.position_mm
    assert res.extra["baseline"]["summary"]["mean"] == pytest.approx(later.mean())
    assert f"the batch result at the same poses: mean {later.mean():.4f} mm" in printed
    assert main(["online", str(path), "--model", "compliance+map", "--stdin"]) == 2
    assert "--stdin is for the engines without it" in capsys.readouterr().err
    assert main(["online", str(path), "--model", "geometric", "--engine", "ukf"]) == 2
    assert "--engine ukf does not apply" in capsys.readouterr().err
