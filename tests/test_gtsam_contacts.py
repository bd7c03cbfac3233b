"""The GTSAM engine on contacts (DESIGN.md 8.2): fixture points, a plane and known distances as
GTSAM factors on the parameter vector (the set-up entries close it, as in the batch graph).

On a dataset from the independent generator (tests/contact_sim.py: two-socket plates and a
table, with noisy joint readings so that the poses' joints are variables), GTSAM's own
Levenberg-Marquardt (through ``calibrate``) reaches the batch engine's estimate to 1e-5 sigma,
and ``gtsam.Marginals`` (of the nonlinear graph, and of the linearised one) is the batch
covariance to 1e-6 relative. Every contact and distance factor's Jacobian is checked against
``gtsam.utils.numerical_derivative`` at seeded random points."""
import shutil

import gtsam
import numpy as np
import pytest
from contact_sim import plane_dataset, two_socket_dataset
from test_contacts_simulated import DATA, ROBOTS, _merge
from test_factors import _check

import factors as fx
from fgcal.estimation.calibrate import CalibrationOptions, calibrate, solve_calibration
from fgcal.estimation.gtsam_graph import distance_constraint_factor, gtsam_covariance, nonlinear_graph, to_gtsam
from fgcal.io.dataset_io import dataset_model, load_dataset, save_dataset
from fgcal.measurements.types import BY_LEVEL


@pytest.fixture(scope="module")
def both(tmp_path_factory):
    """Two plates of two sockets (8 configurations each) and 15 table contacts of a perturbed Panda."""
    tmp = tmp_path_factory.mktemp("gtsam_contacts")
    name, chain = ROBOTS["panda"]
    rng = np.random.default_rng(3)
    sockets = two_socket_dataset(tmp / "sockets", DATA / name, chain, rng, n_placements=2, configs_per_socket=8,
                                 contact_sigma_mm=0.02, joint_sigma_deg=0.002, distance_sigma_mm=0.005)
    plane_dataset(tmp / "plane", DATA / name, chain, rng, n_contacts=15, ball_radius_mm=4.0, contact_sigma_mm=0.02,
                  joint_sigma_deg=0.002, true_urdf=sockets.urdf, patch_radius_mm=200.0, max_tries=5)
    save_dataset(_merge(load_dataset(tmp / "sockets"), load_dataset(tmp / "plane")), tmp / "both")
    shutil.copy(tmp / "sockets" / "robot.urdf", tmp / "both" / "robot.urdf")
    ds = load_dataset(tmp / "both")
    assert len(ds.contacts) and len(ds.plane_contacts) and ds.setup.distances
    return ds


def test_gtsam_engine_matches_the_batch(both):
    ds, model = both, dataset_model(both)
    batch = calibrate(ds, model, CalibrationOptions())
    gt = calibrate(ds, model, CalibrationOptions(engine="gtsam"))
    assert gt.names == batch.names and any(n.startswith("plane.") for n in batch.names)
    # 1e-5: each engine stops at its own convergence test (3.9e-6 sigma apart with scipy 1.17.1, under 1e-6 before)
    assert np.max(np.abs(gt.estimate - batch.estimate) / batch.sigma) < 1e-5

    # GTSAM's covariance at the batch solution (noise as estimated, outliers as excluded)
    sol = solve_calibration(ds, model, CalibrationOptions())
    graph, state = sol.graph, sol.state
    assert graph.joint_vars and graph.S and graph.setup.spec.distances
    cov = graph.covariance(state)
    g, values = nonlinear_graph(graph, state)
    assert g.error(values) == pytest.approx(graph.cost(state), rel=1e-9)
    marginal = gtsam.Marginals(g, values).marginalCovariance(fx.theta_key())
    d = np.sqrt(np.outer(np.diag(cov), np.diag(cov)))  # relative to each entry's scale
    assert np.max(np.abs(marginal - cov) / d) < 1e-6
    assert np.max(np.abs(gtsam_covariance(graph, state) - cov) / d) < 1e-6
    # to_gtsam: the same parameters as calibrate (the gauge held, the set-up entries last)
    g0, v0, names, _ = to_gtsam(ds, model)
    assert not any(n.startswith("base.") for n in names) and names[-graph.S:] == list(graph.setup.names())


@pytest.mark.parametrize("joints", ["variables", "fixed"])
def test_contact_and_distance_factor_jacobians(both, joints):
    ds, model = both, dataset_model(both)
    sol = solve_calibration(ds, model, CalibrationOptions(joint_noise=joints == "variables"))
    graph = sol.graph
    rng = np.random.default_rng(11)
    t_key = fx.theta_key()
    column = graph.n_geo + graph.K
    checked = 0
    for _trial in range(3):
        theta = sol.state.theta + rng.normal(scale=1e-3, size=sol.state.theta.shape)  # a random point
        for level, terms in graph.measurements.items():
            kind = BY_LEVEL[level]
            for m in rng.choice(len(terms), size=3, replace=False):
                i = int(terms.pose[m])
                v = gtsam.Values()
                v.insert(t_key, theta)
                if graph.joint_vars:
                    v.insert(fx.joint_key(i), graph.readings[i] + rng.normal(scale=1e-3, size=graph.n_joints))
                    qargs = {"q_key": fx.joint_key(i)}
                else:
                    qargs = {"q_fixed": graph.readings[i]}
                f = kind.factor([d[m] for d in terms.data], graph.index, graph.held, kind.sigma(graph.sigmas),
                                t_key=t_key, chain=graph.chain, setup=graph.setup, setup_column=column, **qargs)
                _check(f, v)
                checked += 1
        for c in range(len(graph.setup.spec.distances)):
            v = gtsam.Values()
            v.insert(t_key, theta)
            _check(distance_constraint_factor(graph.setup, c, column, t_key), v)
            checked += 1
    assert checked == 3 * (6 + len(graph.setup.spec.distances))


def test_contact_error_at_given_setup_values(both):
    """``error`` is ``setup_error`` at the set-up values that close the payload."""
    ds, model = both, dataset_model(both)
    sol = solve_calibration(ds, model, CalibrationOptions(joint_noise=False))
    graph, theta = sol.graph, sol.state.theta
    s = graph.setup_values(theta)
    for level, terms in graph.measurements.items():
        kind = BY_LEVEL[level]
        q = graph.readings[terms.pose]
        full = kind.setup_error(theta[:graph.n_geo], q, terms.data, s, graph.index, graph.held, graph.chain)
        got = kind.error(theta[:graph.n_geo], q, (*terms.data, s), graph.index, graph.held, graph.chain)
        for a, b in zip(got, full[:3]):
            np.testing.assert_array_equal(a, b)
