"""A linearisation keeps its excluded measurements' rows as they would be included: putting them back
(:func:`fgcal.estimation.graph_types.included`) gives the linearisation with nothing excluded, which the
outlier test's leverage needs, without evaluating the factors again."""
import numpy as np

from fgcal.estimation.calibrate import CalibrationOptions, build_graph
from fgcal.estimation.graph_types import included
from fgcal.estimation.noise import included_leverage, scaled_inverse
from fgcal.measurements.contact import ContactObservations
from fgcal.measurements.dataset import Dataset, Noise
from fgcal.measurements.setup import DistanceConstraint, FixtureSpec, SetupSpec
from fgcal.robots.model import Tooling


def _contacts(model, seed=2, n=40):
    rng = np.random.default_rng(seed)
    lo, hi = model.joint_limits[:, 0], model.joint_limits[:, 1]
    q = rng.uniform(np.maximum(lo, -2.5), np.minimum(hi, 2.5), size=(n, model.n_joints))
    kinds = np.array(["s0", "s1", "table"])
    fixture = kinds[np.arange(n) % 3]
    ds = Dataset(robot=model.name, tooling=Tooling(4.0, {"B": np.array([10.0, -5.0, 60.0])}),
                 noise=Noise(cmm_sigma=0.01, joint_resolution=0.001, extra=(("contact_sigma", 0.02),)),
                 provenance={}, pose_ids=np.arange(1, n + 1), joints_deg=model.joints_to_file_units(q),
                 setup=SetupSpec({"s0": FixtureSpec("s0", "point"), "s1": FixtureSpec("s1", "point"),
                                  "table": FixtureSpec("table", "plane")}, (DistanceConstraint("s0", "s1", 50.0, 0.01),)))
    pt = fixture != "table"
    ds.contacts = ContactObservations(ds.pose_ids[pt], np.full(pt.sum(), "B"), fixture[pt])
    ds.plane_contacts = ContactObservations(ds.pose_ids[~pt], np.full((~pt).sum(), "B"), fixture[~pt])
    return ds


def test_excluded_rows_put_back_equal_the_linearisation_without_exclusions(puma):
    ds = _contacts(puma)
    graph, state, _ = build_graph(ds, puma, puma.parameters().names, CalibrationOptions())
    assert graph.joint_vars  # joint variables: the rows have local columns too
    state.theta = state.theta + np.random.default_rng(1).normal(scale=1e-3, size=state.theta.shape)
    plain = graph.linearise(state, remember=False)
    graph.excluded = {"contacts": np.arange(len(graph.row["contacts"])) % 5 == 1,
                      "plane_contacts": np.arange(len(graph.row["plane_contacts"])) == 3}
    lin = graph.linearise(state)
    pose, rows = graph.factor_rows("contacts")
    out = graph.excluded["contacts"]
    assert np.all(lin.r[pose[out, None], rows[out]] == 0.0) and np.all(lin.J_theta[pose[out, None], rows[out]] == 0.0)
    assert np.all(lin.J_local[pose[out, None], rows[out]] == 0.0) and lin.cost < plain.cost
    back = included(lin)
    for a, b in ((back.r, plain.r), (back.J_theta, plain.J_theta), (back.J_local, plain.J_local)):
        assert np.array_equal(a, b)
    h = graph.row_leverage(state, scaled_inverse(graph.parameter_information(state, plain)), plain)
    assert np.array_equal(included_leverage(graph, state), h)
    assert graph.linearise(state) is lin  # the one with the exclusions is still the graph's
