"""``fgcal export --urdf`` of a contact calibration (DESIGN.md 8.2): the result records the tooling
(the ball that made the contacts, its centre in the tool frame) and the exported link ``tool`` is at
that ball's centre, checked with an independent URDF parser (yourdfpy) at random joints against
the calibrated forward kinematics times the ball's offset, for a URDF robot (the calibrated copy of
the user's URDF) and a built-in one (fgcal's own URDF), with a ball off the tool frame's origin."""
import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fgcal.errors import FgcalError
from fgcal.estimation.calibrate import CalibrationOptions, calibrate
from fgcal.estimation.result import load_result, save_result
from fgcal.measurements.dataset import Noise
from fgcal.robots.model import Tooling
from fgcal.robots.robot_file import load_model
from fgcal.studies.simulate import SetupSimulation, SimulationSettings, simulate

yourdfpy = pytest.importorskip("yourdfpy", reason="yourdfpy (test extra) reads the exported URDF independently")

DATA = Path(__file__).parent / "data" / "urdf"
BALL = np.array([15.0, -10.0, 40.0])  # mm, tool frame: a ball well off the tool frame's origin
ROBOTS = {"puma560": lambda: load_model("puma560"),
          "panda": lambda: load_model(DATA / "panda.urdf", chain={"base": "panda_link0", "tip": "panda_hand_tcp"})}


def _export(result_path, out, tmp_path):
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "export", str(result_path), "--urdf", str(out)],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    return run.stdout


def _tool_in_world(path, model, q):
    """The link ``tool`` in ``world`` (4, 4) mm by yourdfpy at joints ``q`` (N, n) rad."""
    u = yourdfpy.URDF.load(str(path), load_meshes=False, load_collision_meshes=False)
    out = []
    for qi in q:
        u.update_cfg({n: v if t.value == "revolute" else v / 1000.0
                      for n, t, v in zip(model.joint_names, model.joint_types, qi, strict=True)})
        T = u.get_transform("tool", "world").copy()
        T[:3, 3] *= 1000.0
        out.append(T)
    return np.array(out)


@pytest.fixture(scope="module", params=sorted(ROBOTS))
def contact_result(request, tmp_path_factory):
    tmp = tmp_path_factory.mktemp(request.param)
    model = replace(ROBOTS[request.param](), tooling=Tooling(0.0, {"B": BALL}))
    settings = SimulationSettings(levels=("contacts",), noise=Noise(0.01, 0.0, 0.0),
                                  setup=SetupSimulation(placements=2, configs=8))
    ds, _ = simulate(model, np.random.default_rng(5), settings)
    result = calibrate(ds, model, CalibrationOptions())
    save_result(result, tmp / "r.json")
    return tmp, result


def test_result_records_the_tooling(contact_result):
    tmp, result = contact_result
    assert result.tooling == {"radius": 0.0, "balls": {"B": BALL.tolist()}, "tool_ball": "B"}
    again = load_result(tmp / "r.json")  # the round trip
    assert again.tooling == result.tooling
    assert np.array_equal(again.tool_point(), BALL)


def test_exported_tool_link_is_at_the_ball_centre(contact_result):
    tmp, result = contact_result
    stdout = _export(tmp / "r.json", tmp / "out.urdf", tmp)
    assert "link tool at the centre of ball B (15, -10, 40 mm in the tool frame)" in stdout
    model = result.model()
    lo, hi = np.maximum(model.joint_limits[:, 0], -np.pi), np.minimum(model.joint_limits[:, 1], np.pi)
    q = np.random.default_rng(9).uniform(lo, hi, size=(12, model.n_joints))
    T = model.forward(result.slot_vector(model), q)
    predicted = T[:, :3, :3] @ BALL + T[:, :3, 3]  # the calibrated ball centre (mm, world)
    theirs = _tool_in_world(tmp / "out.urdf", model, q)
    assert np.abs(theirs[:, :3, 3] - predicted).max() < 1e-6
    assert np.abs(theirs[:, :3, :3] - T[:, :3, :3]).max() < 1e-12  # the tool frame's orientation, moved
    assert np.linalg.norm(theirs[:, :3, 3] - T[:, :3, 3], axis=1).min() > 40.0  # |BALL| = 43.9 mm: not the tool frame's origin


def test_without_contacts_the_tool_link_stays_at_the_tool_frame(tmp_path):
    model = replace(ROBOTS["puma560"](), tooling=Tooling(0.0, {"R": BALL}))
    ds, _ = simulate(model, np.random.default_rng(3), SimulationSettings(n_poses=30, n_balls=1, levels=("centres",)))
    result = calibrate(ds, model, CalibrationOptions())
    assert result.tooling == {"radius": 0.0, "balls": {"R": BALL.tolist()}, "tool_ball": None}
    assert result.tool_point() is None
    save_result(result, tmp_path / "r.json")
    _export(tmp_path / "r.json", tmp_path / "out.urdf", tmp_path)
    q = np.zeros((1, 6)) + 0.3
    T = model.forward(result.slot_vector(model), q)
    assert np.abs(_tool_in_world(tmp_path / "out.urdf", model, q)[0] - T[0]).max() < 1e-6


@pytest.mark.parametrize("tooling,words", [
    ({"balls": {"B": [0, 0]}}, "tooling.balls"),
    ({"balls": {"B": [0, 0, 1]}, "tool_ball": "C"}, "tooling.tool_ball"),
    ({"balls": {}, "radius": -1}, "tooling.radius"),
    ({"balls": {}, "what": 1}, "tooling: must be a mapping")])
def test_a_malformed_tooling_is_refused_in_one_line(contact_result, tmp_path, tooling, words):
    tmp, _ = contact_result
    d = json.loads((tmp / "r.json").read_text())
    d["tooling"] = tooling
    (tmp_path / "bad.json").write_text(json.dumps(d))
    with pytest.raises(FgcalError, match=words):
        load_result(tmp_path / "bad.json")
