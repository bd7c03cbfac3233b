"""A graph with many set-up unknowns forms its theta Jacobian on each pose's columns (the robot's and
its fixture's): the same rows, the same dense Jacobian placed from them, the same normal equations,
step, covariance and leverage as the graph formed densely, with joint variables and excluded rows."""
import numpy as np
import pytest

from fgcal.estimation.calibrate import CalibrationOptions, build_graph
from fgcal.estimation.graph_types import included
from fgcal.estimation.joint_errors import JointErrorSpec
from fgcal.measurements.contact import ContactObservations
from fgcal.measurements.dataset import Dataset, Noise
from fgcal.measurements.setup import DistanceConstraint, FixtureSpec, SetupSpec
from fgcal.robots.model import Tooling

SOCKETS = 24


def _many_sockets(model, joint_resolution, seed=3, n=120, known=0):
    """Contacts of one ball in SOCKETS points (pairs 50 mm apart; the first ``known`` fixed at given
    positions, the next ``known`` given with a prior) at random joints (the rows need not be zero: the
    linearisations are compared, not solved)."""
    rng = np.random.default_rng(seed)
    lo, hi = model.joint_limits[:, 0], model.joint_limits[:, 1]
    q = rng.uniform(np.maximum(lo, -2.5), np.minimum(hi, 2.5), size=(n, model.n_joints))
    names = [f"s{k}" for k in range(SOCKETS)]
    fixtures = {f: FixtureSpec(f, "point") for f in names}
    for k in range(known):
        fixtures[names[k]] = FixtureSpec(names[k], "point", rng.normal(size=3) * 300, None, True)
        fixtures[names[known + k]] = FixtureSpec(names[known + k], "point", rng.normal(size=3) * 300, 0.5)
    distances = tuple(DistanceConstraint(names[k], names[k + 1], 50.0, 0.01) for k in range(0, SOCKETS, 2))
    ds = Dataset(robot=model.name, tooling=Tooling(4.0, {"B": np.array([10.0, -5.0, 60.0])}),
                 noise=Noise(cmm_sigma=0.01, joint_resolution=joint_resolution, extra=(("contact_sigma", 0.02),)),
                 provenance={}, pose_ids=np.arange(1, n + 1), joints_deg=model.joints_to_file_units(q),
                 setup=SetupSpec(fixtures, distances))
    ds.contacts = ContactObservations(ds.pose_ids, np.full(n, "B"), np.array(names)[rng.integers(0, SOCKETS, n)])
    return ds


def _graphs(model, joint_resolution, known=0, joint_errors=None):
    """The graph, the same graph formed densely and solved by the dense algebra, and a state off the start."""
    ds = _many_sockets(model, joint_resolution, known=known)
    options = CalibrationOptions(joint_errors=joint_errors, prior="weak")  # weak priors: a regular information (no gauge held)
    names = list(model.parameters().names) + ([] if joint_errors is None else joint_errors.names(model.n_joints))
    graph, state, _ = build_graph(ds, model, names, options)
    dense, _, _ = build_graph(ds, model, names, options)
    dense._pose_columns = None  # the dense layout: every theta column in every row
    dense._setup_split = lambda S: None  # and the dense solve and inverse (not by the sockets' blocks)
    rng = np.random.default_rng(11)
    state.theta = state.theta + rng.normal(scale=1e-3, size=state.theta.shape)
    state.q = state.q + rng.normal(scale=1e-4, size=state.q.shape)
    return graph, dense, state


@pytest.mark.parametrize("joint_resolution, known, joint_errors", [(0.0, 0, None), (0.001, 0, None), (0.0, 3, None),
                                                                    (0.0, 0, JointErrorSpec(harmonics=2)),
                                                                    (0.001, 0, JointErrorSpec(harmonics=2))])
def test_pose_column_linearisation_equals_the_dense_one(puma, joint_resolution, known, joint_errors):
    """Also with fixed sockets (rows with no set-up column), sockets given with a prior, and a joint-error
    map (its block among the robot's columns, with exact and with noisy joint readings)."""
    graph, dense, state = _graphs(puma, joint_resolution, known, joint_errors)
    lin, ref = graph.linearise(state), dense.linearise(state)
    P = len(state.theta)
    assert lin.columns is not None and ref.columns is None
    assert graph._setup_split(graph.parameter_information(state, lin)) is not None  # the blocks' algebra ran
    assert graph.K == (0 if joint_errors is None else 4 * puma.n_joints)
    assert lin.J_stored.shape[2] < P // 2 and lin.J_theta.shape == ref.J_theta.shape
    np.testing.assert_array_equal(lin.r, ref.r)
    np.testing.assert_array_equal(lin.J_theta, ref.J_theta)
    for a, b in zip(graph.normal_equations(lin), dense.normal_equations(ref)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * max(np.abs(b).max(initial=0.0), 1.0))
    _, step, _ = graph.step(state, lin, 1e-3)
    _, step_ref, _ = dense.step(state, ref, 1e-3)
    np.testing.assert_allclose(step, step_ref, rtol=0, atol=1e-9 * np.abs(step_ref).max())
    # The inverses agree to what the information's conditioning allows (the weak priors alone fix the
    # gauge here: a condition number of ~1e10, the two inverses ~3e-7 apart in sigma-scaled units).
    info = dense.parameter_information(state, ref)
    d = np.sqrt(np.diag(info))
    tol = 100 * np.finfo(float).eps * np.linalg.cond(info / np.outer(d, d))
    cov, cov_ref = graph.covariance(state, lin), dense.covariance(state, ref)
    sd = np.sqrt(np.diag(cov_ref))
    assert np.max(np.abs(cov - cov_ref) / np.outer(sd, sd)) <= tol
    np.testing.assert_allclose(graph.row_leverage(state, cov, lin), dense.row_leverage(state, cov_ref, ref),
                               rtol=0, atol=tol)


def test_excluded_rows_are_put_back_on_their_columns(puma):
    graph, dense, state = _graphs(puma, 0.0)
    out = np.zeros(graph.n_poses, dtype=bool)
    out[::7] = True
    graph.excluded = dense.excluded = {"contacts": out}
    lin, ref = graph.linearise(state), dense.linearise(state)
    pose, rows = graph.factor_rows("contacts")
    assert np.all(lin.J_theta[pose[out, None], rows[out]] == 0.0)
    back, back_ref = included(lin), included(ref)
    assert back.columns is lin.columns
    np.testing.assert_array_equal(back.J_theta, back_ref.J_theta)
    assert np.any(back.J_theta[pose[out, None], rows[out]] != 0.0)
