"""A test matrix: measurement types x engines x commands, on small simulated datasets.

Types: ball centres of three balls, a single reflector, full poses, ballbar distances (all
simulated by :mod:`fgcal.studies.simulate` on the Puma 560), contacts to two-socket plates plus a
table (tests/contact_sim.py on the Kinova URDF), centres from three stations
(tests/test_stations.py) and a camera's pixels of a board on a Panda's tool (tests/pixel_sim.py:
OpenCV's projection, eye-to-hand). Every cell is checked against an expectation computed independently of
the code under test where one exists: the simulated truth, the batch solve for the other
engines, the holding rule for what is held, the result's own kinematics for the export.
"""
import json
import re
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from contact_sim import UrdfChain, plane_dataset, rigid_align, two_socket_dataset
from pixel_sim import camera_dataset
from plain_dh import fk_from_truth
from test_contacts_simulated import _merge
from test_stations import CHAIN as STATION_CHAIN
from test_stations import _simulate as _stations_simulate

from fgcal.estimation.calibrate import CalibrationOptions, calibrate
from fgcal.estimation.holding import unseen_parameters
from fgcal.estimation.result import load_result
from fgcal.io.dataset_io import dataset_model, load_dataset, save_dataset
from fgcal.online.run import OnlineRun
from fgcal.robots.model import Tooling
from fgcal.robots.robot_file import load_model
from fgcal.studies.simulate import SimulationSettings, simulate

DATA = Path(__file__).parent / "data" / "urdf"
REFLECTOR = np.array([0.0, 0.0, 50.0])
N_POSES = 30

TYPES = ["centres", "reflector", "poses", "distances", "contacts", "stations", "pixels"]
ONLINE = ["ekf", "ukf", "isam2"]
ENGINES = ["batch", "gtsam", *ONLINE]
DESIGN_REFUSED: set = set()  # every type is designed for (stations: each pose from its station)
# compensate needs a TCP in the world: a camera's data hold the base and the tool (its frames are the
# camera's and the target's), so its TCP is a point in a frame of the calibration's choosing
COMPENSATED = [t for t in TYPES if t != "pixels"]
HAS_TRUTH = {"centres", "reflector", "poses", "distances"}  # simulated by fgcal: a truth.yaml
TRUE_URDF: dict = {}  # kind -> (the true robot's URDF text, chain): the URDF-generated datasets

# Cells that fail, measured on these seeded datasets (2026-12-01); strict: a fix makes them pass.
# (iSAM2 on centres, a reflector and poses was 0.23-0.35 sigma off: its result was the running
# estimate, not the final smoothing; fixed, those cells pass.)
# (The online engines on a ballbar dataset reported 3-4 of 30 poses: those the running estimate took
# before the pivot was known; the result now holds the poses of the final smoothing, which takes all.)
XFAIL_ENGINE = {
}
XFAIL_CLI = {}


def _cli(*args, cwd=None, timeout=300):
    return subprocess.run([sys.executable, "-m", "fgcal.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, cwd=cwd)


def _one_line_error(out):
    """Exit status 2, exactly one error line, no traceback."""
    assert out.returncode == 2, (out.returncode, out.stdout[-2000:], out.stderr[-2000:])
    assert "Traceback" not in out.stderr and "Traceback" not in out.stdout, out.stderr
    errors = [ln for ln in out.stderr.splitlines() if ln.startswith("fgcal: error:")]
    assert len(errors) == 1, out.stderr
    assert errors[0].strip() == out.stderr.strip().splitlines()[-1].strip()  # the error is the last line
    return errors[0]


def _reflector(model):
    return replace(model, tooling=Tooling(0.0, {"R": REFLECTOR.copy()}))


def _simulated(model, levels, n_balls, seed, path):
    ds, _ = simulate(model, np.random.default_rng(seed), SimulationSettings(n_poses=N_POSES, levels=levels,
                                                                           n_balls=n_balls))
    save_dataset(ds, path)


def _contacts(tmp: Path):
    chain = {"tip": "j2s6s200_end_effector"}
    rng = np.random.default_rng(0)
    sockets = two_socket_dataset(tmp / "sockets", DATA / "kinova.urdf", chain, rng, n_placements=2,
                                 configs_per_socket=8, ball_offset_mm=(0.0, 0.0, 30.0), contact_sigma_mm=0.02,
                                 distance_sigma_mm=0.0005)
    plane_dataset(tmp / "plane", DATA / "kinova.urdf", chain, rng, n_contacts=16, ball_radius_mm=0.0,
                  ball_offset_mm=(0.0, 0.0, 30.0), contact_sigma_mm=0.02, true_urdf=sockets.urdf,
                  patch_radius_mm=200.0, max_tries=5)
    save_dataset(_merge(load_dataset(tmp / "sockets"), load_dataset(tmp / "plane")), tmp / "contacts")
    shutil.copy(tmp / "sockets" / "robot.urdf", tmp / "contacts" / "robot.urdf")
    TRUE_URDF["contacts"] = (sockets.urdf, {"tip": "j2s6s200_end_effector"})
    return tmp / "contacts"


@pytest.fixture(scope="module")
def paths(puma, ur10, tmp_path_factory):
    """Each type's dataset directory (and the two compliance ones on the UR10)."""
    tmp = tmp_path_factory.mktemp("matrix")
    out = {}
    for name, model, levels, balls, seed in [("centres", puma, ("centres",), 3, 1),
                                             ("reflector", _reflector(puma), ("centres",), 1, 2),
                                             ("poses", puma, ("poses",), 3, 3),
                                             ("distances", puma, ("distances",), 1, 4),
                                             ("ur10-centres", ur10, ("centres",), 3, 5),
                                             ("ur10-reflector", _reflector(ur10), ("centres",), 1, 6)]:
        _simulated(model, levels, balls, seed, tmp / name)
        out[name] = tmp / name
    out["ur10-stations"] = _on_stations(out["ur10-reflector"], tmp / "ur10-stations")
    out["ur10-contacts"] = _dh_contacts(out["ur10-centres"], tmp / "ur10-contacts")
    out["contacts"] = _contacts(tmp / "c")
    TRUE_URDF["stations"] = (_stations_simulate(tmp / "s", 0, n=N_POSES), STATION_CHAIN)
    out["stations"] = tmp / "s" / "all"
    camera_dataset(tmp / "pixels", DATA / "panda.urdf", {"base": "panda_link0", "tip": "panda_hand_tcp"},
                   np.random.default_rng(8), n_images=N_POSES, n_held_out=0)
    out["pixels"] = tmp / "pixels"
    return out


UR10_STATIONS = {"B": [25.0, 1.0, -2.0, 600.0, -250.0, 40.0], "C": [-50.0, -1.0, 2.5, -150.0, 700.0, -30.0]}


def _on_stations(src: Path, out: Path) -> Path:
    """The dataset ``src`` (fgcal-simulated reflector centres) as measured from three stations: every
    third pose from A (the world), B and C; B's and C's centres moved into their frames
    (:data:`UR10_STATIONS`, deg and mm) by the test's own transform."""
    import yaml

    from fgcal.robots.transforms import euler_zyx_trans

    shutil.copytree(src, out)
    meta = yaml.safe_load((out / "dataset.yaml").read_text())
    meta["stations"] = ["A", "B", "C"]
    (out / "dataset.yaml").write_text(yaml.safe_dump(meta))
    head, *rows = (out / "joints.csv").read_text().splitlines()
    station = {int(r.split(",")[0]): "ABC"[k % 3] for k, r in enumerate(rows)}
    (out / "joints.csv").write_text("\n".join([head + ",station"] + [f"{r},{station[int(r.split(',')[0])]}"
                                                                      for r in rows]) + "\n")
    head, *rows = (out / "centres.csv").read_text().splitlines()
    lines = [head]
    for r in rows:
        pose, ball, *xyz = r.split(",")
        x = np.array(xyz, dtype=float)
        if station[int(pose)] != "A":
            frame = UR10_STATIONS[station[int(pose)]]
            T = euler_zyx_trans(*np.radians(frame[:3]), *frame[3:])
            x = (x - T[:3, 3]) @ T[:3, :3]
        lines.append(f"{pose},{ball}," + ",".join(repr(float(v)) for v in x))
    (out / "centres.csv").write_text("\n".join(lines) + "\n")
    return out


def _dh_contacts(src: Path, out: Path) -> Path:
    """Two-socket contacts (three plates, eight seatings a socket) of the true UR10 of ``src``'s
    truth.yaml, by tests/dh_contacts.py (an independent DH forward kinematics); truth.yaml copied."""
    from dh_contacts import dh_two_socket_dataset

    from fgcal.io.dataset_io import load_truth

    truth, _ = load_truth(src / "truth.yaml")
    dh_two_socket_dataset(out, "ur10", truth, load_model("ur10").joint_limits, np.random.default_rng(0))
    shutil.copy(src / "truth.yaml", out / "truth.yaml")
    return out


_BATCH = {}


def _batch(paths, kind, options=None, ids=None):
    """The batch solve of ``kind`` (cached), optionally on the poses ``ids``."""
    key = (kind, None if ids is None else tuple(ids), repr(options))
    if key not in _BATCH:
        ds = load_dataset(paths[kind])
        model = dataset_model(ds)
        if ids is not None and len(ids) != ds.n_poses:
            ds = ds.select(np.asarray(ids))
        _BATCH[key] = (ds, model, calibrate(ds, model, options or CalibrationOptions()))
    return _BATCH[key]


def _angle_wrapped(names, d):
    """|d| (file units) with the angles' differences taken modulo 360 deg (a Panda's base.phi ends at
    180.02 deg from one start, at -179.98 from another)."""
    angle = np.array([n.split(".")[-1] in ("phi", "theta", "psi", "alpha", "tilt_u", "tilt_v") for n in names])
    d = np.asarray(d, dtype=float)
    return np.abs(np.where(angle, (d + 180.0) % 360.0 - 180.0, d))


def _held(result):
    return {h["name"] for h in result.held}


# --- engines ---------------------------------------------------------------------------------------

def _engine_cells():
    for kind in TYPES:
        for engine in ENGINES:
            marks = []
            if (kind, engine) in XFAIL_ENGINE:
                marks = [pytest.mark.xfail(strict=True, raises=AssertionError, reason=XFAIL_ENGINE[(kind, engine)])]
            yield pytest.param(kind, engine, marks=marks, id=f"{kind}-{engine}")


@pytest.mark.parametrize("kind, engine", list(_engine_cells()))
def test_engine(paths, kind, engine, tmp_path):
    ds, model, batch = _batch(paths, kind)
    assert batch.converged
    assert np.all(np.isfinite(batch.estimate)) and np.all(batch.sigma > 0)
    if engine == "batch":
        if kind in HAS_TRUTH:  # the simulated truth, within 5 sigma for every estimated parameter
            from fgcal.io.dataset_io import load_truth

            truth, _ = load_truth(paths[kind] / "truth.yaml")
            # A held angle's true deviation is absorbed by its frame's other parameters (a reflector's
            # tool angles by the tool translation): that frame is compared by the kinematics instead.
            frames = {h.split(".")[0] for h in _held(batch)}
            params = [p for p in batch.parameters if p.name.split(".")[0] not in frames]
            assert all(p.name in truth for p in params)
            z = np.array([(p.estimate - truth[p.name]) / p.sigma for p in params])
            assert np.abs(z).max() < 5.0, (params[int(np.argmax(np.abs(z)))].name, np.abs(z).max())
            # and the spread of the normalised errors is a standard normal's (a bias or a wrong sigma is not)
            assert 0.5 < np.sqrt(np.mean(z ** 2)) < 1.6, np.sqrt(np.mean(z ** 2))
        return
    if engine == "gtsam":
        g = calibrate(ds, model, CalibrationOptions(engine="gtsam"))
        assert g.names == batch.names and _held(g) == _held(batch)
        d = np.abs(g.estimate - batch.estimate) / batch.sigma
        assert d.max() < 1e-4, (g.names[int(np.argmax(d))], d.max())
        np.testing.assert_allclose(g.sigma, batch.sigma, rtol=1e-4)
        return
    run = OnlineRun(ds, model, engine)
    for rec in run.pending():
        run.feed(rec)
    result = run.result()
    accepted = list(result.pose_ids)
    assert len(accepted) >= 0.9 * ds.n_poses, f"{engine} accepted {len(accepted)} of {ds.n_poses} poses"
    _, _, ref = _batch(paths, kind, ids=accepted)  # the batch on the same accepted poses
    assert _held(result) == _held(ref)
    assert result.names == ref.names
    d = _angle_wrapped(result.names, result.estimate - ref.estimate) / ref.sigma
    assert d.max() < 0.05, (result.names[int(np.argmax(d))], d.max())
    ratio = result.sigma / ref.sigma
    assert ratio.min() > 0.95 and ratio.max() < 1.05, (ratio.min(), ratio.max())


# --- held and not held -----------------------------------------------------------------------------

def test_held_reflector_tool_angles(paths):
    ds, model, batch = _batch(paths, "reflector")
    names = model.parameters().names
    unseen = unseen_parameters(model, names, REFLECTOR[None, :])
    priors = set(batch.options.get("typical_deviation_priors") or {})
    expected = set(unseen) - priors
    assert {"tool.phi", "tool.theta", "tool.psi"} <= expected
    assert _held(batch) == expected
    assert priors <= {p.name for p in batch.parameters}  # what has a prior is estimated


def test_held_poses_nothing(paths):
    ds, model, batch = _batch(paths, "poses")
    assert unseen_parameters(model, model.parameters().names, "pose") == {}
    assert _held(batch) == set()
    assert not batch.options.get("typical_deviation_priors")
    assert set(batch.names) == set(model.identifiable_names())


# --- the compliance model --------------------------------------------------------------------------

@pytest.mark.parametrize("kind", ["ur10-centres", "ur10-reflector", "ur10-stations", "ur10-contacts"])
def test_compliance_model(paths, kind, tmp_path):
    """The compliance model on the UR10 (whose model has inertials): centres (nothing held), a
    reflector (tool angles held), a reflector from three stations, two-socket contacts (the base
    held: nothing fixes the world frame); the simulated arm has no compliance (within 4 sigma of
    zero), and its geometry is the simulated truth within 5 sigma (contacts: the ball at 30 new
    joint sets, after aligning the free world frame, 5 times closer than the nominal's)."""
    out = _cli("calibrate", paths[kind], "--model", "compliance", "--folds", "3", "--out", tmp_path / "r.json")
    assert out.returncode == 0, out.stderr[-3000:]
    assert "Traceback" not in out.stderr
    r = load_result(tmp_path / "r.json")
    comp = [p for p in r.parameters if p.name.endswith(".compliance")]
    assert comp, f"no compliance estimated: {[p.name for p in r.parameters]}"
    for p in comp:
        assert np.isfinite(p.estimate) and np.isfinite(p.sigma) and p.sigma > 0, (p.name, p.estimate, p.sigma)
        assert abs(p.estimate) < 4 * p.sigma, (p.name, p.estimate, p.sigma)  # the simulated arm has none
    if kind != "ur10-centres":
        assert {"tool.phi", "tool.theta", "tool.psi"} <= _held(r)
    else:
        assert not _held(r)
    from fgcal.io.dataset_io import load_truth

    truth, _ = load_truth(paths[kind] / "truth.yaml")
    if kind == "ur10-contacts":
        from contact_sim import aligned_rms

        assert {f"base.{c}" for c in ("phi", "theta", "psi", "px", "py", "pz")} <= _held(r)
        model = r.model()
        rng = np.random.default_rng(8)
        q = rng.uniform(np.maximum(model.joint_limits[:, 0], -np.pi), np.minimum(model.joint_limits[:, 1], np.pi),
                        size=(30, 6))
        ball = np.array([0.0, 0.0, 30.0])
        true = np.array([(fk_from_truth(truth, np.degrees(qi)) @ np.append(ball, 1.0))[:3] for qi in q])
        T, T0 = model.forward(r.slot_vector(model), q), model.forward(model.nominal, q)
        got, nominal = T[:, :3, :3] @ ball + T[:, :3, 3], T0[:, :3, :3] @ ball + T0[:, :3, 3]
        assert aligned_rms(got, true) < 0.2 * aligned_rms(nominal, true), (aligned_rms(got, true),
                                                                         aligned_rms(nominal, true))
        return
    geometry = [p for p in r.parameters if p.name in truth and not p.name.endswith(".compliance")
                and p.name.split(".")[0] not in {h.split(".")[0] for h in _held(r)}]
    z = np.array([(p.estimate - truth[p.name]) / p.sigma for p in geometry])
    assert len(geometry) > 20 and np.abs(z).max() < 5.0, (geometry[int(np.argmax(np.abs(z)))].name, np.abs(z).max())
    if kind == "ur10-stations":  # and the stations' frames are the simulated ones
        for name, pose in UR10_STATIONS.items():
            got = {p.name: p for p in r.parameters if p.name.startswith(f"station.{name}.")}
            for c, v in zip(("phi", "theta", "psi", "px", "py", "pz"), pose, strict=True):
                p = got[f"station.{name}.{c}"]
                assert abs(p.estimate - v) < 5 * p.sigma, (p.name, p.estimate, v, p.sigma)


# --- the commands ------------------------------------------------------------------------------------

COMMANDS = ["check", "calibrate", "verify", "report", "export", "design"]
_CLI_DONE = {}


def _cli_result(paths, kind, tmp):
    """``calibrate DS --out r.json`` for ``kind``, once."""
    if (kind, "r") not in _CLI_DONE:
        r = tmp / f"{kind}-r.json"
        out = _cli("calibrate", paths[kind], "--out", r)
        _CLI_DONE[(kind, "r")] = (out, r)
    return _CLI_DONE[(kind, "r")]


def _cli_verify(paths, kind, tmp):
    if (kind, "v") not in _CLI_DONE:
        out, r = _cli_result(paths, kind, tmp)
        assert out.returncode == 0, out.stderr[-3000:]
        v = tmp / f"{kind}-v.json"
        _CLI_DONE[(kind, "v")] = (_cli("verify", r, paths[kind], "--out", v), v)
    return _CLI_DONE[(kind, "v")]


@pytest.fixture(scope="module")
def cli_tmp(tmp_path_factory):
    return tmp_path_factory.mktemp("cli")


def _command_cells():
    for kind in TYPES:
        for command in COMMANDS:
            marks = []
            if (kind, command) in XFAIL_CLI:
                marks = [pytest.mark.xfail(strict=True, raises=AssertionError, reason=XFAIL_CLI[(kind, command)])]
            yield pytest.param(kind, command, marks=marks, id=f"{kind}-{command}")


@pytest.mark.parametrize("kind, command", list(_command_cells()))
def test_command(paths, cli_tmp, kind, command, tmp_path):
    ds_path = paths[kind]
    if command == "check":
        out = _cli("check", ds_path)
        assert out.returncode == 0, out.stderr[-3000:]
        assert "Traceback" not in out.stderr
        return
    if command == "design":
        out = _cli("design", "--dataset", ds_path, "--poses", "8", "--out", tmp_path / "p.csv")
        if kind in DESIGN_REFUSED:
            _one_line_error(out)
            assert not (tmp_path / "p.csv").exists()
            return
        n = 8
        if out.returncode == 2:
            # A point type gives at most 3 (a distance 1) equations per pose: 8 poses cannot identify
            # its parameters. Then the refusal must be one line with the arithmetic right, and the
            # number of poses it asks for must be designable.
            line = _one_line_error(out)
            m = re.search(r"cannot identify the (\d+) parameters \(each pose gives at most (\d+) independent "
                          r"equations\): at least (\d+) poses needed", line)
            assert m, line
            n_par, per_pose, n = map(int, m.groups())
            assert per_pose in (1, 3) and 8 * per_pose < n_par and n == -(-n_par // per_pose), line
            assert not (tmp_path / "p.csv").exists()
            out = _cli("design", "--dataset", ds_path, "--poses", n, "--out", tmp_path / "p.csv")
        assert out.returncode == 0, out.stderr[-3000:]
        ids = np.loadtxt(tmp_path / "p.csv", delimiter=",", skiprows=1, usecols=0, ndmin=1).astype(int).tolist()
        ds = load_dataset(ds_path)
        assert len(ids) == n and len(set(ids)) == n and set(ids) <= set(ds.pose_ids.tolist()), ids
        if ds.stations is not None:  # which station each pose is to be measured from: the dataset's
            from fgcal.io.dataset_io import read_joints_and_stations

            of = dict(zip(ds.pose_ids.tolist(), ds.stations.tolist(), strict=True))
            assert read_joints_and_stations(tmp_path / "p.csv")[2].tolist() == [of[i] for i in ids]
        return
    out, r = _cli_result(paths, kind, cli_tmp)
    if command == "calibrate":
        assert out.returncode == 0, out.stderr[-3000:]
        assert "Traceback" not in out.stderr
        result = load_result(r)
        _, _, batch = _batch(paths, kind)  # the command's result is the library's
        assert result.names == batch.names
        np.testing.assert_allclose(result.estimate, batch.estimate, rtol=0, atol=1e-6 * batch.sigma.max())
        return
    assert out.returncode == 0, out.stderr[-3000:]
    result = load_result(r)
    if command == "verify":
        vout, v = _cli_verify(paths, kind, cli_tmp)
        assert vout.returncode == 0, vout.stderr[-3000:]
        d = json.loads(v.read_text())
        if kind in HAS_TRUTH:
            assert d["truth"]["position_mm"]["rms"] < d["truth"]["before"]["position_mm"]["rms"], d["truth"]
        elif kind == "contacts":
            assert d["consistency_mm"]["rms"] < d["before"]["consistency_mm"]["rms"], d
        else:  # stations: no truth file, the measured positions; pixels: the reprojection error (px)
            assert d["position_mm"]["rms"] < d["before"]["position_mm"]["rms"], d
        return
    if command == "report":
        vout, v = _cli_verify(paths, kind, cli_tmp)
        assert vout.returncode == 0, vout.stderr[-3000:]
        out = _cli("report", r, "--verify", v, "--out", tmp_path / "rep")
        assert out.returncode == 0, out.stderr[-3000:]
        md = (tmp_path / "rep" / "report.md").read_text()
        missing = [p.name for p in result.parameters if p.name not in md]
        assert not missing, missing
        return
    if command == "export":
        out = _cli("export", r, "--urdf", tmp_path / "cal.urdf", "--model", tmp_path / "cal.yaml")
        assert out.returncode == 0, out.stderr[-3000:]
        assert (tmp_path / "cal.urdf").exists()
        back = load_model(tmp_path / "cal.yaml")
        model = result.model()
        rng = np.random.default_rng(7)
        lim = np.clip(model.joint_limits, -np.pi, np.pi)
        q = rng.uniform(lim[:, 0], lim[:, 1], size=(5, len(lim)))
        want = model.forward(result.slot_vector(model), q)
        got = back.forward(back.nominal, q)
        np.testing.assert_allclose(got[:, :3, 3], want[:, :3, 3], rtol=0, atol=1e-9)
        np.testing.assert_allclose(got[:, :3, :3], want[:, :3, :3], rtol=0, atol=1e-12)
        return
    raise AssertionError(command)


# --- compensate -------------------------------------------------------------------------------------

# Measured on these datasets (2026-12-02): the true robot's TCP at the commanded joints, from the
# targets (max over 12, mm); the seeds' are ~3 mm.
# Limits twice those measured: centres 0.045, reflector 0.062, poses 0.041, distances 0.30 (30 lengths, one
# equation a pose, determine the geometry least), contacts 0.056, stations 0.016 mm.
COMPENSATE_LIMIT_MM = {"centres": 0.1, "reflector": 0.12, "poses": 0.08, "distances": 0.6, "contacts": 0.11,
                       "stations": 0.03}
FREE_WORLD = {"contacts", "distances"}  # nothing fixes the world frame (a ballbar: its turn about the pivot)


def _true_points(paths, kind, q_file, tcp):
    """Where the simulated true robot puts the tool point ``tcp`` (3,) at joints ``q_file`` (N, n)
    in file units, by a forward kinematics independent of fgcal's (tests/plain_dh.py for the
    fgcal-simulated Puma, tests/contact_sim.py's URDF chain for the URDF-generated datasets)."""
    if kind in HAS_TRUTH:
        from fgcal.io.dataset_io import load_truth

        truth, _ = load_truth(paths[kind] / "truth.yaml")
        return np.array([(fk_from_truth(truth, q) @ np.append(tcp, 1.0))[:3] for q in q_file])
    text, chain = TRUE_URDF[kind]
    true = UrdfChain(text, chain.get("base"), chain["tip"])
    return true.point(true.from_readings(q_file), tcp)


def _well_conditioned(model, slots, q_file, n):
    """The ``n`` joint sets of ``q_file`` (file units) farthest from a singularity (the smallest singular
    value of the pose Jacobian, rows in mm and 100 mm x rad) among those 10 deg or more inside the limits."""
    from fgcal.robots.kinematics import jacobians

    q = model.joints_to_internal(q_file)
    lim = model.joint_limits
    margin = np.minimum(q - lim[:, 0], lim[:, 1] - q).min(axis=1)
    J = jacobians(slots, q, chain=model.chain).pose_joints * np.array([1, 1, 1, 100, 100, 100.0])[None, :, None]
    smallest = np.linalg.svd(J, compute_uv=False)[:, -1]
    smallest[margin < np.radians(10.0)] = -1.0
    return q_file[np.sort(np.argsort(-smallest)[:n])]


@pytest.mark.parametrize("kind", COMPENSATED)
def test_compensate(paths, cli_tmp, kind, tmp_path):
    """``compensate`` on each type's result: targets 3 mm (random directions) from where the calibrated
    robot puts the TCP (a ball; the reflector, a position-only instrument, whose orientation is the
    held tool angles') at 12 of the dataset's joint sets, those as seeds; the true robot at the
    commanded joints puts the TCP on the targets within the calibration's accuracy (contacts and a
    ballbar: after aligning the free world frame), against ~3 mm at the seeds."""
    from fgcal.io.dataset_io import write_csv
    from fgcal.robots.compensate import tcp_matrix
    from fgcal.robots.transforms import matrix_to_quaternion

    out, r = _cli_result(paths, kind, cli_tmp)
    assert out.returncode == 0, out.stderr[-3000:]
    result = load_result(r)
    ds = load_dataset(paths[kind])
    model = result.model()
    tcp = np.zeros(3) if kind == "poses" else np.asarray(next(iter(ds.tooling.balls.values())), dtype=float)
    seeds = _well_conditioned(model, result.slot_vector(model), ds.joints_deg, 12)
    T = model.forward(result.slot_vector(model), model.joints_to_internal(seeds)) @ tcp_matrix(tcp, (0.0, 0.0, 0.0))
    step = np.random.default_rng(11).normal(size=(len(T), 3))
    T[:, :3, 3] += 3.0 * step / np.linalg.norm(step, axis=1, keepdims=True)  # 3 mm from where the seeds go
    write_csv(tmp_path / "t.csv", ["pose", "x", "y", "z", "qw", "qx", "qy", "qz",
                                   *[f"q{i}" for i in range(1, model.n_joints + 1)]],
              [[i + 1, *T[i, :3, 3], *matrix_to_quaternion(T[i, :3, :3]), *seeds[i]] for i in range(len(T))])
    run = _cli("compensate", r, tmp_path / "t.csv", "--tcp", ",".join(map(repr, tcp.tolist())),
               "--out", tmp_path / "cmd.csv")
    assert run.returncode == 0, run.stderr[-3000:]
    cmd = np.loadtxt(tmp_path / "cmd.csv", delimiter=",", skiprows=1, ndmin=2)
    assert cmd[:, 0].astype(int).tolist() == list(range(1, len(T) + 1))
    reached, before = _true_points(paths, kind, cmd[:, 1:], tcp), _true_points(paths, kind, seeds, tcp)
    target = T[:, :3, 3]
    if kind in FREE_WORLD:  # the true points aligned onto the targets
        R, t = rigid_align(reached, target)
        reached = reached @ R.T + t
        R, t = rigid_align(before, target)
        before = before @ R.T + t
    err, err0 = np.linalg.norm(reached - target, axis=1), np.linalg.norm(before - target, axis=1)
    assert err.max() < COMPENSATE_LIMIT_MM[kind], (err.max(), err0.max())
    assert err.max() < 0.1 * err0.max(), (err.max(), err0.max())
