"""The EKF relinearises only where a step bends the measurement (:data:`fgcal.online.kalman.LINEAR_ENOUGH`):
its running estimate stays where relinearising by the step's size alone puts it, to a stated tolerance."""
import numpy as np

from fgcal.online.engines import make_engine, pose_records
from fgcal.online.measurement import PoseMeasurement
from fgcal.studies.simulate import SimulationSettings, simulate


def test_relinearising_by_the_bend_keeps_the_running_estimate(puma, monkeypatch):
    """After each of 300 poses the state is that of the step-size rule (``linear_enough = 0``,
    the rule before) to 1e-3 of each posterior sigma, the sigmas to 1e-5 relative; the
    final smoothing's estimate to 1e-6 sigma; the journal's noise estimates to 1e-4 relative; and most relinearisations are gone."""
    ds, _ = simulate(puma, np.random.default_rng(25), SimulationSettings(n_poses=300))
    evaluations = []
    evaluate = PoseMeasurement._evaluate
    monkeypatch.setattr(PoseMeasurement, "_evaluate", lambda m, x: (evaluations.append(m.engine), evaluate(m, x))[1])
    bend, size = make_engine("ekf", ds, puma), make_engine("ekf", ds, puma)
    size.linear_enough = 0.0
    for rec in pose_records(ds):
        a, b = bend.update(rec), size.update(rec)
        assert (a.accepted, a.reason, a.journal.keys()) == (b.accepted, b.reason, b.journal.keys())
        for key in a.journal:  # the noise estimates the pose added, its noise factor: from the running state
            np.testing.assert_allclose(a.journal[key], b.journal[key], rtol=1e-4)
        sigma = np.sqrt(np.diag(size.kf.P))
        assert np.max(np.abs(bend.kf.x - size.kf.x) / sigma) < 1e-3
        np.testing.assert_allclose(np.sqrt(np.diag(bend.kf.P)), sigma, rtol=1e-5)
    n_bend, n_size = evaluations.count(bend), evaluations.count(size)
    assert n_size - len(ds.pose_ids) > 100 and n_bend - len(ds.pose_ids) < 0.25 * (n_size - len(ds.pose_ids))
    bend.finish()
    size.finish()
    (x, _), (y, cov) = bend.estimate(), size.estimate()
    assert np.max(np.abs(x - y) / np.sqrt(np.diag(cov))) < 1e-6
