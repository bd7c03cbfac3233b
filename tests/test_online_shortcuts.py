"""The online engines' shortcuts keep their results: the EKF relinearises only where a step bends the
measurement (:data:`fgcal.online.kalman.LINEAR_ENOUGH`), its running estimate where relinearising by
the step's size alone puts it, to a stated tolerance; the final smoothing builds its graph from the
engine's own sphere fits, the same graph to the last bit."""
import numpy as np

from fgcal.estimation.build import build_graph
from fgcal.estimation.options import CalibrationOptions
from fgcal.online.centres import prefit, smoothing_fits
from fgcal.online.engines import make_engine, pose_records
from fgcal.online.measurement import PoseMeasurement
from fgcal.online.records import records_dataset
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


def test_the_smoothing_build_from_the_engines_fits_is_the_batch_build(puma, monkeypatch):
    """The graph's starting state built from the engine's sphere fits (a ball with a gross probe
    point among them: its checked fit is not the plain one) equals, bit for bit, the one that
    fits the spheres again, at the nominal start and at a warm one; no plain fit nor mirror
    image is formed again."""
    import fgcal.estimation.build as build

    again = []
    for name in ("fit_spheres_batch", "mirror_through_points"):
        fn = getattr(build, name)
        monkeypatch.setattr(build, name, lambda *a, fn=fn, **k: (again.append((fn.__name__, "guess" in k)), fn(*a, **k))[1])
    ds, _ = simulate(puma, np.random.default_rng(3), SimulationSettings(n_poses=60))
    records = pose_records(ds, model=puma)
    ball, pts = records[5].probes[1]
    records[5].probes[1] = (ball, pts + np.array([[0.0, 0.0, 0.0]] * (len(pts) - 1) + [[0.5, 0.0, 0.0]]))
    prefit(records, ds.tooling, ds.noise.cmm_sigma)
    seen = records_dataset(ds, records, puma)
    names = puma.parameters().names
    start = None
    for options in (CalibrationOptions(prior="none"), CalibrationOptions(prior="weak")):
        mine = smoothing_fits(records, ds.tooling.radius)
        again.clear()
        _, a, _ = build_graph(seen, puma, names, options, start=start, fits=mine)
        assert again and all(guess for _, guess in again)  # only the refits from a guess
        _, b, _ = build_graph(seen, puma, names, options, start=start, fits={})
        assert mine["plain fits"] and all(np.array_equal(u, v) for u, v in zip((a.theta, a.q, a.c), (b.theta, b.q, b.c)))
        start = puma.nominal + 1e-4
