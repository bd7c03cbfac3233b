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
    """One factor per pose's centres and per pose's probes: the same total error as the graph of one
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


def test_shared_pose_kinematics_gives_the_factors_own_rows(puma):
    """The pose-centre factors reading a filled factors.PoseKinematics linearise to the rows they
    compute themselves (to rounding), and compute their own at values it was not filled at."""
    import gtsam

    from fgcal.estimation.build import build_graph
    from fgcal.estimation.gtsam_graph import _nonlinear_graph, nonlinear_graph

    ds, _ = simulate(puma, np.random.default_rng(19), SimulationSettings(n_poses=5))
    graph, state, _ = build_graph(ds, puma, list(puma.parameters().names), CalibrationOptions())
    own, values = nonlinear_graph(graph, state)
    shared_graph, _, shared = _nonlinear_graph(graph, state)
    assert shared is not None

    def system(g, v):
        A, b = g.linearize(v).jacobian()
        return A, b

    def fill(v):
        q = [v.atVector(gtsam.symbol("q", i)) for i in range(graph.n_poses)]
        shared.fill(v.atVector(gtsam.symbol("k", 0)), q)

    fill(values)
    assert shared.rows(0, [0], values.atVector(gtsam.symbol("k", 0)), values.atVector(gtsam.symbol("q", 0))) is not None
    A0, b0 = system(own, values)
    A1, b1 = system(shared_graph, values)
    np.testing.assert_allclose(A1, A0, rtol=1e-9, atol=1e-9 * np.abs(A0).max())
    np.testing.assert_allclose(b1, b0, rtol=1e-9, atol=1e-9 * np.abs(b0).max())
    # Elsewhere (not filled there): each factor's own kinematics, so the same rows again.
    delta, rng = gtsam.VectorValues(), np.random.default_rng(3)
    for k in values.keys():
        delta.insert(k, 1e-3 * rng.normal(size=values.atVector(k).shape))
    moved = values.retract(delta)
    assert shared.rows(0, [0], moved.atVector(gtsam.symbol("k", 0)), moved.atVector(gtsam.symbol("q", 0))) is None
    A2, b2 = system(shared_graph, moved)
    A3, b3 = system(own, moved)
    np.testing.assert_allclose(A2, A3, rtol=0, atol=0)
    np.testing.assert_allclose(b2, b3, rtol=0, atol=0)
    assert not np.allclose(b2, b0)  # the move changed the rows: the comparison above can fail
