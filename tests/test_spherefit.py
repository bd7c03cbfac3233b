import numpy as np
import pytest

from fgcal.measurements.spherefit import algebraic_sphere, default_threshold, fit_sphere

CENTRE = np.array([612.0, 233.0, 471.0])
R = 6.35


def cap_points(rng, n, polar_deg=(45.0, 75.0)):
    """As the simulator probes: the pole, then a ring of n-1 points 45-75 deg from it."""
    polar = np.radians(rng.uniform(*polar_deg, n))
    polar[0] = 0.0
    az = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.arange(n) / max(n - 1, 1)
    d = np.stack([np.sin(polar) * np.cos(az), np.sin(polar) * np.sin(az), np.cos(polar)], axis=1)
    return CENTRE + R * d, d


def test_exact_points_give_the_exact_centre():
    rng = np.random.default_rng(40)
    pts, _ = cap_points(rng, 4)
    c, r = algebraic_sphere(pts)
    np.testing.assert_allclose(c, CENTRE, atol=1e-8)
    assert abs(r - R) < 1e-8
    for radius in (R, None):
        fit = fit_sphere(pts, radius=radius, sigma=0.0)
        np.testing.assert_allclose(fit.centre, CENTRE, atol=1e-9)
        assert fit.ok and fit.rms < 1e-9


@pytest.mark.parametrize("n", [4, 8])
def test_covariance_matches_monte_carlo(n):
    rng = np.random.default_rng(41 + n)
    pts, _ = cap_points(rng, n)
    sigma = 0.01
    errors = []
    for _ in range(3000):
        fit = fit_sphere(pts + rng.normal(size=pts.shape) * sigma, radius=R, sigma=sigma)
        errors.append(fit.centre - CENTRE)
    errors = np.array(errors)
    predicted = fit_sphere(pts, radius=R, sigma=sigma).covariance
    np.testing.assert_allclose(np.cov(errors.T), predicted, atol=0.1 * np.abs(predicted).max())
    assert np.all(np.abs(errors.mean(axis=0)) < 4 * np.sqrt(np.diag(predicted) / len(errors)))


def test_false_alarm_rate_is_small():
    rng = np.random.default_rng(43)
    pts, _ = cap_points(rng, 4)
    flagged = sum(not fit_sphere(pts + rng.normal(size=pts.shape) * 0.01, radius=R, sigma=0.01).ok
                  for _ in range(3000))
    assert flagged / 3000 < 0.005  # nominal 0.001


def test_an_outlier_is_flagged_and_named_when_redundancy_allows():
    rng = np.random.default_rng(44)
    for n, nameable in ((4, False), (6, True)):
        pts, dirs = cap_points(rng, n)
        pts = pts + rng.normal(size=pts.shape) * 0.01
        pts[2] += 0.5 * dirs[2]
        fit = fit_sphere(pts, radius=R, sigma=0.01)
        assert not fit.ok
        if nameable:
            assert fit.suspect == 2 and "outlier: point 3" in fit.status
        else:
            assert fit.suspect is None and "not enough to say which" in fit.status


def test_free_radius_is_recovered():
    rng = np.random.default_rng(45)
    pts, _ = cap_points(rng, 10, polar_deg=(30.0, 85.0))
    fit = fit_sphere(pts + rng.normal(size=pts.shape) * 0.001, radius=None, sigma=0.001)
    assert fit.ok and abs(fit.radius - R) < 0.01


def test_threshold_follows_the_noise():
    assert default_threshold(0.01, 4) == pytest.approx(0.01 * np.sqrt(10.828 / 4), rel=1e-3)
    assert default_threshold(0.0, 4) == 1e-6


def test_too_few_points():
    with pytest.raises(ValueError, match="at least 3"):
        fit_sphere(np.zeros((2, 3)), radius=R)
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        fit_sphere(np.zeros((4, 2)), radius=R)
