"""fgcal.util.chi2 (the default calibration's chi-square tails without scipy) against scipy.special."""
import math

import numpy as np
import pytest
from scipy import special

from fgcal.util.chi2 import chi2_cdf, chi2_isf, chi2_sf

DOFS = [0.5, 1, 2, 3, 5.5, 6, 37.3, 1000, 6000.7, 20000]


@pytest.mark.parametrize("k", DOFS)
def test_quantile_matches_scipy(k):
    for p in [0.5, 0.3, 1e-3, 0.01, 0.99, 1 - 1e-6, 1e-6, 1e-12, 1e-50, 1e-300]:
        assert chi2_isf(k, p) == pytest.approx(special.chdtri(k, p), rel=1e-12), p


@pytest.mark.parametrize("k", DOFS)
def test_tails_match_scipy(k):
    rng = np.random.default_rng(7)
    for x in np.concatenate([k * rng.uniform(0.01, 3.0, 30), [k, k + 1, 1e-6, 5 * k + 300]]):
        assert chi2_cdf(k, x) == pytest.approx(special.chdtr(k, x), rel=1e-10, abs=1e-300)
        assert chi2_sf(k, x) == pytest.approx(special.chdtrc(k, x), rel=1e-10, abs=1e-300)
        assert chi2_cdf(k, x) + chi2_sf(k, x) == pytest.approx(1.0, abs=1e-14)


def test_quantile_inverts_the_tail():
    for k in (1, 4, 250):
        for p in (0.2, 1e-4):
            assert chi2_sf(k, chi2_isf(k, p)) == pytest.approx(p, rel=1e-11)


def test_edges_as_scipy():
    """Where scipy.special gives nan, inf or 0 (a nan statistic of a level without redundancy), so do these."""
    for k, x in [(3, 0.0), (3, math.inf), (0, 1.0), (-1, 1.0), (2, math.nan), (math.nan, 1.0)]:
        for ours, theirs in [(chi2_cdf, special.chdtr), (chi2_sf, special.chdtrc)]:
            np.testing.assert_equal(ours(k, x), float(theirs(k, x)))
    for k, p in [(2, 0.0), (2, 1.0), (2, 1.5), (2, -0.1), (0, 0.5), (2, math.nan)]:
        np.testing.assert_equal(chi2_isf(k, p), float(special.chdtri(k, p)))


def test_default_calibration_imports_no_scipy(tmp_path):
    """The reason for the module: a default calibration, run end to end (read, solve, write), imports
    no scipy (an import at a module's top anywhere on its path costs every run ~0.25 s)."""
    import subprocess
    import sys

    from fgcal import SimulationSettings, load_model, save_dataset, simulate
    ds, _ = simulate(load_model("puma560"), np.random.default_rng(3), SimulationSettings(n_poses=12))
    save_dataset(ds, tmp_path / "ds")
    code = ("import sys, fgcal; "
            f"fgcal.calibrate({str(tmp_path / 'ds')!r}).save({str(tmp_path / 'r.json')!r}); "
            "print(sorted(m for m in sys.modules if m.split('.')[0] == 'scipy'))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip().splitlines()[-1] == "[]"
