"""The noise model estimated from the data: variance components and gross errors.

Each measurement level (probe points, measured centres, measured poses' positions and
rotations, joint readings) is a *variance component*: its sigma is scaled until the sum of its
squared whitened residuals equals its redundancy, the sum over its rows of one minus the row's
leverage (Foerstner's redundancy numbers; iterated, this is Helmert's/Foerstner's variance
component estimation). A component is estimated only where its redundancy reaches
:data:`MIN_REDUNDANCY`; below that the declared sigma stays and the result says so.

Gross errors are found by data snooping (Baarda's w-test): each measurement row's squared
residual over its redundancy number, in units of the level's robust scale (:func:`robust_scale`),
is tested against the chi-square(1) quantile of :data:`OUTLIER_ALPHA` (or of
:data:`FAMILY_ALPHA` over the level's rows, if stricter: a good measurement excluded costs
accuracy); a measurement is as gross as its worst row; per pose and round the worst one is
excluded and the solve is repeated. Every exclusion is named (pose, ball, line of the file).

Pure functions of a :class:`~fgcal.estimation.graph.Graph` and its linearisation; no I/O.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from enum import Enum

import numpy as np

from fgcal.estimation.elimination import scaled_inverse
from fgcal.estimation.graph_types import included
from fgcal.measurements.types import BY_LEVEL, all_levels, kinematic_types
from fgcal.util.chi2 import chi2_cdf, chi2_isf, chi2_sf

__all__ = [
    "MIN_REDUNDANCY",
    "OUTLIER_ALPHA",
    "LevelNoise",
    "NoiseMode",
    "Outlier",
    "OutlierMode",
    "component_table",
    "components",
    "find_outliers",
    "fit_test",
    "included_leverage",
    "readmissible",
    "robust_scale",
    "scaled_inverse",
]

log = logging.getLogger(__name__)

MIN_REDUNDANCY = 5.0  # below this a variance factor is too uncertain (its relative sigma sqrt(2/r) > 0.6)
OUTLIER_ALPHA = math.erfc(4.0 / math.sqrt(2.0))  # a single-coordinate residual beyond 4 sigma (6.3e-5) ...
FAMILY_ALPHA = 0.01  # ... or below 1% false alarms over a level's measurements, whichever is stricter
MAX_OUTLIER_FRACTION = 0.05  # more than this in a level is a heavy-tailed distribution, not gross errors
SCALE_LIMITS = (1e-2, 1e3)  # an estimated sigma stays within these multiples of the declared one
SCALE_CUT_ALPHA = 1e-3  # the robust scale averages the statistics below this chi-square tail (3.3 sigma)


class NoiseMode(str, Enum):
    """Where the measurement noise comes from."""

    ESTIMATED = "estimated"  # from the residuals, per level, where the redundancy allows
    DECLARED = "declared"  # dataset.yaml's values only


class OutlierMode(str, Enum):
    """What happens to gross errors."""

    EXCLUDE = "exclude"  # detect by data snooping, exclude and name them
    NONE = "none"  # keep every measurement


def component_table() -> dict:
    """Variance components: name -> (graph level, columns of its factor rows, Sigmas field, unit, to unit).

    Probe points and joint readings, and each registered measurement type's own components
    (:attr:`fgcal.measurements.base.KinematicMeasurement.noise_components`).
    """
    table = {"probes": ("probes", slice(0, 1), "probe", "mm", 1.0)}
    for kind in kinematic_types():
        for c in kind.noise_components:
            table[c.name] = (kind.level, c.columns, c.sigma_field, c.unit, c.to_unit)
    table["joints"] = ("joints", slice(0, None), "joint", "deg", float(np.degrees(1.0)))  # revolute joints: deg
    return table



@dataclass
class LevelNoise:
    """One variance component: declared and estimated sigma, and the test of the declared one.

    Attributes
    ----------
    declared, used : float
        Sigma in ``unit`` from dataset.yaml, and the one the covariance is computed with.
    estimated : float or None
        Sigma estimated from the residuals; None when the redundancy is too small (``note``).
    redundancy : float
        Sum of the redundancy numbers of the component's rows.
    variance_factor : float
        Squared residuals over redundancy at the *declared* sigma: ``(estimated / declared)**2``.
    p_value : float
        Two-sided chi-square test of the declared sigma (small: the declared noise is wrong).
    """

    unit: str
    declared: float
    used: float
    estimated: float | None
    redundancy: float
    variance_factor: float
    p_value: float
    note: str = ""


@dataclass
class Outlier:
    """A measurement excluded as a gross error, so that it can be re-measured.

    ``index`` is its row among the level's measurements (0-based, file order), ``line`` its line
    in the file (0 when made in memory); ``statistic`` is its largest coordinate's residual in sigmas of the level's
    scale, corrected for its redundancy.
    """

    level: str
    pose: int
    ball: str | None
    index: int
    line: int
    residual: float
    unit: str
    statistic: float


def components(graph, lin, h) -> dict[str, tuple[float, float]]:
    """Per variance component: (sum of squared whitened residuals, redundancy), kept rows only.

    ``h`` (N, m) is the rows' leverage (:meth:`fgcal.estimation.graph.Graph.row_leverage`).
    """
    out = {}
    for name, (level, cols, _, _, _) in component_table().items():
        if level not in graph.row:
            continue
        pose, rows = graph.factor_rows(level)
        kept = ~graph.excluded.get(level, np.zeros(len(pose), dtype=bool))
        rows = rows[kept][:, cols]
        p = pose[kept, None]
        out[name] = (float(np.sum(lin.r[p, rows] ** 2)), float(np.sum(1.0 - h[p, rows])))
    return out


def robust_scale(t, width: int, cut_alpha: float = SCALE_CUT_ALPHA) -> float:
    """Robust variance factor of chi-square(``width``) statistics ``t`` (K,) with a few gross ones among them.

    The mean of the statistics below the ``cut_alpha`` tail quantile of the current scale, divided
    by the mean of a chi-square truncated there, iterated from the median's scale. Gross errors
    beyond the cut do not enter it; for clean data it scatters about two thirds as much as the
    median's scale (relative sigma about 1.5/sqrt(K) against 2.3/sqrt(K) for one-dimensional
    rows), so fewer good measurements are excluded because the scale came out low.
    """
    t = np.asarray(t, dtype=float)
    t = t[np.isfinite(t)]
    if not t.size:
        return float("nan")
    scale = float(np.median(t) / chi2_isf(width, 0.5))
    if not scale > 0:
        return scale
    cut = float(chi2_isf(width, cut_alpha))
    # E[X | X < c] for X ~ chi-square(k): k P(chi2(k + 2) < c) / P(chi2(k) < c)
    truncated_mean = width * chi2_cdf(width + 2, cut) / chi2_cdf(width, cut)
    for _ in range(20):
        new = float(np.mean(t[t <= cut * scale]) / truncated_mean)
        if abs(new - scale) <= 1e-9 * scale:
            break
        scale = new
    return scale


def _row_sigma(graph, level) -> np.ndarray:
    """The sigma of each of a factor's rows (width,) at the graph's current noise."""
    if level == "probes":
        return np.array([graph.sigmas.probe])
    kind = next(t for t in kinematic_types() if t.level == level)
    return np.asarray(kind.sigma(graph.sigmas), dtype=float)


def _row_statistics(graph, lin, h, level, h_in=None):
    """Per factor of ``level``: each row's squared whitened residual over its redundancy number.

    Returns ``(pose (K,), w2 (K, width), excluded (K,))``. Each row's ``w2`` is chi-square(1) times
    the level's variance factor when the noise model holds (Baarda's w-test), however the rows of
    a factor are correlated; their sum is not chi-square(width) when they are (a measured centre's
    three coordinates share a pose's joint variables), which made good centres look gross.
    Excluded factors carry zero in ``lin.r``: their rows are recomputed from the raw errors. Their
    residual ``r`` is then the one of the solution without them, whose variance is the row's
    noise plus the prediction's (the parameters' and the pose's joint variables'): with ``h_in``
    (N, m), the leverage with every measurement included (:func:`included_leverage`), ``r**2 (1 -
    h_in)`` is the statistic the row would have if it were included (``r_in = (1 - h_in) r``, the
    leave-one-out identity); without it the prediction's variance is left out (conservative).
    """
    pose, rows = graph.factor_rows(level)
    r = lin.r[pose[:, None], rows]
    red = np.maximum(1.0 - h[pose[:, None], rows], 1e-9)
    excluded = graph.excluded.get(level, np.zeros(len(pose), dtype=bool))
    if excluded.any():
        r[excluded] = lin.raw[level][0][excluded] / _row_sigma(graph, level)
        red[excluded] = 1.0
        if h_in is not None:
            red[excluded] = 1.0 / np.maximum(1.0 - h_in[pose[excluded][:, None], rows[excluded]], 1e-9)
    return pose, r**2 / red, excluded


def included_leverage(graph, state) -> np.ndarray:
    """The rows' leverage (N, m) at ``state`` as if no measurement were excluded (see :func:`_row_statistics`)."""
    lin = included(graph.linearise(state))  # the excluded rows put back: no second evaluation
    return graph.row_leverage(state, scaled_inverse(graph.parameter_information(state, lin)), lin)


def _column_scales(level, w2, kept) -> np.ndarray:
    """The robust scale (:func:`robust_scale`) of each of a level's rows (width,), per variance component.

    A level's components (a measured pose's position and rotation rows) are scaled apart: one
    scale over all rows of a level judged the position rows of a pose in units of a mix of both,
    and where the declared ratio of the two sigmas was wrong (3x on real tracker data) good
    positions were excluded in the first round. Columns of no component share the level's scale.
    """
    scales = np.full(w2.shape[1], robust_scale(w2[kept].ravel(), 1))
    for lv, cols, *_ in component_table().values():
        if lv == level and np.sum(kept) >= 10:
            part = w2[kept][:, cols]
            if part.size:
                scales[cols] = robust_scale(part.ravel(), 1)
    return scales


def _ratios(graph, lin, h, level, alpha: float = OUTLIER_ALPHA, h_in=None):
    """Per factor of ``level``: its statistic over the test's limit (beyond 1: gross), and which are excluded.

    The statistic is the largest row's ``w2`` (:func:`_row_statistics`) in units of its
    component's robust scale of the kept rows (:func:`_column_scales`); the limit is the
    chi-square(1) quantile of ``alpha`` or of :data:`FAMILY_ALPHA` over the level's rows,
    whichever is stricter. An excluded factor's residual is its distance from the solution
    without it (its redundancy number taken as 1: its own noise only, a little conservative).
    Returns ``(pose (K,), ratio (K,) or None when the level is too small to test, excluded (K,))``.
    """
    pose, w2, excluded = _row_statistics(graph, lin, h, level, h_in)
    if np.sum(~excluded) < 10:
        return pose, None, excluded
    scales = _column_scales(level, w2, ~excluded)
    if not np.all(scales > 0):
        return pose, None, excluded
    ratio = (w2 / scales).max(axis=1) / chi2_isf(1, min(alpha, FAMILY_ALPHA / w2.size))
    return pose, ratio, excluded


def find_outliers(graph, lin, h, alpha: float = OUTLIER_ALPHA) -> dict[str, np.ndarray]:
    """Gross errors to exclude next: at most one per pose, the worst beyond the test's limit (:func:`_ratios`).

    Returns ``{level: indices of its factors}`` (only new ones). A level where more than
    :data:`MAX_OUTLIER_FRACTION` would be excluded is left alone (logged): its residuals are
    heavy-tailed rather than a few gross errors.
    """
    best: dict[int, tuple[float, str, int]] = {}  # pose -> (ratio, level, index)
    for level in all_levels():
        if level not in graph.row:
            continue
        pose, ratio, excluded = _ratios(graph, lin, h, level, alpha)
        if ratio is None:
            continue
        ratio = np.where(excluded, 0.0, ratio)
        if np.sum(excluded) + np.sum(ratio > 1) > MAX_OUTLIER_FRACTION * len(pose):
            log.info("%s: %d residuals beyond the outlier limit: heavy tails, none excluded", level,
                     int(np.sum(ratio > 1)))
            continue
        for k in np.nonzero(ratio > 1)[0]:
            if ratio[k] > best.get(int(pose[k]), (0.0,))[0]:
                best[int(pose[k])] = (float(ratio[k]), level, int(k))
    out: dict[str, list[int]] = {}
    for _, level, row in best.values():
        out.setdefault(level, []).append(row)
    return {lv: np.array(sorted(ks), dtype=int) for lv, ks in out.items()}


def readmissible(graph, lin, h, h_in=None, alpha: float = OUTLIER_ALPHA) -> dict[str, np.ndarray]:
    """Excluded measurements that pass the outlier test at the current noise and solution: ``{level: indices}``.

    An exclusion is decided at the noise of its round (the declared one in the first); once the
    noise is estimated each one is tested again, with the same statistic and limit as
    :func:`find_outliers`, and those within the limit are measurements like the others. ``h_in``:
    the leverage with every measurement included (:func:`included_leverage`).
    """
    out = {}
    for level, mask in graph.excluded.items():
        if not mask.any():
            continue
        _, ratio, excluded = _ratios(graph, lin, h, level, alpha, h_in)
        if ratio is None:
            back = np.nonzero(excluded)[0]  # too few measurements left to test any: keep them all
        else:
            back = np.nonzero(excluded & (ratio <= 1))[0]
        if back.size:
            out[level] = back
    return out


def name_outliers(graph, lin, h, ds, pose_ids, h_in=None) -> list[Outlier]:
    """The excluded measurements with their pose, ball and line in the file (``h_in``: see :func:`readmissible`)."""
    out = []
    for level, mask in graph.excluded.items():
        if not mask.any():
            continue
        pose, w2, _ = _row_statistics(graph, lin, h, level, h_in)
        kept = ~mask
        scales = _column_scales(level, w2, kept) if kept.any() else np.ones(w2.shape[1])
        e = lin.raw[level][0]
        obs = getattr(ds, level)
        # a row's ball, or what the type names a row by (a camera's corner: its point)
        labels = obs.ball if hasattr(obs, "ball") else getattr(obs, "point", None)
        unit = getattr(BY_LEVEL[level], "unit", "mm") if level in BY_LEVEL else "mm"
        for k in np.nonzero(mask)[0]:
            resid = float(np.abs(e[k, 0])) if level == "probes" else float(np.linalg.norm(
                e[k, 3:] if level == "poses" else e[k]))
            label = str(labels[k]) if level != "poses" and labels is not None else None
            line = int(obs.line[k]) if getattr(obs, "line", None) is not None else 0
            out.append(Outlier(level, int(pose_ids[pose[k]]), label, int(k), line, resid, unit,
                               float(np.sqrt((w2[k] / scales).max()))))
    return sorted(out, key=lambda o: (o.pose, o.level, o.index))


def fit_test(ssq: float, redundancy: float) -> float:
    """Two-sided p-value of ``ssq`` (sum of squared whitened residuals) against chi-square(redundancy)."""
    if redundancy <= 0:
        return float("nan")
    return float(min(1.0, 2 * min(chi2_cdf(redundancy, ssq), chi2_sf(redundancy, ssq))))


def noise_row(unit: str, k: float, used: float, decl: float, ssq: float, red: float, mode: NoiseMode) -> LevelNoise:
    """One row of a noise table: a component (or one group of it) with weighted residual sum of squares
    ``ssq`` and redundancy ``red`` at the sigma ``used``, declared ``decl`` (``k``: the unit's scale)."""
    ratio2 = (used / decl) ** 2 if decl > 0 else float("nan")
    vf_declared = ssq / red * ratio2 if red > 0 else float("nan")
    estimable = red >= MIN_REDUNDANCY
    at_floor = decl > 0 and used <= SCALE_LIMITS[0] * decl * (1 + 1e-9)
    if mode is NoiseMode.DECLARED:
        note = "declared (--noise declared)"
    elif at_floor:  # the rounds brought it down until its rows no longer count (variance_steps)
        note = (f"not resolved: the data show none of this noise; held at its floor ({SCALE_LIMITS[0]:g} x the "
                f"declared sigma), where its redundancy is {red:.3g}")
        estimable = False
    elif not estimable and decl > 0 and not math.isclose(used, decl, rel_tol=1e-9):
        note = (f"not resolved: lowered from the declared sigma until its redundancy fell to {red:.3g} "
                f"(estimating it needs {MIN_REDUNDANCY:g}); the data show no more of this noise")
    elif not estimable:
        note = f"declared: redundancy {red:.3g} is too small to estimate it (needs {MIN_REDUNDANCY:g})"
    else:
        note = "estimated"
    estimated = float(decl * np.sqrt(vf_declared) * k) if estimable and np.isfinite(vf_declared) else None
    return LevelNoise(unit, float(decl * k), float(used * k), estimated, float(red), float(vf_declared),
                      fit_test(ssq * ratio2, red), note)


def level_noise(comps, sigmas, declared, mode: NoiseMode) -> dict[str, LevelNoise]:
    """The noise table of a finished solve: ``comps`` at the final ``sigmas``."""
    out = {}
    for name, (ssq, red) in comps.items():
        _, _, field, unit, k = component_table()[name]
        used = float(np.max(getattr(sigmas, field)))  # joints: the largest (one scale for all of them)
        decl = float(np.max(getattr(declared, field)))
        out[name] = noise_row(unit, k, used, decl, ssq, red, mode)
    return out
