"""The noise rounds settle where the data show none of a declared noise (exact joint readings declared
with a 0.001 deg resolution: 36-38 rounds before, the round limit on the UR10 bench) and still estimate
a joint noise that is there (fgcal.estimation.variance_steps)."""
from dataclasses import replace

import numpy as np
import pytest

from fgcal.estimation.calibrate import CalibrationOptions, calibrate
from fgcal.estimation.graph_types import Sigmas
from fgcal.estimation.noise import SCALE_LIMITS
from fgcal.estimation.variance_steps import VarianceSteps, update_sigmas
from fgcal.measurements.dataset import Noise
from fgcal.studies.simulate import SimulationSettings, simulate
from fgcal.studies.simulate_setup import SetupSimulation

RESOLUTION = 0.001  # deg, declared: a sigma of 0.001 / sqrt(12) deg
CASES = {"centres": SimulationSettings(n_poses=60, levels=("centres",)),
         "stations": SimulationSettings(n_poses=60, levels=("centres",), setup=SetupSimulation(stations=3))}


def _rounds(v_true: float, steps, limit: int = 200) -> tuple[int, float]:
    """Rounds of :func:`update_sigmas` to settle one component whose variance factor is the expected one
    beside a known other of variance 1: ``f(v) = (v_true + 1) / (v + 1)`` (declared variance 1); and the
    variance where it settled."""
    sigmas = Sigmas(probe=1.0, centre=1.0, pose_position=1.0, pose_rotation=1.0, joint=0.0)
    for n in range(1, limit + 1):
        v = sigmas.probe**2
        f = (v_true + 1.0) / (v + 1.0)
        sigmas, changed = update_sigmas(sigmas, {"probes": (100.0 * f, 100.0)}, sigmas.replaced(probe=1.0),
                                        steps=steps)
        if not changed:
            return n, sigmas.probe**2
    return limit, sigmas.probe**2


@pytest.mark.parametrize("v_true", [0.0, 0.05, 0.3, 4.0])
def test_the_secant_settles_where_foerstner_crawls(v_true):
    slow, v_slow = _rounds(v_true, None)
    fast, v_fast = _rounds(v_true, VarianceSteps())
    assert fast <= 7
    if v_true == 0.0:
        # Foerstner's: 1/v grows by 1 a round, f within 1 % of 1 only at v < 0.0101: about 100 rounds
        assert slow > 90
        assert v_fast == pytest.approx(SCALE_LIMITS[0] ** 2)  # the floor
    else:
        assert abs((v_true + 1) / (v_fast + 1) - 1) < 0.01 and fast < slow
        assert v_fast == pytest.approx(v_true, abs=0.03 * (1 + v_true))


def _dataset(puma, case: str, repeatability: float):
    settings = replace(CASES[case], noise=Noise(0.01, 0.0, repeatability))  # readings not rounded
    ds, _ = simulate(puma, np.random.default_rng(7), settings)
    ds.noise = replace(ds.noise, joint_resolution=RESOLUTION)
    return ds


def _z(result, ds) -> np.ndarray:
    return np.array([(p.estimate - ds.truth[p.name]) / p.sigma for p in result.parameters if p.name in ds.truth])


@pytest.mark.parametrize("case,engine", [("centres", "batch"), ("stations", "batch"), ("centres", "gtsam")])
def test_exact_joints_with_a_declared_resolution_settle_at_the_truth(puma, case, engine):
    ds = _dataset(puma, case, 0.0)
    r = calibrate(ds, puma, CalibrationOptions(engine=engine))
    assert r.fit_test["noise_rounds"] <= 8 and r.iterations <= 20  # before: 36-38 rounds, 74-87 iterations
    joints = r.noise["joints"]  # at its floor, or where its redundancy ran out, or a small value the data settle at
    assert joints.used < 0.35 * joints.declared
    assert joints.note.startswith("not resolved") == (joints.estimated is None)
    z = _z(r, ds)
    assert len(z) == 30 and np.abs(z).max() < 3.5 and 0.7 < np.sqrt(np.mean(z**2)) < 1.3
    # as if the readings had been declared exact: the same estimates and sigmas
    exact = calibrate(replace(ds, noise=replace(ds.noise, joint_resolution=0.0)), puma, CalibrationOptions(engine=engine))
    assert np.max(np.abs(r.estimate - exact.estimate) / exact.sigma) < 0.05
    assert np.allclose(r.sigma, exact.sigma, rtol=0.03)  # stations: joints settle at 8.7e-5 deg, 1-2 % wider
    for name, n in exact.noise.items():
        assert r.noise[name].estimated == pytest.approx(n.estimated, rel=0.02)


@pytest.mark.parametrize("case", ["centres", "stations"])
def test_a_real_joint_noise_is_still_estimated(puma, case):
    ds = _dataset(puma, case, 0.005)  # deg per joint, 17 times the declared resolution's sigma
    r = calibrate(ds, puma)
    assert r.fit_test["noise_rounds"] <= 4
    joints = r.noise["joints"]
    assert joints.note == "estimated" and joints.estimated == pytest.approx(0.005, rel=0.2)
    z = _z(r, ds)
    assert np.abs(z).max() < 3.5 and 0.6 < np.sqrt(np.mean(z**2)) < 1.4
