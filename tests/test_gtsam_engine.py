"""``--engine gtsam``: the Python-driven Levenberg-Marquardt on GTSAM's graph ends at the batch's
optimum, with grouped factors (no robust loss) and with one factor per row (a robust loss)."""
import numpy as np
import pytest

from fgcal.estimation.calibrate import CalibrationOptions, calibrate
from fgcal.studies.simulate import SimulationSettings, simulate


@pytest.mark.parametrize("robust", [None, "huber"])
def test_gtsam_engine_ends_at_the_batch_optimum(puma, robust):
    ds, _ = simulate(puma, np.random.default_rng(17), SimulationSettings(n_poses=10))
    kw = dict(noise="declared", outliers="none", robust=robust)
    batch = calibrate(ds, puma, CalibrationOptions(**kw))
    other = calibrate(ds, puma, CalibrationOptions(engine="gtsam", **kw))
    assert other.converged and other.names == batch.names
    assert np.max(np.abs(other.estimate - batch.estimate) / batch.sigma) < 1e-4
    np.testing.assert_allclose(other.sigma, batch.sigma, rtol=1e-6)


def test_grouped_graph_has_the_rows_of_the_per_row_graph(puma):
    """One factor per pose's balls (its probe and centre rows): the same total error as the graph of one
    factor per row, at a point off the optimum."""
    from fgcal.estimation.build import build_graph
    from fgcal.estimation.gtsam_graph import nonlinear_graph

    ds, _ = simulate(puma, np.random.default_rng(18), SimulationSettings(n_poses=6))
    names = list(puma.parameters().names)
    graph, state, _ = build_graph(ds, puma, names, CalibrationOptions())
    grouped, values = nonlinear_graph(graph, state)
    graph.robust = "huber"
    graph.robust_k = 1e12  # a Huber threshold no row reaches: the Gaussian error, one factor per row
    per_row, _ = nonlinear_graph(graph, state)
    assert grouped.size() < per_row.size()
    assert grouped.error(values) == pytest.approx(per_row.error(values), rel=1e-12)


def test_pose_ball_rows_give_the_factors_own_rows(puma):
    """The pose factors reading a filled factors.PoseBallRows linearise to the rows they compute
    themselves (to rounding), and compute their own at any other values: a copy of the filled
    values, and values elsewhere. Some rows excluded, so that the factors' layouts differ."""
    import gtsam

    from fgcal.estimation.build import build_graph
    from fgcal.estimation.gtsam_graph import _nonlinear_graph, nonlinear_graph

    ds, _ = simulate(puma, np.random.default_rng(19), SimulationSettings(n_poses=5))
    graph, state, _ = build_graph(ds, puma, list(puma.parameters().names), CalibrationOptions())
    graph.excluded = {"probes": np.arange(len(graph.probes[1])) % 7 == 3, "kinematic": np.arange(len(graph.ball_pose)) == 4}
    own, values = nonlinear_graph(graph, state)
    shared_graph, _, shared = _nonlinear_graph(graph, state)
    assert shared is not None and shared_graph.size() == own.size()

    def system(g, v):
        return g.linearize(v).jacobian()

    def fill(v):
        shared.fill(v, v.atVector(gtsam.symbol("k", 0)), gtsam.utilities.extractVectors(v, "q"),
                    gtsam.utilities.extractVectors(v, "c"))

    fill(values)
    assert shared.rows(0, values) is not None and shared.rows(0, gtsam.Values(values)) is None
    A0, b0 = system(own, values)
    A1, b1 = system(shared_graph, values)
    np.testing.assert_allclose(A1, A0, rtol=1e-9, atol=1e-9 * np.abs(A0).max())
    np.testing.assert_allclose(b1, b0, rtol=1e-9, atol=1e-9 * np.abs(b0).max())
    # Other values (not the filled object): each factor's own rows, so exactly the graph's without the cache.
    delta, rng = gtsam.VectorValues(), np.random.default_rng(3)
    for k in values.keys():
        delta.insert(k, 1e-3 * rng.normal(size=values.atVector(k).shape))
    for other in (gtsam.Values(values), values.retract(delta)):
        A2, b2 = system(shared_graph, other)
        A3, b3 = system(own, other)
        np.testing.assert_array_equal(A2, A3)
        np.testing.assert_array_equal(b2, b3)
    assert not np.allclose(b2, b0)  # the move changed the rows: the comparison above can fail
    fill(values.retract(delta))  # filled elsewhere: the first values are no longer read from the cache
    assert shared.rows(0, values) is None
