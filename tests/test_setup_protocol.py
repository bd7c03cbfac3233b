"""The set-up block protocol: a block kind and a measurement type defined only here (a per-group
offset of a tracker's readings: each group of poses was measured with the reflector re-seated,
so its readings carry an unknown offset) are registered, then solved, reported and exported
through fgcal's own code, without edits to fgcal. Numbers against the simulated truth."""
from dataclasses import dataclass

import numpy as np
import pytest

from fgcal.estimation.calibrate import CalibrationOptions, calibrate
from fgcal.measurements import types
from fgcal.measurements.base import NoiseComponent, ObservationRows, Terms
from fgcal.measurements.contact import SetupMeasurement
from fgcal.measurements.dataset import Dataset, Noise
from fgcal.measurements.setup import BLOCK_KINDS, BlockKind, FixtureSpec, SetupSpec
from fgcal.robots.kinematics import tool_points
from fgcal.robots.model import Tooling

OFFSET = BlockKind("offset", "offset", ("dx", "dy", "dz"), (False, False, False))
BALL = np.array([0.0, 0.0, 80.0])
SIGMA = 0.01


@dataclass
class GroupObservations(ObservationRows):
    pose: np.ndarray
    ball: np.ndarray
    xyz: np.ndarray
    group: np.ndarray
    line: np.ndarray | None = None

    ROW_SHAPES = {"xyz": (3,)}

    def __post_init__(self):
        self.group = np.asarray(self.group, dtype=str).reshape(-1)
        super().__post_init__()


class GroupPoint(SetupMeasurement):
    """A reflector reading with its group's unknown offset: ``FK offset - (xyz - d_group)``."""

    level = "group_centres"
    file = "group_centres.csv"
    columns = ("pose", "ball", "x", "y", "z", "group")
    width = 3
    title = "reflector readings with a per-group offset"
    fixture_type = "offset"
    noise_key = None
    sigma_field = "group_centre"
    noise_components = (NoiseComponent("group_centres", slice(0, 3), "group_centre"),)
    derived = True  # made in memory here, not read from a file

    def declared_sigmas(self, noise):
        return {self.sigma_field: noise.cmm_sigma}

    def blocks_of(self, obs):
        return obs.group

    def block_starts(self, obs, T, tooling, unknown, where):
        pred = tool_points(T, tooling.offsets(obs.ball)[:, None, :])[:, 0]
        return {g: (obs.xyz[obs.group == g] - pred[obs.group == g]).mean(axis=0) for g in unknown}

    def terms(self, obs, tooling, row_of_pose, layout=None):
        pose = np.array([row_of_pose[p] for p in obs.pose.tolist()], dtype=int)
        start = np.array([layout.offset[g] for g in obs.group.tolist()], dtype=int)
        return Terms(pose, (tooling.offsets(obs.ball).reshape(-1, 3), obs.xyz, start))

    def setup_error(self, theta, q, data, s, index, held, chain):
        offset, xyz, start = data
        p, J_t, J_q = self._ball_points(theta, q, offset, index, held, chain)
        cols = start[:, None] + np.arange(3)
        return p - (xyz - s[cols]), J_t, J_q, np.broadcast_to(np.eye(3), (len(start), 3, 3)), cols

    def rows(self, obs):
        return ([int(p), b, *map(float, x), g] for p, b, x, g in zip(obs.pose, obs.ball, obs.xyz, obs.group))

    def metric(self, e):
        return np.linalg.norm(e, axis=1), None

    def residual_summary(self, e):
        return {"group_centres_mm": np.asarray(e).ravel().tolist()}


GROUP = GroupPoint()


@pytest.fixture
def with_groups(monkeypatch):
    monkeypatch.setitem(BLOCK_KINDS, "offset", OFFSET)
    monkeypatch.setattr(types, "KINEMATIC_TYPES", types.KINEMATIC_TYPES + (GROUP,))
    monkeypatch.setitem(types.BY_LEVEL, GROUP.level, GROUP)
    return GROUP


def _dataset(model, seed, n=60):
    """Reflector readings of a perturbed arm, three groups with known offsets (truth kept here)."""
    rng = np.random.default_rng(seed)
    truth = model.nominal.copy()
    ident = [model.slot(n) for n in model.identifiable_names()]
    truth[ident] += rng.normal(size=len(ident)) * np.where(model.slot_is_angle[ident], np.radians(0.05), 0.5)
    lo, hi = model.joint_limits[:, 0], model.joint_limits[:, 1]
    q = rng.uniform(np.maximum(lo, -2.5), np.minimum(hi, 2.5), size=(n, model.n_joints))
    T = model.forward(truth, q)
    world = np.einsum("nij,j->ni", T[:, :3, :3], BALL) + T[:, :3, 3] + rng.normal(scale=SIGMA, size=(n, 3))
    groups = np.array(["g0", "g1", "g2"])[np.arange(n) % 3]
    shifts = {"g0": np.array([0.3, -0.2, 0.5]), "g1": np.array([-1.0, 0.4, 0.2]), "g2": np.array([0.1, 0.9, -0.6])}
    xyz = world + np.array([shifts[g] for g in groups])
    ds = Dataset(robot=model.name, tooling=Tooling(0.0, {"R": BALL}), noise=Noise(cmm_sigma=SIGMA, joint_resolution=0.0),
                 provenance={}, pose_ids=np.arange(1, n + 1), joints_deg=model.joints_to_file_units(q),
                 setup=SetupSpec({"g0": FixtureSpec("g0", "offset", shifts["g0"], None, True),  # the reference group
                                  "g1": FixtureSpec("g1", "offset"), "g2": FixtureSpec("g2", "offset")}))
    ds.group_centres = GroupObservations(ds.pose_ids, np.full(n, "R"), xyz, groups)
    return ds, truth, shifts


def test_a_block_kind_defined_here_is_solved_reported_and_exported(puma, with_groups, tmp_path):
    ds, truth, shifts = _dataset(puma, 3)
    result = calibrate(ds, puma, CalibrationOptions(joint_noise=False))
    est = {p.name: (p.estimate, p.sigma) for p in result.parameters}
    for g in ("g1", "g2"):  # the offsets found, within their sigmas
        for k, c in enumerate(("dx", "dy", "dz")):
            value, sigma = est[f"offset.{g}.{c}"]
            assert abs(value - shifts[g][k]) < 4 * sigma + 1e-9 and sigma < 0.05
    assert result.setup["estimated"]["g1"]["type"] == "offset"
    # the robot: the tool point at new joint sets against the truth, within the covariance's reach
    q = np.random.default_rng(9).uniform(-2.0, 2.0, size=(50, 6))
    pred = tool_points(puma.forward(result.slot_vector(puma), q), BALL[None, None, :])[:, 0]
    true = tool_points(puma.forward(truth, q), BALL[None, None, :])[:, 0]
    assert np.sqrt(np.mean(np.sum((pred - true) ** 2, axis=1))) < 0.05
    # reported and exported by fgcal's own code
    from fgcal.estimation.result import load_result, save_result
    from fgcal.report.document import write_report
    from fgcal.robots.urdf import export_urdf

    save_result(result, tmp_path / "r.json")
    back = load_result(tmp_path / "r.json")
    assert back.setup == result.setup
    write_report(back, tmp_path / "rep")
    text = (tmp_path / "rep" / "report.md").read_text()
    assert "offset.g1.dx" in text and "set-up unknown" in text
    text = export_urdf(back.model(), back.slot_vector())
    assert "<robot" in text and "offset" not in text  # the set-up is not the robot
