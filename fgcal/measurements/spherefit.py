"""Ball centres from CMM surface points (the paper's eq. 16), with quality checks.

An algebraic fit gives the starting guess; a geometric least-squares fit (distances to the
sphere) with the radius known, or free, gives the centre, its covariance and per-point
residuals. A fit whose residual is too large for the CMM's noise is flagged, and the point that
most likely caused it is named. Units: mm. No I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from fgcal.util.chi2 import chi2_isf

__all__ = [
    "SphereFit",
    "algebraic_sphere",
    "best_of_candidates",
    "check_points",
    "default_threshold",
    "fit_sphere",
    "fit_spheres_arrays",
    "fit_spheres_batch",
    "fit_spheres_checked",
    "mirror_through_points",
]

FALSE_ALARM = 1e-3  # probability that a good fit is flagged by the default threshold
MIN_THRESHOLD_MM = 1e-6  # exact data still carries floating-point noise


def check_points(points, minimum: int) -> np.ndarray:
    """Convert ``points`` to a float ``(n, 3)`` array with ``n >= minimum``; raise ``ValueError``."""
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape (n, 3), got {points.shape}")
    if len(points) < minimum:
        raise ValueError(f"need at least {minimum} points, got {len(points)}")
    return points


def algebraic_sphere(points) -> tuple[np.ndarray, float]:
    """Centre (3,) and radius of the sphere through ``points`` (n >= 4, not coplanar), linear LS.

    Solves ``|p|^2 = 2 c.p + (r^2 - |c|^2)``; exact for exact points, biased under noise, so it
    serves as the geometric fit's starting guess.
    """
    points = check_points(points, 4)
    A = np.hstack([2.0 * points, np.ones((len(points), 1))])
    b = np.sum(points**2, axis=1)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    centre = sol[:3]
    return centre, float(np.sqrt(max(sol[3] + centre @ centre, 0.0)))


@lru_cache(maxsize=256)
def chi2_quantile(p: float, dof: int) -> float:
    """The ``p`` quantile of the chi-square distribution with ``dof`` degrees of freedom.

    Plain Python (:mod:`fgcal.util.chi2`): ``scipy.special`` takes ~0.3 s to import, ``scipy.stats`` ~1 s.
    """
    return chi2_isf(dof, 1.0 - p)


@lru_cache(maxsize=256)
def _chi2_bound(dof: int) -> float:
    return chi2_quantile(1.0 - FALSE_ALARM, dof)


def default_threshold(sigma: float, n_points: int, n_unknowns: int = 3) -> float:
    """RMS residual (mm) above which a fit is flagged: the chi-square bound at 0.1% false alarm."""
    dof = n_points - n_unknowns
    if dof <= 0 or sigma <= 0:
        return MIN_THRESHOLD_MM
    return max(MIN_THRESHOLD_MM, sigma * float(np.sqrt(_chi2_bound(dof) / n_points)))


def fit_spheres_batch(points, radius: float, iterations: int = 20, guess=None) -> np.ndarray:
    """Centres ``(K, 3)`` of K spheres of known ``radius``, each through n points ``(K, n, 3)``.

    Vectorised Gauss-Newton, without quality checks: a starting point for a joint solve. Points
    on a cap fit two centres equally well (mirror images through the cap); Gauss-Newton finds
    the one nearer its start, so pass ``guess`` (K, 3), for example the kinematic prediction,
    where one is known; otherwise it starts from algebraic fits. A sphere whose points do not
    determine it gets NaN.
    """
    points = np.asarray(points, dtype=float)
    K, n, _ = points.shape
    if guess is not None:
        return _gauss_newton_batch(points, np.asarray(guess, dtype=float).copy(), radius, iterations)
    mean = points.mean(axis=1, keepdims=True)
    local = points - mean  # centred: the algebraic fit is far better conditioned
    A = np.concatenate([2.0 * local, np.ones((K, n, 1))], axis=2)
    b = np.sum(local**2, axis=2)
    sv = np.linalg.svd(A, compute_uv=False)
    good = sv[:, -1] > 1e-9 * sv[:, 0]
    centre = np.full((K, 3), np.nan)
    if not good.any():
        return centre
    AtA = np.einsum("kni,knj->kij", A[good], A[good])
    Atb = np.einsum("kni,kn->ki", A[good], b[good])
    sol = np.linalg.solve(AtA, Atb[..., None])[..., 0]
    centre[good] = _gauss_newton_batch(points[good], sol[:, :3] + mean[good, 0], radius, iterations)
    return centre


def point_groups(owner, xyz, minimum: int = 1):
    """Points grouped by owner (for example a ball variable), stacked by equal count.

    Parameters
    ----------
    owner : array_like of int, shape (M,)
        Index of the sphere each point belongs to (0 .. K-1).
    xyz : array_like, shape (M, 3)

    Yields
    ------
    spheres : ndarray of int, shape (k,)
        The spheres with ``n`` points each (``n >= minimum``).
    points : ndarray, shape (k, n, 3)
    """
    owner = np.asarray(owner, dtype=int)
    xyz = np.asarray(xyz, dtype=float)
    counts = np.bincount(owner)
    order = np.argsort(owner, kind="stable")
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    for n in np.unique(counts):
        if n < minimum:
            continue
        spheres = np.nonzero(counts == n)[0]
        yield spheres, xyz[order[starts[spheres][:, None] + np.arange(n)]]


def fit_spheres_checked(point_sets, radius: float, sigma: float, threshold: float | None = None,
                        plain: list | None = None):
    """:func:`fit_sphere` (known radius) for several balls at once, fast for the common case.

    Balls with equal point counts are fitted together (vectorised Gauss-Newton from algebraic
    starts); a ball that fails the residual check, or whose fit is doubtful, is refitted by
    :func:`fit_sphere` to get its full diagnosis. Returns a list of :class:`SphereFit`.
    ``plain``: a list as long as ``point_sets``, given to be filled with each ball's centre (3,)
    from :func:`fit_spheres_batch` before any check (None for fewer than 4 points).
    """
    out: list[SphereFit | None] = [None] * len(point_sets)
    by_count: dict[int, list[int]] = {}
    for i, pts in enumerate(point_sets):
        by_count.setdefault(len(pts), []).append(i)
    for n, idx in by_count.items():
        if n < 4:
            for i in idx:
                out[i] = fit_sphere(point_sets[i], radius=radius, sigma=sigma, threshold=threshold)
            continue
        centres, res, rms, cov, passed = fit_spheres_arrays(np.array([point_sets[i] for i in idx], dtype=float),
                                                            radius, sigma, threshold)
        for k, i in enumerate(idx):
            if plain is not None:
                plain[i] = centres[k]
            if passed[k]:
                out[i] = SphereFit(centres[k], float(radius), res[k], float(rms[k]), cov[k], True, "ok")
            else:
                out[i] = fit_sphere(point_sets[i], radius=radius, sigma=sigma, threshold=threshold)
    return out


def fit_spheres_arrays(points, radius: float, sigma: float, threshold: float | None = None):
    """The vectorised part of :func:`fit_spheres_checked`: K balls of n >= 4 points each.

    Parameters
    ----------
    points : ndarray, shape (K, n, 3)
        Probe points (mm).

    Returns
    -------
    centres : ndarray, shape (K, 3)
    residuals : ndarray, shape (K, n)
        Signed distances from the fitted spheres (mm).
    rms : ndarray, shape (K,)
    covariance : ndarray, shape (K, 3, 3)
        Of each centre for ``sigma`` (mm^2).
    passed : ndarray of bool, shape (K,)
        The fits that are determined and pass the residual check; the others need
        :func:`fit_sphere`'s full diagnosis (it may still accept them).
    """
    pts = np.asarray(points, dtype=float)
    n = pts.shape[1]
    centres = fit_spheres_batch(pts, radius)
    diff = pts - centres[:, None, :]
    dist = np.linalg.norm(diff, axis=2)
    res = dist - radius
    rms = np.sqrt(np.mean(res**2, axis=1))
    limit = default_threshold(sigma, n, 3) if threshold is None else threshold
    J = -diff / dist[..., None]
    info = np.einsum("kni,knj->kij", J, J)
    finite = np.all(np.isfinite(info), axis=(1, 2))
    eig = np.linalg.eigvalsh(np.where(finite[:, None, None], info, np.eye(3)))
    well = finite & (eig[:, 0] > 1e-12 * eig[:, -1])
    cov = np.linalg.inv(np.where(well[:, None, None], info, np.eye(3))) * sigma**2
    passed = well & np.all(np.isfinite(centres), axis=1) & (rms <= limit)
    return centres, res, rms, cov, passed


def best_of_candidates(points, radius: float, candidates, sigma: float, prediction=None) -> np.ndarray:
    """For each sphere, the candidate centre with the smallest sum of squared residuals.

    ``candidates`` is ``(C, K, 3)`` (for example Gauss-Newton from an algebraic start and from
    its mirror image). Where two candidates fit within the noise (``9 sigma^2`` apart), the one
    nearer ``prediction`` (K, 3) wins.
    """
    points = np.asarray(points, dtype=float)
    cand = np.asarray(candidates, dtype=float)
    ssr = np.sum((np.linalg.norm(points[None] - cand[:, :, None, :], axis=3) - radius) ** 2, axis=2)
    ssr = np.where(np.all(np.isfinite(cand), axis=2), ssr, np.inf)
    best = np.argmin(ssr, axis=0)
    if prediction is not None:
        dist = np.linalg.norm(cand - np.asarray(prediction)[None], axis=2)
        near = ssr <= ssr.min(axis=0) + 9.0 * max(sigma, 1e-6) ** 2
        dist = np.where(near & np.isfinite(dist), dist, np.inf)
        best = np.where(np.isfinite(dist.min(axis=0)), np.argmin(dist, axis=0), best)
    return cand[best, np.arange(cand.shape[1])]


def mirror_through_points(points, centres) -> np.ndarray:
    """Reflect each centre ``(K, 3)`` through the best-fit plane of its points ``(K, n, 3)``."""
    mean = points.mean(axis=1)
    _, _, vt = np.linalg.svd(points - mean[:, None, :])
    normal = vt[:, -1]
    h = np.einsum("ki,ki->k", centres - mean, normal)
    return centres - 2.0 * h[:, None] * normal


def _gauss_newton_batch(pts, c, radius, iterations):
    """Each sphere stops when its own step is below 1e-10 mm (or NaN): its result does not depend
    on the other spheres of the batch."""
    c = np.array(c, dtype=float)
    active = np.arange(len(c))
    for _ in range(iterations):
        p, x = (pts, c) if len(active) == len(c) else (pts[active], c[active])
        diff = p - x[:, None, :]
        dist = np.linalg.norm(diff, axis=2)
        res = dist - radius
        J = -diff / dist[..., None]
        JtJ = np.einsum("kni,knj->kij", J, J)
        Jtr = np.einsum("kni,kn->ki", J, res)
        step = -np.linalg.solve(JtJ + 1e-12 * np.eye(3), Jtr[..., None])[..., 0]
        c[active] = x + step
        active = active[np.max(np.abs(step), axis=1) > 1e-10]  # mm; NaN stops too
        if not len(active):
            break
    return c


@dataclass
class SphereFit:
    """Result of :func:`fit_sphere`.

    Attributes
    ----------
    centre : ndarray, shape (3,)
    radius : float
    residuals : ndarray, shape (n,)
        Signed distance of each point from the fitted sphere (mm).
    rms : float
        RMS of the residuals (mm).
    covariance : ndarray, shape (3, 3)
        Of the centre, for the ``sigma`` given (mm^2); NaN when not determined.
    ok : bool
    status : str
        ``"ok"`` or why not.
    suspect : int or None
        Index of the point that most likely spoils a flagged fit.
    """

    centre: np.ndarray
    radius: float
    residuals: np.ndarray
    rms: float
    covariance: np.ndarray
    ok: bool
    status: str
    suspect: int | None = None


def _gauss_newton(points, centre, radius, free_radius: bool, iterations: int = 50):
    for _ in range(iterations):
        diff = points - centre
        dist = np.linalg.norm(diff, axis=1)
        res = dist - radius
        J = -diff / dist[:, None]
        if free_radius:
            J = np.hstack([J, -np.ones((len(points), 1))])
        step, *_ = np.linalg.lstsq(J, -res, rcond=None)
        centre = centre + step[:3]
        if free_radius:
            radius = radius + step[3]
        if np.linalg.norm(step) < 1e-13 * (1.0 + np.linalg.norm(centre)):
            break
    diff = points - centre
    dist = np.linalg.norm(diff, axis=1)
    J = -diff / dist[:, None]
    if free_radius:
        J = np.hstack([J, -np.ones((len(points), 1))])
    return centre, radius, dist - radius, J


def _initial_centre(points, radius):
    try:
        centre, _ = algebraic_sphere(points)
        if np.all(np.isfinite(centre)) and abs(np.linalg.norm(points - centre, axis=1).mean() - radius) < radius:
            return centre
    except (ValueError, np.linalg.LinAlgError):
        pass
    # Points on a cap: the centre lies a radius behind their mean, along the cap's normal.
    mean = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - mean)
    normal = vt[-1]
    return mean - radius * normal


def fit_sphere(points, radius: float | None = None, sigma: float = 0.01, threshold: float | None = None,
               guess=None) -> SphereFit:
    """Geometric least-squares sphere fit with quality check.

    Parameters
    ----------
    points : array_like, shape (n, 3)
        Surface points (mm); n >= 3 with the radius known, n >= 4 with it free.
    radius : float, optional
        The ball's known radius (mm); fitted when omitted.
    sigma : float
        CMM noise per coordinate (mm), for the covariance and the default threshold.
    threshold : float, optional
        RMS residual (mm) above which the fit is flagged; :func:`default_threshold` by default.
    guess : array_like, shape (3,), optional
        Starting centre (for example from the robot's forward kinematics); it also picks the
        right one of the two solutions that three points and a known radius allow.

    Returns
    -------
    SphereFit
    """
    free = radius is None
    n_unknowns = 4 if free else 3
    points = check_points(points, n_unknowns)
    r0 = radius if not free else algebraic_sphere(points)[1]
    c0 = np.asarray(guess, dtype=float) if guess is not None else _initial_centre(points, r0)
    centre, r, res, J = _gauss_newton(points, c0, r0, free)
    rms = float(np.sqrt(np.mean(res**2)))
    limit = default_threshold(sigma, len(points), n_unknowns) if threshold is None else threshold
    try:
        info = J.T @ J
        cov = np.linalg.inv(info)[:3, :3] * sigma**2
        if np.linalg.cond(info) > 1e12:
            raise np.linalg.LinAlgError
    except np.linalg.LinAlgError:
        return SphereFit(centre, float(r), res, rms, np.full((3, 3), np.nan), False,
                         "points do not determine a sphere (coplanar or coincident)")
    if not np.all(np.isfinite(centre)):
        return SphereFit(centre, float(r), res, rms, cov, False, "fit did not converge")
    if rms <= limit:
        return SphereFit(centre, float(r), res, rms, cov, True, "ok")
    status = f"residual {rms:.4g} mm above {limit:.4g} mm"
    suspect, off, rest_ok = _suspect(points, centre, r, free, sigma, threshold)
    if suspect is None:
        status += f"; {len(points)} points leave one redundant measurement, not enough to say which is bad"
    elif rest_ok:
        status += f"; outlier: point {suspect + 1} ({off:+.4g} mm off the sphere of the others)"
    else:
        status += f"; more than one bad point (worst: point {suspect + 1}, {off:+.4g} mm)"
    return SphereFit(centre, float(r), res, rms, cov, False, status, suspect)


def _suspect(points, centre, radius, free, sigma, threshold):
    """Leave-one-out: the point whose removal leaves the most consistent fit.

    Needs two or more redundant measurements: with one, every normalised residual is the same
    and no point can be singled out. Returns (index or None, its distance off, rest passes).
    """
    n = len(points)
    n_unknowns = 4 if free else 3
    if n - 1 - n_unknowns < 1:
        return None, 0.0, False
    best = None
    for k in range(n):
        keep = np.arange(n) != k
        c, r, res, _ = _gauss_newton(points[keep], centre, radius, free)
        ssr = float(np.sum(res**2))
        if best is None or ssr < best[1]:
            best = (k, ssr, float(np.linalg.norm(points[k] - c) - r))
    k, ssr, off = best
    limit = default_threshold(sigma, n - 1, n_unknowns) if threshold is None else threshold
    return k, off, bool(np.sqrt(ssr / (n - 1)) <= limit)
