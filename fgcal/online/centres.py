"""Ball centres from a pose's probe points for the online engines: the plain fits (all at once),
the mirror images a narrow or early pose leaves open, and narrow caps linearised at the prediction."""
from __future__ import annotations

import numpy as np

from fgcal.measurements.spherefit import (
    best_of_candidates,
    chi2_quantile,
    fit_spheres_batch,
    fit_spheres_checked,
    mirror_through_points,
)
from fgcal.online.records import PoseData

__all__ = ["INNOVATION_FALSE_ALARM", "NARROW_CAP", "NEAR_ENOUGH", "prefit"]

INNOVATION_FALSE_ALARM = 1e-6
MIRROR_CHI2 = chi2_quantile(1 - INNOVATION_FALSE_ALARM, 1)  # a mirror image this close in fit is a candidate
# A cap is narrow when the smallest eigenvalue of its fit's information is below this share of the
# largest (the centre is then poorly determined across the cap's axis). Measured on the simulated
# PUMA's balls (10 seeded datasets): 0.30 or more for the usual probing, 0.0033 at most for points
# within 8 deg of the cap's axis.
NARROW_CAP = 0.05
NEAR_ENOUGH = 0.02  # a prediction this close (share of the radius): linearising there errs by 2e-4 radius


def _good_centres(rec: PoseData, tooling, sigma_cmm: float, prediction=None, spread=None, flip=(),
                  search: bool = False, min_balls: int = 3):
    """Fitted centres of a pose's probed balls: ``(good, ambiguous, None)`` or ``(None, [], reason)``.

    ``good``: ``(ball, xyz, cov)`` per usable ball. ``prediction`` (ball -> xyz, mm): where the
    current estimate puts each ball. As in the batch solve, of the centres that fit a cap of
    points equally well (the fit and its mirror image through the points) the one nearer the
    prediction is taken, and a residual above the sphere check's limit is left to the innovation
    gate. A ball whose plain fit passes its check and lies near its prediction (within a quarter
    of the radius, and nearer it than a quarter of the way to its mirror image) is taken as fitted:
    the search among mirror images, which costs most of a pose's time, runs for the other balls,
    or for all with ``search`` (the innovation gate's second look). ``ambiguous``: the balls
    searched whose mirror image fits as well (the gate may take it for the balls in ``flip``).

    A ball probed on a narrow cap (:data:`NARROW_CAP`) has no centre worth fitting: its points
    determine the centre well along the cap's axis only, and the fitted centre (or its mirror) can
    lie millimetres off with a covariance that its linearisation there understates. Its centre is
    the points' information linearised at the prediction instead (:func:`_linearised_at`), the
    first-order content of its probe residuals there, as the batch's joint solve sees them,
    once the prediction is certain enough for that (``spread``, ball -> mm, within
    :data:`NEAR_ENOUGH` of the radius); until then only along the cap's axis
    (:func:`_axial_only`): a fitted centre there, even the one nearer the prediction, can be
    millimetres off and would corrupt the early estimate.
    """
    good, bad = [], []
    usable = [(b, p) for b, p in rec.probes if len(p) >= 3]
    bad += [f"ball {b}: {len(p)} probe points" for b, p in rec.probes if len(p) < 3]
    sigma = max(sigma_cmm, 1e-6)
    prefit([rec], tooling, sigma_cmm)
    assert rec.fits is not None  # set by prefit
    fits = [rec.fits[j][1:4] for j, (_, p) in enumerate(rec.probes) if len(p) >= 3]
    kept, narrow = [], {}
    for (ball, pts), (fit, mirror, thin) in zip(usable, fits):
        # A residual above the sphere check's limit alone does not reject the ball: as in the batch
        # solve, the innovation gate (with the kinematic prediction's redundancy) judges the pose.
        if not fit.ok and not (prediction is not None and fit.status.startswith("residual")):
            bad.append(f"ball {ball}: {fit.status}")
            continue
        kept.append((ball, pts, fit, mirror))
        if thin and prediction is not None and ball in prediction:
            narrow[ball] = (_linearised_at(pts, prediction[ball], tooling.radius, sigma)
                            if spread[ball] < NEAR_ENOUGH * tooling.radius else
                            _axial_only(pts, prediction[ball], tooling.radius, sigma, spread[ball]))
    chosen, ambiguous = {}, []
    if prediction is not None:
        kept_pred = [k for k in kept if k[0] in prediction and k[0] not in narrow]
        if not search and kept_pred:
            kept_pred = [k for k, plain in zip(kept_pred, _plain_fit_will_do(kept_pred, prediction, tooling.radius))
                         if not plain]
        chosen, ambiguous = _search_mirrors([k[:3] for k in kept_pred], prediction, tooling.radius, sigma, flip)
    for ball, pts, fit, _ in kept:
        centre, cov = fit.centre, fit.covariance
        if ball in narrow:
            if narrow[ball] is None:
                continue
            centre, cov = narrow[ball]
        elif ball in chosen and np.linalg.norm(chosen[ball] - centre) > 1e-9:
            d = pts - chosen[ball]
            J = d / np.linalg.norm(d, axis=1, keepdims=True)
            centre, cov = chosen[ball], np.linalg.inv(J.T @ J) * sigma**2
        good.append((ball, centre, cov))
    if rec.probes and len(good) + sum(v is None for v in narrow.values()) < min_balls:
        return None, [], f"{len(good)} good ball(s) of {len(rec.probes)}; a pose needs {min_balls}" + (
            f" ({'; '.join(bad)})" if bad else "")
    return good, ambiguous, None


def _linearised_at(points, centre, radius: float, sigma: float):
    """``(centre (3,), covariance (3, 3))`` that the probe ``points`` (n, 3) say about a ball centre
    near ``centre``: their residuals ``|p - c| - radius`` linearised there (one Gauss-Newton step,
    mm; covariance ``sigma^2 (U'U)^-1`` with U the unit directions from ``centre`` to the points)."""
    d = points - centre
    dist = np.linalg.norm(d, axis=1)
    U = d / dist[:, None]
    info = U.T @ U
    return centre + np.linalg.solve(info, U.T @ (dist - radius)), np.linalg.inv(info) * sigma**2


def _axial_only(points, centre, radius: float, sigma: float, spread: float):
    """``(centre (3,), covariance (3, 3))`` from a narrow cap's ``points`` along its axis only, for a
    prediction ``centre`` of standard deviation ``spread`` (mm): the mean distance of the points
    from it says where the centre lies along the axis (to ``spread^2 / 2 radius``, the error of
    a prediction off to the side); across the axis the covariance is the radius squared, which
    leaves the information there to the other balls and poses. None when that axial error
    exceeds the radius (the ball then says nothing: it is left out of the pose, not refused)."""
    d = points - centre
    dist = np.linalg.norm(d, axis=1)
    axis = np.mean(d / dist[:, None], axis=0)
    axis /= np.linalg.norm(axis)
    along = sigma**2 / len(points) + (spread**2 / (2.0 * radius)) ** 2
    aa = np.outer(axis, axis)
    if along > radius**2:  # the prediction is too uncertain for the cap to say anything
        return None
    return centre + np.mean(dist - radius) * axis, along * aa + radius**2 * (np.eye(3) - aa)


def _plain_fit_will_do(kept, prediction, radius) -> np.ndarray:
    """For each ``(ball, points, fit, mirror)``: its fit passed its check and lies near the
    prediction (a quarter of the radius, and a quarter of the way to its mirror image): any other
    start would end in the same minimum."""
    ok = np.array([fit.ok for _, _, fit, _ in kept])
    centre = np.array([fit.centre for _, _, fit, _ in kept])
    pred = np.array([prediction[b] for b, _, _, _ in kept])
    d_pred, d_mirror = _lengths(centre - pred), _lengths(centre - np.array([m for _, _, _, m in kept]))
    return ok & (d_pred < 0.25 * radius) & (d_pred < 0.25 * d_mirror)


def _lengths(d) -> np.ndarray:
    """The rows' Euclidean lengths (K,) of ``d`` (K, 3): ``np.linalg.norm(d, axis=1)``'s sum, without its dispatch."""
    return np.sqrt(np.add.reduce(d * d, axis=1))


def prefit(records, tooling, sigma_cmm: float) -> None:
    """The plain sphere fit of every probed ball (3 points or more) of ``records`` and its mirror
    image through the points, kept on each record (``fits``): all at once, vectorised (each
    ball's fit is the one a fit of its pose alone gives). Records that have them are left alone."""
    def stale(r, j, p):
        return r.fits is None or j not in r.fits or r.fits[j][0] is not p

    todo = [(r, j, p) for r in records for j, (_, p) in enumerate(r.probes) if len(p) >= 3 and stale(r, j, p)]
    for r in records:
        if r.fits is None:
            r.fits = {}
    if not todo:
        return
    plain: list = [None] * len(todo)  # the unchecked fits, for the final smoothing's build (smoothing_fits)
    fits = fit_spheres_checked([p for _, _, p in todo], tooling.radius, max(sigma_cmm, 1e-6), plain=plain)
    covs = np.array([f.covariance for f in fits])
    finite = np.all(np.isfinite(covs), axis=(1, 2))
    ev = np.linalg.eigvalsh(np.where(finite[:, None, None], covs, np.eye(3)))
    thin = finite & (ev[:, 0] < NARROW_CAP * ev[:, -1])
    counts = np.array([len(p) for _, _, p in todo])
    mirrors = np.empty((len(todo), 3))
    for n in np.unique(counts):
        idx = np.nonzero(counts == n)[0]
        mirrors[idx] = mirror_through_points(np.array([todo[i][2] for i in idx]),
                                             np.array([fits[i].centre for i in idx]))
    for (r, j, p), fit, mirror, narrow, c in zip(todo, fits, mirrors, thin.tolist(), plain):
        r.fits[j] = (p, fit, mirror, narrow, c)  # the points themselves: a record whose points are replaced is fitted again


def smoothing_fits(records, radius: float) -> dict:
    """The sphere fits of ``records`` (:func:`prefit`'s) as the batch build takes them
    (:data:`fgcal.estimation.build.PLAIN_FITS`, :data:`~fgcal.estimation.build.MIRRORS`): each
    ball's unchecked fit and the mirror image of its fit, by the bytes of its points."""
    from fgcal.estimation.build import MIRRORS, PLAIN_FITS

    plain, mirrors = {}, {}
    for r in records:
        for p, fit, mirror, _, c in (r.fits or {}).values():
            key = np.ascontiguousarray(p, dtype=float).tobytes()
            if c is not None:
                plain[(radius, key)] = c
            mirrors[(key, np.ascontiguousarray(fit.centre, dtype=float).tobytes())] = mirror
    return {PLAIN_FITS: plain, MIRRORS: mirrors}


def _search_mirrors(kept, prediction, radius, sigma, flip):
    """Of each ball's fit, its mirror image and a fit started at the prediction, the one the batch
    takes; balls with equal point counts at once. Returns ``(ball -> centre, ambiguous balls)``."""
    chosen, ambiguous = {}, []
    by_count: dict[int, list] = {}
    for ball, pts, fit in kept:
        by_count.setdefault(len(pts), []).append((ball, pts, fit))
    for group in by_count.values():
        pts = np.array([p for _, p, _ in group])
        first = np.array([f.centre for _, _, f in group])
        pred = np.array([prediction[b] for b, _, _ in group])
        refits = fit_spheres_batch(np.concatenate([pts, pts]), radius,
                                   guess=np.concatenate([mirror_through_points(pts, first), pred]))
        cands = [first, refits[:len(group)], refits[len(group):]]
        near = best_of_candidates(pts, radius, cands, sigma, pred)
        # the mirror image, where it fits nearly as well (within the 1e-6 chi-square limit of
        # one residual): the innovation gate may take it for the balls in ``flip``
        other = fit_spheres_batch(pts, radius, guess=mirror_through_points(pts, near))
        ssr = [np.sum((np.linalg.norm(pts - c[:, None], axis=2) - radius) ** 2, axis=1) for c in (near, other)]
        alike = (ssr[1] <= ssr[0] + MIRROR_CHI2 * sigma**2) & (np.linalg.norm(other - near, axis=1) > radius)
        for k, (ball, _, _) in enumerate(group):
            if alike[k]:
                ambiguous.append(ball)
            chosen[ball] = other[k] if (ball in flip and alike[k]) else near[k]
    return chosen, ambiguous
