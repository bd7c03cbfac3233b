"""Several instrument stations (DESIGN.md 8.3): a tracker reflector seen from three stations, from
data made by an independent URDF forward kinematics (tests/contact_sim.py) with known station
frames; one solve estimates the robot and the stations; ``fgcal calibrate DS1 DS2 DS3`` equals
one dataset with a station column; the station rows' Jacobians against differences."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from contact_sim import UrdfChain, new_poses, perturbed_urdf
from predict_util import predicted_points

from fgcal.estimation.calibrate import CalibrationOptions, build_graph, calibrate
from fgcal.io.dataset_io import dataset_model, load_dataset
from fgcal.robots.transforms import euler_zyx_trans

DATA = Path(__file__).parent / "data" / "urdf"
CHAIN = {"base": "panda_link0", "tip": "panda_hand_tcp"}
REFLECTOR = np.array([20.0, -10.0, 40.0])
SIGMA = 0.01
# Station frames in the world (A is the world): phi, theta, psi (deg), px, py, pz (mm)
STATIONS = {"B": [30.0, 2.0, -1.0, 800.0, -300.0, 50.0], "C": [-60.0, -1.5, 3.0, -200.0, 900.0, -20.0]}


def _write(out: Path, nominal_text: str, q_deg, ids, xyz, station, with_column=True):
    out.mkdir(parents=True)
    (out / "robot.urdf").write_text(nominal_text)
    meta = {"format": "fgcal-dataset/1", "robot": "robot.urdf", "chain": CHAIN,
            "tool": {"radius": 0.0, "balls": {"R": [float(v) for v in REFLECTOR]}},
            "noise": {"cmm_sigma": SIGMA, "joint_resolution": 0.0}, "provenance": {"generator": "test_stations"}}
    if with_column:
        meta["stations"] = ["A", "B", "C"]
    (out / "dataset.yaml").write_text(yaml.safe_dump(meta))
    head = "pose," + ",".join(f"q{i}" for i in range(1, q_deg.shape[1] + 1)) + (",station" if with_column else "")
    rows = [f"{p}," + ",".join(repr(float(v)) for v in q) + (f",{s}" if with_column else "")
            for p, q, s in zip(ids, q_deg, station)]
    (out / "joints.csv").write_text(head + "\n" + "\n".join(rows) + "\n")
    (out / "centres.csv").write_text("pose,ball,x,y,z\n" + "\n".join(
        f"{p},R," + ",".join(repr(float(v)) for v in x) for p, x in zip(ids, xyz)) + "\n")


def _simulate(tmp: Path, seed: int, n: int = 90, pose_seed=None):
    """The true (perturbed) Panda of ``seed`` measured from three stations, a third of the poses each
    (poses and noise from ``pose_seed``, default the same seed)."""
    rng = np.random.default_rng(seed)
    nominal = (DATA / "panda.urdf").read_text()
    true_text = perturbed_urdf(nominal, rng, CHAIN["base"], CHAIN["tip"])
    if pose_seed is not None:
        rng = np.random.default_rng(pose_seed)
    true = UrdfChain(true_text, CHAIN["base"], CHAIN["tip"])
    lo, hi = np.maximum(true.limits[:, 0], -np.pi), np.minimum(true.limits[:, 1], np.pi)
    q = rng.uniform(lo, hi, size=(n, true.n))
    world = true.point(q, REFLECTOR) + rng.normal(scale=SIGMA, size=(n, 3))
    station = np.array(["A", "B", "C"])[np.arange(n) % 3]
    local = world.copy()
    for name, pose in STATIONS.items():  # what station B measures: T_B^-1 applied to world points
        T = euler_zyx_trans(*np.radians(pose[:3]), *pose[3:])
        sel = station == name
        local[sel] = (world[sel] - T[:3, 3]) @ T[:3, :3]
    ids = np.arange(1, n + 1)
    _write(tmp / "all", nominal, true.to_readings(q), ids, local, station)
    for name in "ABC":  # the same poses as three datasets, one per station, without a column
        sel = station == name
        _write(tmp / name, nominal, true.to_readings(q)[sel], ids[sel], local[sel], station[sel], with_column=False)
    return true_text


def test_station_rows_and_jacobians(tmp_path):
    _simulate(tmp_path, 0, n=30)
    ds = load_dataset(tmp_path / "all")
    assert len(ds.centres) == 10 and len(ds.station_centres) == 20
    model = dataset_model(ds)
    graph, state, _ = build_graph(ds, model, model.parameters().names, CalibrationOptions(joint_noise=False))
    rng = np.random.default_rng(3)
    state.theta = state.theta + rng.normal(scale=1e-3, size=state.theta.shape)
    lin = graph.linearise(state)
    pose, rows = graph.factor_rows("station_centres")
    obs = ds.station_centres

    def residuals(theta):
        x = graph.params.full(theta, graph.held)
        s = graph.setup_values(theta)
        T = model.forward(x, graph.readings[pose])
        pred = np.einsum("nij,j->ni", T[:, :3, :3], REFLECTOR) + T[:, :3, 3]
        out = []
        for p_, m, st in zip(pred, obs.xyz, obs.station):
            e = graph.setup.block(s, st)
            Ts = euler_zyx_trans(*e)
            out.append((p_ - (Ts[:3, :3] @ m + Ts[:3, 3])) / graph.sigmas.station_centre)
        return np.concatenate(out)

    assert np.allclose(lin.r[pose[:, None], rows].ravel(), residuals(state.theta), atol=1e-9)
    J = lin.J_theta[pose[:, None], rows].reshape(-1, len(state.theta))
    h = 1e-6
    num = np.array([(residuals(state.theta + h * e) - residuals(state.theta - h * e)) / (2 * h)
                    for e in np.eye(len(state.theta))]).T
    assert np.allclose(J, num, rtol=1e-5, atol=1e-5 * np.abs(num).max())


def _errors(result, model, true_text, seed):
    check = new_poses(true_text, CHAIN, REFLECTOR, np.random.default_rng(100 + seed), 60)
    q = model.joints_to_internal(check.readings)
    points, J, cov = predicted_points(result.slot_vector(model), result, model, q, REFLECTOR)
    predicted = np.sqrt(np.mean(np.einsum("nip,pq,niq->n", J, cov, J)))
    err = np.sqrt(np.mean(np.sum((points - check.points) ** 2, axis=1)))
    return err, predicted


def test_three_stations_calibrate_to_the_noise_limit(tmp_path):
    errors, predicted = [], []
    for seed in range(4):
        true_text = _simulate(tmp_path / str(seed), seed)
        ds = load_dataset(tmp_path / str(seed) / "all")
        model = dataset_model(ds)
        result = calibrate(ds, model, CalibrationOptions())
        est = result.setup["estimated"]
        for name, pose in STATIONS.items():  # the stations found, against the truth
            d = np.subtract(est[name]["pose"], pose)
            assert np.all(np.abs(d[:3]) < 0.01) and np.all(np.abs(d[3:]) < 0.5), (name, d)
        err, pred = _errors(result, model, true_text, seed)
        errors.append(err)
        predicted.append(pred)
        assert result.noise["station_centres"].used == pytest.approx(SIGMA, rel=0.35)
    print("stations", errors, predicted)
    assert np.sqrt(np.mean(np.square(errors))) < 1.5 * np.sqrt(np.mean(np.square(predicted))), (errors, predicted)


def test_several_datasets_equal_one_with_a_station_column(tmp_path):
    _simulate(tmp_path, 5, n=60)
    one = tmp_path / "one.json"
    many = tmp_path / "many.json"
    for args, out in (([tmp_path / "all"], one), ([tmp_path / "A", tmp_path / "B", tmp_path / "C"], many)):
        run = subprocess.run([sys.executable, "-m", "fgcal.cli", "calibrate", *map(str, args), "--out", str(out)],
                             capture_output=True, text=True)
        assert run.returncode == 0, run.stderr
    from fgcal.estimation.result import load_result

    a, b = load_result(one), load_result(many)
    assert a.names == b.names
    assert np.max(np.abs(a.estimate - b.estimate) / a.sigma) < 1e-6
    assert np.allclose(a.sigma, b.sigma, rtol=1e-6)


def test_verify_from_the_stations_found(tmp_path):
    """New poses measured from stations B and C: verify puts them in the world by the stations the
    calibration found; the error against the truth there is the calibration's."""
    _simulate(tmp_path / "train", 6)
    _simulate(tmp_path / "other", 6, pose_seed=60)  # the same robot, other poses and noise
    ds = load_dataset(tmp_path / "train" / "all")
    model = dataset_model(ds)
    result = calibrate(ds, model, CalibrationOptions())
    from fgcal.estimation.verification import verify

    ver = verify(result, load_dataset(tmp_path / "other" / "all"), model).to_dict()
    # the verification set is measured with noise SIGMA: its RMS is that plus the model's small error
    assert SIGMA * np.sqrt(3) * 0.7 < ver["position_mm"]["rms"] < SIGMA * np.sqrt(3) * 1.5 + 0.01
    assert ver["before"]["position_mm"]["rms"] > 10 * ver["position_mm"]["rms"]
    other = load_dataset(tmp_path / "other" / "all")
    other.station_centres.station[:] = "D"
    with pytest.raises(Exception, match="station D is not a station of the calibration"):
        verify(result, other, model)


def test_gtsam_engine_equals_the_batch_and_online_and_design_take_stations(tmp_path):
    _simulate(tmp_path, 7, n=45)
    ds = load_dataset(tmp_path / "all")
    model = dataset_model(ds)
    batch = calibrate(ds, model, CalibrationOptions())
    other = calibrate(ds, model, CalibrationOptions(engine="gtsam"))
    assert other.names == batch.names
    assert np.max(np.abs(other.estimate - batch.estimate) / batch.sigma) < 1e-5
    assert np.allclose(other.sigma, batch.sigma, rtol=1e-5)
    # fgcal online and fgcal design take them (they refused in one line before: tests/test_online_stations.py
    # and tests/test_design_stations.py check their numbers)
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "online", str(tmp_path / "all"), "--engine", "ekf",
                          "--out", str(tmp_path / "o.json")], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr[-2000:]
    got = json.loads((tmp_path / "o.json").read_text())
    assert [p["name"] for p in got["parameters"]] == batch.names and got["n_poses"] == ds.n_poses
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "design", "--dataset", str(tmp_path / "all"), "--poses",
                          "20", "--out", str(tmp_path / "p.csv")], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr[-2000:]
    assert (tmp_path / "p.csv").read_text().splitlines()[0].endswith(",station")
