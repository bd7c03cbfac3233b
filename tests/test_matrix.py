"""A test matrix: measurement types x engines x commands, on small simulated datasets.

Types: ball centres of three balls, a single reflector, full poses, ballbar distances (all
simulated by :mod:`fgcal.studies.simulate` on the Puma 560), contacts to two-socket plates plus a
table (tests/contact_sim.py on the Kinova URDF) and centres from three stations
(tests/test_stations.py). Every cell is checked against an expectation computed independently of
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
from contact_sim import plane_dataset, two_socket_dataset
from test_contacts_simulated import _merge
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

TYPES = ["centres", "reflector", "poses", "distances", "contacts", "stations"]
ONLINE = ["ekf", "ukf", "isam2"]
ENGINES = ["batch", "gtsam", *ONLINE]
ONLINE_REFUSED = {"stations"}  # the online engines do not take station centres (yet)
DESIGN_REFUSED = {"stations"}  # nor does the design
HAS_TRUTH = {"centres", "reflector", "poses", "distances"}  # simulated by fgcal: a truth.yaml

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
    out["contacts"] = _contacts(tmp / "c")
    _stations_simulate(tmp / "s", 0, n=N_POSES)
    out["stations"] = tmp / "s" / "all"
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
    if kind in ONLINE_REFUSED:
        out = _cli("online", paths[kind], "--engine", engine, "--out", tmp_path / "o.json")
        line = _one_line_error(out)
        assert "online" in line and not (tmp_path / "o.json").exists()
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
    d = np.abs(result.estimate - ref.estimate) / ref.sigma
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

@pytest.mark.parametrize("kind", ["ur10-centres", "ur10-reflector"])
def test_compliance_model(paths, kind, tmp_path):
    out = _cli("calibrate", paths[kind], "--model", "compliance", "--folds", "3", "--out", tmp_path / "r.json")
    assert out.returncode == 0, out.stderr[-3000:]
    assert "Traceback" not in out.stderr
    r = load_result(tmp_path / "r.json")
    comp = [p for p in r.parameters if p.name.endswith(".compliance")]
    assert comp, f"no compliance estimated: {[p.name for p in r.parameters]}"
    for p in comp:
        assert np.isfinite(p.estimate) and np.isfinite(p.sigma) and p.sigma > 0, (p.name, p.estimate, p.sigma)
        assert abs(p.estimate) < 4 * p.sigma, (p.name, p.estimate, p.sigma)  # the simulated arm has none
    if kind == "ur10-reflector":
        assert {"tool.phi", "tool.theta", "tool.psi"} <= _held(r)


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
        ids = np.loadtxt(tmp_path / "p.csv", delimiter=",", skiprows=1, ndmin=2)[:, 0].astype(int).tolist()
        ds = load_dataset(ds_path)
        assert len(ids) == n and len(set(ids)) == n and set(ids) <= set(ds.pose_ids.tolist()), ids
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
        else:  # stations: no truth file, the measured positions
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
