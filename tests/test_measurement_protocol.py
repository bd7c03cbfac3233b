"""The measurement plug-in protocol: a measurement type written only here (a height gauge reading the
z coordinate of a tool ball) and registered, then simulated, written and read, solved in the batch
graph and in GTSAM, designed for and verified through fgcal's own code, without edits to fgcal.
Numbers are checked against computations written here (finite differences of plain forward
kinematics)."""
from dataclasses import dataclass

import numpy as np
import pytest

from fgcal.estimation.calibrate import CalibrationOptions, build_graph, calibrate
from fgcal.estimation.verification import verify
from fgcal.io.dataset_io import load_dataset, save_dataset
from fgcal.measurements import types
from fgcal.measurements.base import KinematicMeasurement, NoiseComponent, ObservationRows, Terms
from fgcal.measurements.cells import ball_name, number
from fgcal.measurements.dataset import Noise
from fgcal.robots.kinematics import tool_points
from fgcal.studies.simulate import SimulationSettings, simulate


@dataclass
class HeightObservations(ObservationRows):
    pose: np.ndarray
    ball: np.ndarray
    z: np.ndarray
    line: np.ndarray | None = None

    ROW_SHAPES = {"z": ()}


class HeightMeasurement(KinematicMeasurement):
    """The world z (mm) of a tool ball's centre, as a height gauge reads it."""

    level = "heights"
    file = "heights.csv"
    columns = ("pose", "ball", "z")
    width = 1
    per_ball = True
    title = "ball heights"
    noun = "height"
    noise_components = (NoiseComponent("heights", slice(0, 1), "height"),)

    def error(self, theta, q, data, index, held, chain):
        from factors.errors import ball_centre_error

        offset, z = data
        p, J_t, J_q = ball_centre_error(theta, q, offset, np.zeros((len(z), 3)), index, held, chain)
        return p[:, 2:3] - np.asarray(z, dtype=float).reshape(-1, 1), J_t[:, 2:3], J_q[:, 2:3]

    def declared_sigmas(self, noise):
        return {"height": noise.cmm_sigma}

    def sigma(self, sigmas):
        return np.array([sigmas.height])

    def terms(self, obs, tooling, row_of_pose):
        return Terms(np.array([row_of_pose[p] for p in obs.pose.tolist()], dtype=int),
                     (tooling.offsets(obs.ball).reshape(-1, 3), obs.z))

    def design_data(self, forward, offsets):
        return offsets, tool_points(forward, offsets[:, None, :])[:, 0, 2]

    def simulate(self, T, offsets, rng, noise):
        z = tool_points(T, offsets[:, None, :])[:, 0, 2]
        return (z + rng.normal(size=len(z)) * HEIGHT_NOISE)[:, None]  # not what the dataset declares

    def parse(self, where, record, balls):
        return ball_name(record["ball"], where, balls), np.array([number(record["z"], where, "z")])

    def observations(self, pose, ball, values, line=None):
        return HeightObservations(pose, ball, np.asarray(values, dtype=float).reshape(-1), line)

    def rows(self, obs):
        return ([int(p), b, float(z)] for p, b, z in zip(obs.pose, obs.ball, obs.z))

    def metric(self, e):
        return np.abs(np.asarray(e)[:, 0]), None

    def residual_summary(self, e):
        return {"heights_mm": np.asarray(e)[:, 0].tolist()}


HEIGHT = HeightMeasurement()
HEIGHT_NOISE = 0.03  # mm: three times the declared cmm_sigma
EXACT_JOINTS = Noise(cmm_sigma=0.01, joint_resolution=0.0)


@pytest.fixture
def with_heights(monkeypatch):
    monkeypatch.setattr(types, "KINEMATIC_TYPES", types.KINEMATIC_TYPES + (HEIGHT,))
    monkeypatch.setitem(types.BY_LEVEL, "heights", HEIGHT)
    return HEIGHT


def _simulated(puma, seed, levels, n_poses=30, truth=None):
    return simulate(puma, np.random.default_rng(seed),
                    SimulationSettings(n_poses=n_poses, levels=levels, noise=EXACT_JOINTS), truth=truth)[0]


def test_a_registered_type_is_simulated_written_and_read(puma, with_heights, tmp_path):
    ds = _simulated(puma, 1, ("centres", "heights"))
    assert ds.levels() == ["centres", "heights"] and len(ds.heights) == len(ds.centres)
    # Noiseless part of the simulation: the true robot's ball heights, computed here.
    truth = puma.slots_from_file_units(np.array([ds.truth[n] for n in puma.slot_names]))
    q = puma.joints_to_internal(ds.joints_deg[ds.row_of(ds.heights.pose)])
    z_true = np.array([puma.forward(truth, qi[None])[0, :3, :3] @ ds.tooling.balls[b] + puma.forward(truth, qi[None])[0, :3, 3]
                       for qi, b in zip(q, ds.heights.ball)])[:, 2]
    assert np.std(ds.heights.z - z_true) == pytest.approx(HEIGHT_NOISE, rel=0.35)
    save_dataset(ds, tmp_path / "h")
    assert (tmp_path / "h" / "heights.csv").read_text().splitlines()[0] == "pose,ball,z"
    back = load_dataset(tmp_path / "h")
    assert np.array_equal(back.heights.z, ds.heights.z) and np.array_equal(back.heights.ball, ds.heights.ball)


def test_its_rows_in_the_graph_are_its_error_and_jacobian(puma, with_heights):
    """The batch graph's whitened heights rows against finite differences of plain kinematics."""
    ds = _simulated(puma, 2, ("centres", "heights"), n_poses=8)
    opts = CalibrationOptions(joint_noise=False)
    graph, state, pose_ids = build_graph(ds, puma, puma.parameters().names, opts)
    lin = graph.linearise(state)
    pose, rows = graph.factor_rows("heights")
    terms = graph.measurements["heights"]
    sigma = graph.sigmas.height
    assert sigma == EXACT_JOINTS.cmm_sigma  # declared by the type from the dataset's noise

    def heights(theta):
        x = graph.params.full(theta, graph.held)
        T = puma.forward(x, graph.readings[terms.pose])
        return tool_points(T, terms.data[0][:, None, :])[:, 0, 2]

    r = lin.r[pose[:, None], rows][:, 0]
    assert np.allclose(r, (heights(state.theta) - terms.data[1]) / sigma, atol=1e-9)
    J = lin.J_theta[pose[:, None], rows][:, 0]
    h = 1e-6
    J_num = np.array([(heights(state.theta + h * e) - heights(state.theta - h * e)) / (2 * h)
                      for e in np.eye(len(state.theta))]).T / sigma
    assert np.allclose(J, J_num, rtol=1e-5, atol=1e-4 * np.abs(J_num).max())


def test_it_calibrates_in_the_batch_and_in_gtsam(puma, with_heights):
    ds = _simulated(puma, 3, ("centres", "heights"))
    centres_only = calibrate(ds, puma, CalibrationOptions(levels=("centres",), noise="declared"))
    both = calibrate(ds, puma, CalibrationOptions(noise="declared"))
    assert both.names == centres_only.names
    truth = np.array([ds.truth[n] for n in both.names])
    z = (both.estimate - truth) / both.sigma
    assert np.sqrt(np.mean(z**2)) < 2.0
    # More measurements, no less information: every sigma shrinks or stays.
    assert np.all(both.sigma <= centres_only.sigma * (1 + 1e-9)) and np.any(both.sigma < 0.999 * centres_only.sigma)
    assert len(both.residuals["heights_mm"]) == len(ds.heights)
    assert "heights" in both.levels
    # By default each level's noise is estimated, the new type's too: its 3x noise is found.
    estimated = calibrate(ds, puma, CalibrationOptions())
    assert estimated.noise["heights"].used == pytest.approx(HEIGHT_NOISE, rel=0.2)
    assert estimated.noise["centres"].used == pytest.approx(0.01, rel=0.2)
    z = (estimated.estimate - truth) / estimated.sigma
    assert np.sqrt(np.mean(z**2)) < 2.0
    # The GTSAM graph of the same problem has the batch graph's cost.
    from fgcal.estimation.gtsam_graph import nonlinear_graph

    graph, state, _ = build_graph(ds, puma, both.names, CalibrationOptions(noise="declared"))
    g, values = nonlinear_graph(graph, state)
    assert g.error(values) == pytest.approx(graph.linearise(state).cost, rel=1e-9)


def test_design_information_and_verification_use_it(puma, with_heights):
    from fgcal.studies.design_info import Layout, information

    ds = _simulated(puma, 4, ("centres", "heights"), n_poses=6)
    q = puma.joints_to_internal(ds.joints_deg)
    balls = np.zeros((len(q), len(puma.tooling.names)), dtype=bool)
    balls[:, :3] = True
    params = puma.parameters()
    base = information(puma, q, Layout(("centres",), balls, 4), EXACT_JOINTS, params)
    more = information(puma, q, Layout(("centres", "heights"), balls, 4), EXACT_JOINTS, params)
    # With exact joints the information adds up: the heights' part is sum J^T J / sigma^2, J by differences.
    offsets = puma.tooling.offsets()[:3]

    def z_of(theta):
        T = puma.forward(params.full(theta, puma.nominal), q)
        return tool_points(T, offsets)[:, :, 2]  # (N, 3)

    theta0 = params.take(puma.nominal)
    h = 1e-6
    J = np.stack([(z_of(theta0 + h * e) - z_of(theta0 - h * e)) / (2 * h) for e in np.eye(len(theta0))], axis=-1)
    expected = np.einsum("nbp,nbq->npq", J, J) / EXACT_JOINTS.cmm_sigma**2
    assert np.allclose(more - base, expected, rtol=1e-5, atol=1e-6 * np.abs(expected).max())

    # Verification of a heights-only dataset by the type's own metric.
    train = _simulated(puma, 5, ("centres",))
    result = calibrate(train, puma, CalibrationOptions())
    truth = puma.slots_from_file_units(np.array([train.truth[n] for n in puma.slot_names]))
    test = _simulated(puma, 6, ("heights",), n_poses=10, truth=truth)
    v = verify(result, test, puma)
    assert v.reference == "measured ball heights"
    slots = result.slot_vector(puma)
    q_t = puma.joints_to_internal(test.joints_deg[test.row_of(test.heights.pose)])
    z_model = np.array([tool_points(puma.forward(slots, qi[None]), test.tooling.balls[b][None])[0, 0, 2]
                        for qi, b in zip(q_t, test.heights.ball)])
    err = z_model - test.heights.z
    per_pose = [np.sqrt(np.mean(err[test.heights.pose == p] ** 2)) for p in v.pose_ids]
    assert np.allclose(v.after.position_mm, per_pose, atol=1e-9)


@pytest.mark.parametrize("engine", ["ekf", "ukf", "isam2"])
def test_the_online_engines_take_it(puma, with_heights, engine, tmp_path):
    """The online engines take the registered type through the protocol: the run ends at the batch
    solve, and the running estimate (before the final smoothing) uses the heights."""
    import copy
    import json

    from fgcal.online.records import pose_records, read_levels, record_from_json, record_to_json
    from fgcal.online.run import OnlineRun
    from fgcal.robots.model import ParameterSet

    assert "heights" in read_levels()  # fgcal online takes the dataset
    ds = _simulated(puma, 7, ("centres", "heights"), n_poses=40)
    # A pose's heights through the journal's JSON and back.
    rec = pose_records(ds)[0]
    back = record_from_json(json.loads(json.dumps(record_to_json(rec))))
    assert [(lv, b) for lv, b, _ in back.generic] == [(lv, b) for lv, b, _ in rec.generic] and rec.generic
    assert all(np.array_equal(v, w) for (_, _, v), (_, _, w) in zip(back.generic, rec.generic))

    def run(data, path):
        r = OnlineRun(data, puma, engine, path)
        for rec in r.pending():
            r.feed(rec)
        running = r.engine.estimate()  # before the final smoothing
        names = list(r.engine.params.names)
        return r, running, names

    r, (theta, _), names = run(ds, tmp_path / "h.ck")
    accepted = [p["pose"] for p in r.processed if p["accepted"]]
    assert len(accepted) >= 0.9 * ds.n_poses
    result = r.result()
    r.close()
    batch = calibrate(ds.select(list(r.engine.seen)), puma, CalibrationOptions(prior="weak"))
    assert result.names == batch.names
    assert np.abs((result.estimate - batch.estimate) / batch.sigma).max() < 0.05
    assert np.allclose(result.sigma / batch.sigma, 1, atol=0.05)

    no_heights = copy.copy(ds)
    no_heights.heights = None
    r0, (theta0, _), names0 = run(no_heights, tmp_path / "c.ck")
    r0.close()
    assert names0 == names
    params = ParameterSet(puma, tuple(names))
    sd = np.sqrt(np.diag(params.covariance_to_file_units(_cov_internal(batch, params))))
    shift = np.abs(params.to_file_units(theta) - params.to_file_units(theta0)) / sd
    assert shift.max() > 0.5  # the heights moved the running estimate

    # The running estimate's tool points at 20 new joint sets, against the batch's, in the batch's
    # sigma of the prediction (the root of the trace of its covariance, as the engines report it).
    new = _simulated(puma, 8, ("centres",), n_poses=20)
    q = puma.joints_to_internal(new.joints_deg)
    offsets = puma.tooling.offsets()
    b_params = ParameterSet(puma, tuple(batch.names))
    b_theta = b_params.from_file_units(batch.estimate)
    b_slots = batch.slot_vector(puma)

    def points(t):
        return tool_points(puma.forward(b_params.full(t, b_slots), q), offsets).reshape(-1)

    h = 1e-7
    J = np.array([(points(b_theta + h * e) - points(b_theta - h * e)) / (2 * h) for e in np.eye(len(b_theta))]).T
    var = np.einsum("ij,jk,ik->i", J, _cov_internal(batch, b_params), J).reshape(-1, 3).sum(axis=1)
    p_run = tool_points(puma.forward(r.engine.params.full(theta, r.engine.held), q), offsets)
    miss = np.linalg.norm(p_run.reshape(-1, 3) - points(b_theta).reshape(-1, 3), axis=1) / np.sqrt(var)
    assert miss.max() < 3.0, miss.max()


def _cov_internal(result, params):
    """The result's covariance over ``params`` (its names, in their order) in internal units."""
    idx = [result.names.index(n) for n in params.names]
    scale = np.where(params.is_angle, np.radians(1.0), 1.0)
    return result.covariance[np.ix_(idx, idx)] * np.outer(scale, scale)


@pytest.mark.parametrize("engine", ["ekf", "isam2"])
def test_an_online_run_with_it_resumes_to_the_same_result(puma, with_heights, engine, tmp_path):
    """A run interrupted after 17 poses and resumed from its checkpoint (a filter's snapshot and
    replay, iSAM2's replay of the journal with the heights' factors) ends as the uninterrupted one."""
    from online_util import interrupted_and_resumed

    from fgcal.online.run import OnlineRun

    ds = _simulated(puma, 9, ("centres", "heights"), n_poses=25)
    whole, _, second = interrupted_and_resumed(ds, puma, engine, tmp_path, 17)
    expected, got = whole.result(), second.result()
    np.testing.assert_allclose(got.estimate, expected.estimate, rtol=0, atol=1e-9 * np.abs(expected.estimate).max())
    np.testing.assert_allclose(got.covariance, expected.covariance, rtol=1e-7, atol=1e-12)
    assert len(second.history) == len(whole.history)
    np.testing.assert_allclose([h["estimate"] for h in second.history], [h["estimate"] for h in whole.history],
                               rtol=1e-9, atol=1e-9)
    # Streamed poses: the journal holds their heights, and a resume on the bare dataset reads them back.
    import copy

    from fgcal.online.records import pose_records

    streamed = OnlineRun(ds, puma, engine, tmp_path / "s.ck")
    for rec in pose_records(ds, model=puma):
        streamed.feed(rec, streamed=True)
    streamed.close()
    bare = copy.copy(ds)
    bare.centres = bare.heights = None
    again = OnlineRun(bare, puma, engine, tmp_path / "s.ck")
    assert again.resume() == len(ds.pose_ids)
    assert sum(len(r.generic) for r in again.streamed.values()) == len(ds.heights)
    got = again.result()
    np.testing.assert_allclose(got.estimate, expected.estimate, rtol=0, atol=1e-9 * np.abs(expected.estimate).max())
