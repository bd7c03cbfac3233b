"""Real robots from URDF: fgcal's chain against an independent parser (yourdfpy), calibration of a
perturbed copy simulated with that parser, and the calibrated URDF copy read back by it."""
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from fgcal.estimation.calibrate import CalibrationOptions, calibrate
from fgcal.measurements.dataset import Dataset, Noise, PointObservations, PoseObservations
from fgcal.robots.identifiability import identification_jacobian
from fgcal.robots.model import ParameterSet, Tooling
from fgcal.robots.robot_file import load_model, model_from_dict, model_to_dict
from fgcal.robots.transforms import matrix_to_quaternion, rot
from fgcal.robots.urdf import export_urdf, to_urdf

yourdfpy = pytest.importorskip("yourdfpy", reason="yourdfpy (test extra) checks FK independently")

DATA = Path(__file__).parent / "data" / "urdf"
ROBOTS = {  # file, chain, and where the reflector sits on the tip link (mm)
    "panda": ("panda.urdf", {"base": "panda_link0", "tip": "panda_hand_tcp"}),
    "ur10": ("ur10_robot.urdf", {"tip": "tool0"}),
    "kinova": ("kinova.urdf", {"tip": "j2s6s200_end_effector"}),
}


def _model(robot):
    name, chain = ROBOTS[robot]
    return load_model(DATA / name, chain=chain)


def _urdf_fk(text, model, q, frame_from, frame_to, tmp_path):
    """World positions (mm) of ``frame_to`` in ``frame_from`` by yourdfpy at readings ``q`` (N, n)."""
    path = tmp_path / "check.urdf"
    path.write_text(text)
    u = yourdfpy.URDF.load(str(path), load_meshes=False, load_collision_meshes=False)
    out = []
    for qi in q:
        u.update_cfg({n: v if t.value == "revolute" else v / 1000.0
                      for n, t, v in zip(model.joint_names, model.joint_types, qi)})
        T = u.get_transform(frame_to, frame_from).copy()
        T[:3, 3] *= 1000.0
        out.append(T)
    return np.array(out)


def _joints(model, n, rng):
    lo, hi = model.joint_limits[:, 0], model.joint_limits[:, 1]
    return rng.uniform(np.maximum(lo, -np.pi), np.minimum(hi, np.pi), size=(n, model.n_joints))


@pytest.mark.parametrize("robot", sorted(ROBOTS))
def test_forward_kinematics_matches_an_independent_parser(robot, tmp_path):
    model = _model(robot)
    name, chain = ROBOTS[robot]
    q = _joints(model, 20, np.random.default_rng(1))
    base = model.extra["urdf"]["base"]
    theirs = _urdf_fk((DATA / name).read_text(), model, q, base, chain["tip"], tmp_path)
    assert np.abs(theirs - model.forward(model.nominal, q)).max() < 1e-9
    # the model file round trip keeps the URDF and the kinematics
    again = model_from_dict(model_to_dict(model))
    assert again.slot_names == model.slot_names
    assert np.abs(again.forward(again.nominal, q) - model.forward(model.nominal, q)).max() < 1e-9


def test_minimal_parameters_follow_the_rule_for_7_joints():
    model = _model("panda")
    names = model.identifiable_names()
    assert len(names) == 4 * 7 + 6  # four per revolute joint, plus base and tool
    assert names[6:8] == ["panda_joint1.a", "panda_joint1.alpha"]
    assert model.rule_exceptions == {}


@pytest.mark.parametrize("robot", sorted(ROBOTS))
def test_exported_urdf_reproduces_fgcal_in_an_independent_parser(robot, tmp_path):
    model = _model(robot)
    rng = np.random.default_rng(2)
    slots = model.nominal + np.where(model.slot_is_angle, rng.normal(0, 1e-3, model.nominal.shape),
                                     rng.normal(0, 0.5, model.nominal.shape))
    q = _joints(model, 10, rng)
    ours = model.forward(slots, q)
    copy = export_urdf(model, slots)
    assert np.abs(_urdf_fk(copy, model, q, "world", "tool", tmp_path) - ours).max() < 1e-9
    root = ET.fromstring(copy)  # same joints, limits and efforts as the user's file
    original = ET.fromstring((DATA / ROBOTS[robot][0]).read_text())
    for e in original.findall("joint"):
        twin = root.find(f"joint[@name='{e.get('name')}']")
        assert twin is not None and twin.get("type") == e.get("type")
        if e.find("limit") is not None:
            assert twin.find("limit").attrib == e.find("limit").attrib
    plain = to_urdf(model, slots)
    assert np.abs(_urdf_fk(plain, model, q, "world", "tool", tmp_path) - ours).max() < 1e-9
    assert 'effort="0"' not in plain


def _perturbed_urdf(text, rng, mm=0.5, deg=0.05):
    """A copy of a URDF with every joint origin moved by ~``mm`` and turned by ~``deg``."""
    root = ET.fromstring(text)
    for e in root.findall("joint"):
        o = e.find("origin")
        if o is None:
            o = ET.SubElement(e, "origin")
        xyz = np.array([float(v) for v in o.get("xyz", "0 0 0").split()]) + rng.normal(0, mm / 1000.0, 3)
        rpy = np.array([float(v) for v in o.get("rpy", "0 0 0").split()]) + rng.normal(0, np.radians(deg), 3)
        o.set("xyz", " ".join(repr(float(v)) for v in xyz))
        o.set("rpy", " ".join(repr(float(v)) for v in rpy))
    return ET.tostring(root, encoding="unicode")


def _placement():
    """The instrument 2.5 m from the robot, turned by 120 deg: world = W robot."""
    W = np.eye(4)
    W[:3, :3] = rot(2, np.radians(120.0))
    W[:3, 3] = [2500.0, -300.0, 200.0]
    return W


@pytest.mark.parametrize("robot,full_pose", [("panda", False), ("panda", True), ("ur10", False), ("kinova", True)])
def test_calibrates_a_perturbed_urdf_to_the_noise_limit(robot, full_pose, tmp_path):
    """Simulated with yourdfpy from a perturbed URDF; accuracy at held-out poses within 1.5 x what the
    reported covariance predicts (the noise-limited accuracy)."""
    rng = np.random.default_rng(7)
    model = _model(robot)
    name, chain = ROBOTS[robot]
    actual = _perturbed_urdf((DATA / name).read_text(), rng)
    q_train, q_test = _joints(model, 60, rng), _joints(model, 200, rng)
    base = model.extra["urdf"]["base"]
    W = _placement()
    T_train = W @ _urdf_fk(actual, model, q_train, base, chain["tip"], tmp_path)
    T_test = W @ _urdf_fk(actual, model, q_test, base, chain["tip"], tmp_path)
    sigma = 0.01
    reflector = np.array([0.0, 0.0, 50.0])
    ids = np.arange(1, len(q_train) + 1)
    common = dict(robot=str(DATA / name), provenance={"test": "urdf"}, pose_ids=ids,
                  joints_deg=model.joints_to_file_units(q_train), chain=chain)
    if full_pose:
        R = T_train[:, :3, :3]
        ds = Dataset(tooling=Tooling(0.0, {"F": np.zeros(3)}),
                     noise=Noise(cmm_sigma=sigma, joint_resolution=0.0, pose_position_sigma=sigma,
                                 pose_orientation_sigma=float(np.degrees(sigma / 100.0))),
                     poses=PoseObservations(ids, T_train[:, :3, 3] + rng.normal(0, sigma, (len(ids), 3)),
                                            np.array([matrix_to_quaternion(r) for r in R])), **common)
    else:
        pts = T_train[:, :3, :3] @ reflector + T_train[:, :3, 3]
        ds = Dataset(tooling=Tooling(0.0, {"R": reflector}), noise=Noise(cmm_sigma=sigma, joint_resolution=0.0),
                     centres=PointObservations(ids, ["R"] * len(ids), pts + rng.normal(0, sigma, pts.shape)), **common)
    result = calibrate(ds, model, CalibrationOptions())
    slots = result.slot_vector(model)
    T_cal = model.forward(slots, q_test)
    point = np.zeros(3) if full_pose else reflector
    err = (T_cal[:, :3, :3] @ point + T_cal[:, :3, 3]) - (T_test[:, :3, :3] @ point + T_test[:, :3, 3])
    realised = np.sqrt(np.mean(np.sum(err**2, axis=1)))
    params = ParameterSet(model, tuple(result.names))
    J = identification_jacobian(params, q_test, slots, measurement=point[None])
    scale = np.where(params.is_angle, np.degrees(1.0), 1.0)
    cov = result.covariance / np.outer(scale, scale)
    predicted = np.sqrt(np.trace(J @ cov @ J.T) / len(q_test))
    assert realised < 1.5 * predicted, (realised, predicted)
    assert realised < 0.05  # the perturbation alone leaves millimetres


def test_7r_with_a_guessed_reflector_matches_an_independent_least_squares(tmp_path):
    """Issue 24: a Panda URDF perturbed by 0.5 mm / 0.05 deg per joint origin (simulated with
    yourdfpy), one reflector whose offset the user guessed 4.6 mm off, 200 poses. The
    typical-deviation prior (0.5 mm about the guess) on the weakly seen ``tool.pz`` pulled the fit
    toward the guess: 0.0047 mm at new poses against 0.00415 for scipy's least squares over every
    parameter from the same start (1.13x). Decided at the solution, the data carry it: 1.00x."""
    from scipy.optimize import least_squares

    from fgcal.estimation.calibrate import solve_calibration

    rng = np.random.default_rng(7)
    model = _model("panda")
    name, chain = ROBOTS["panda"]
    actual = _perturbed_urdf((DATA / name).read_text(), rng)
    q_train, q_test = _joints(model, 200, rng), _joints(model, 200, rng)
    base = model.extra["urdf"]["base"]
    W = _placement()
    T_train = W @ _urdf_fk(actual, model, q_train, base, chain["tip"], tmp_path)
    T_test = W @ _urdf_fk(actual, model, q_test, base, chain["tip"], tmp_path)
    sigma, guess = 0.01, np.array([0.0, 0.0, 50.0])
    reflector = guess + np.array([2.0, -1.0, 4.0])
    ids = np.arange(1, len(q_train) + 1)
    meas = T_train[:, :3, :3] @ reflector + T_train[:, :3, 3] + rng.normal(0, sigma, (len(ids), 3))
    ds = Dataset(robot=str(DATA / name), provenance={"test": "urdf"}, pose_ids=ids,
                 joints_deg=model.joints_to_file_units(q_train), chain=chain, tooling=Tooling(0.0, {"R": guess}),
                 noise=Noise(cmm_sigma=sigma, joint_resolution=0.0),
                 centres=PointObservations(ids, ["R"] * len(ids), meas))
    target = T_test[:, :3, :3] @ reflector + T_test[:, :3, 3]

    def predict(slots, q):
        T = model.forward(slots, q)
        return T[:, :3, :3] @ guess + T[:, :3, 3]

    def rms(slots):
        return float(np.sqrt(np.mean(np.sum((predict(slots, q_test) - target) ** 2, axis=1))))

    result = calibrate(ds, model)
    sol = solve_calibration(ds, model, CalibrationOptions(), decide_held=False)
    start = sol.graph.params.full(sol.theta_start, sol.graph.held)
    idx = model.parameters().index

    def residual(theta):
        s = start.copy()
        s[idx] = theta
        return ((predict(s, q_train) - meas) / sigma).ravel()

    ref = start.copy()
    ref[idx] = least_squares(residual, start[idx], method="lm", x_scale="jac").x
    ours, theirs = rms(result.slot_vector(model)), rms(ref)
    assert ours <= 1.05 * theirs, (ours, theirs)  # measured 0.00414 against 0.00415 (the issue's bound: 1.5x)
    assert "tool.pz" in result.options.get("priors_dropped_at_solution", {})
