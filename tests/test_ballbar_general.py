"""The ballbar as a case of the general mechanism, measured (DESIGN.md 7 "Ballbar", 8.1).

Defined here only, through the plug-in protocol (``register``, a ``point`` set-up block): a length
between a tool ball and a pivot *fixture*, ``|FK offset - p| - L`` (mm), with the pivot ``p`` a
set-up block. On the same ballbar data it is solved beside fgcal's built-in form (the world origin
at the pivot, the base's translation estimated): the robot's parameters, their sigmas and the
predicted lengths agree, the only difference being the gauge (the built-in form estimates
``base.px..pz``, the general one ``fixture.pivot.x..z`` with the base held at nominal). The numbers
behind DESIGN.md's paragraph on why the built-in form stays (same numbers, but the general form
renames the result's parameters and moves the world frame of every ballbar dataset).
"""
from dataclasses import dataclass

import numpy as np
import pytest

from fgcal.estimation.calibrate import CalibrationOptions, calibrate
from fgcal.measurements.base import NoiseComponent, ObservationRows, Terms
from fgcal.measurements.contact import SetupMeasurement
from fgcal.measurements.dataset import Noise
from fgcal.measurements.setup import FixtureSpec, SetupSpec
from fgcal.measurements.types import register, unregister
from fgcal.robots.kinematics import tool_points
from fgcal.robots.robot_file import load_model
from fgcal.robots.transforms import euler_zyx_trans
from fgcal.studies.simulate import SimulationSettings, simulate


@dataclass
class PivotLengths(ObservationRows):
    pose: np.ndarray
    ball: np.ndarray
    fixture: np.ndarray
    length: np.ndarray
    line: np.ndarray | None = None

    ROW_SHAPES = {"length": ()}

    def __post_init__(self):
        self.fixture = np.asarray(self.fixture, dtype=str).reshape(-1)
        super().__post_init__()


class PivotLength(SetupMeasurement):
    """A ballbar length from a tool ball to a pivot fixture: 1 row ``|FK offset - p| - L`` (mm)."""

    level = "pivot_lengths"
    file = "pivot_lengths.csv"
    columns = ("pose", "ball", "fixture", "length")
    fixture_type = "point"
    width = 1
    title = "ballbar lengths to a pivot fixture"
    noun = "length"
    noise_key = None
    sigma_field = "pivot_length"
    noise_components = (NoiseComponent("pivot_lengths", slice(0, 1), "pivot_length"),)

    def declared_sigmas(self, noise) -> dict:
        return {self.sigma_field: float(noise.distance_sigma if noise.distance_sigma is not None else noise.cmm_sigma)}

    def terms(self, obs, tooling, row_of_pose, layout=None) -> Terms:
        pose = np.array([row_of_pose[p] for p in obs.pose.tolist()], dtype=int)
        start = np.array([layout.offset[f] for f in obs.fixture.tolist()], dtype=int)
        return Terms(pose, (tooling.offsets(obs.ball).reshape(-1, 3), start, obs.length))

    def setup_error(self, theta, q, data, s, index, held, chain):
        offset, start, length = data
        cols = start[:, None] + np.arange(3)
        p, J_t, J_q = self._ball_points(theta, q, offset, index, held, chain)
        d = p - s[cols]
        dist = np.linalg.norm(d, axis=1)
        u = (d / dist[:, None])[:, None, :]
        return (dist - length)[:, None], u @ J_t, u @ J_q, -u, cols

    def block_starts(self, obs, T, tooling, unknown, where) -> dict:
        """The pivot by trilateration of the predicted ball centres (linear in ``(c, |c|^2)``)."""
        pts = tool_points(T, tooling.offsets(obs.ball)[:, None, :])[:, 0]
        out = {}
        for f in dict.fromkeys(obs.fixture.tolist()):
            if f in unknown:
                sel = obs.fixture == f
                A = np.column_stack([2 * pts[sel], -np.ones(sel.sum())])
                b = np.sum(pts[sel] ** 2, axis=1) - obs.length[sel] ** 2
                out[f] = np.linalg.lstsq(A, b, rcond=None)[0][:3]
        return out

    def observations(self, pose, ball, values, line=None):
        raise NotImplementedError

    def rows(self, obs):
        return ([int(p), b, f, float(v)] for p, b, f, v in zip(obs.pose, obs.ball, obs.fixture, obs.length,
                                                                strict=True))

    def metric(self, e):
        return np.abs(np.asarray(e)[:, 0]), None

    def residual_summary(self, e) -> dict:
        return {"pivot_lengths_mm": np.asarray(e)[:, 0].tolist()}


@pytest.fixture
def pivot_type():
    kind = PivotLength()
    register(kind)
    yield kind
    unregister(kind)


def test_a_pivot_fixture_gives_the_ballbar_numbers(pivot_type):
    puma = load_model("puma560")
    settings = SimulationSettings(n_poses=60, n_balls=1, levels=("distances",), noise=Noise(0.005, 0.0))
    ds, _ = simulate(puma, np.random.default_rng(21), settings)  # the ballbar data of tests/test_chains.py
    builtin = calibrate(ds, puma, CalibrationOptions())

    d = ds.distances
    general_ds = ds.select(ds.pose_ids)
    general_ds.distances = None
    general_ds.pivot_lengths = PivotLengths(d.pose, d.ball, np.full(len(d), "pivot"), d.length)
    general_ds.setup = SetupSpec({"pivot": FixtureSpec("pivot", "point")})
    general = calibrate(general_ds, puma, CalibrationOptions())

    # the gauge differs: base translation estimated (pivot at the origin) or held (pivot a fixture)
    held_b = {h["name"] for h in builtin.held}
    held_g = {h["name"] for h in general.held}
    assert {"base.px", "base.py", "base.pz"} <= held_g - held_b
    assert "world frame" in general.setup["gauge"]
    # the robot's parameters: the same estimates and sigmas
    robot = [n for n in builtin.names if not n.startswith("base.")]
    assert robot == [n for n in general.names if not n.startswith(("base.", "fixture."))]
    b = {p.name: p for p in builtin.parameters}
    g = {p.name: p for p in general.parameters}
    z = np.array([(b[n].estimate - g[n].estimate) / b[n].sigma for n in robot])
    ratio = np.array([g[n].sigma / b[n].sigma for n in robot])
    print("max |estimate difference| / sigma", np.abs(z).max(), "sigma ratios", ratio.min(), ratio.max())
    assert np.abs(z).max() < 1e-3 and np.abs(ratio - 1).max() < 1e-3
    # the pivot fixture in the base's nominal frame is where the built-in form put the world origin
    pivot = np.array(general.setup["estimated"]["pivot"]["position"])
    bx = np.array([b[f"base.p{c}"].estimate for c in "xyz"])
    nominal = np.array([puma.nominal[puma.slot(f"base.p{c}")] for c in "xyz"])
    R0 = euler_zyx_trans(*[puma.nominal[puma.slot(f"base.{f}")] for f in ("phi", "theta", "psi")], 0, 0, 0)[:3, :3]
    assert np.abs(pivot - R0 @ (nominal - bx)).max() < 1e-3  # R0 (x + p_b) = R0 (x + p_0) - pivot: the base's
    # rotation is nominal in both forms, so the frames differ by the translation alone
    # the same length residuals
    r_b, r_g = np.array(builtin.residuals["distances_mm"]), np.array(general.residuals["pivot_lengths_mm"])
    assert np.abs(r_b - r_g).max() < 1e-6
    assert builtin.levels["distances"].variance_factor == pytest.approx(general.levels["pivot_lengths"].variance_factor,
                                                                        rel=1e-6)
    # GTSAM's own optimiser on the general form's graph ends at its batch solve
    other = calibrate(general_ds, puma, CalibrationOptions(engine="gtsam"))
    assert other.names == general.names
    assert np.max(np.abs(other.estimate - general.estimate) / general.sigma) < 1e-3
