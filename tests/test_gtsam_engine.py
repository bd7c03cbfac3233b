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
