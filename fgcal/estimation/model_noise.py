"""Each compared model at its own noise: the covariance of compliance and compliance+map.

:func:`fgcal.estimation.model_select.compare_models` fits the added models at the geometric fit's
noise, the weighting its cross-validation chose the map's size and prior with. Their residuals are
smaller than the geometric model's (on a real UR10 tracker series 0.06 against 0.27 mm): at the
geometric noise their covariance is 8-20 times too wide. :func:`own_noise` re-fits such a model
with each variance component at the sigma of its own residuals (Foerstner's variance components,
as in :mod:`fgcal.estimation.noise`), and the map's prior scaled by the same factor as the
data's noise (pooled over the components by their redundancy), so that the ratio of prior to
noise, which decides the estimate, stays the one the cross-validation chose: the estimate stays
(to the rounds' tolerance), the covariance is the model's. No I/O here.
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from fgcal.estimation.calibrate import calibrate
from fgcal.estimation.joint_errors import JointErrorSpec
from fgcal.estimation.noise import MIN_REDUNDANCY, NoiseMode, fit_test
from fgcal.estimation.options import CalibrationOptions
from fgcal.estimation.robust_cov import scatter_covariance

__all__ = ["OWN_NOTE", "REUSED", "REUSED_NOTE", "fit_model", "own_noise"]

log = logging.getLogger(__name__)

REUSED = "reused"  # a compared model's noise mode: the geometric fit's noise, not re-estimated
REUSED_NOTE = "estimated by the geometric fit and reused"
OWN_NOTE = "estimated from this model's residuals (its map prior scaled alike)"
MAX_ROUNDS = 6
TOLERANCE = 0.01  # relative change of every component's sigma at which the rounds stop


def _reused_noise(result, geometric):
    """``result`` (a model calibrated at ``geometric``'s noise) saying where its noise came from.

    The calibration itself sees only fixed factors on the declared noise and would call them
    ``declared``; what they are is the geometric fit's noise (estimated where its redundancy
    allowed), reused. Nothing is re-estimated: each component's ``used`` sigma is the geometric
    fit's.
    """
    if geometric.noise_mode != NoiseMode.ESTIMATED.value:
        return result  # the geometric fit had the declared noise: so has this one, truly
    result.noise_mode = REUSED
    result.options["noise"] = REUSED
    result.options["noise_scale"] = dict(geometric.options.get("noise_scale") or {})
    for name, n in result.noise.items():
        g = geometric.noise.get(name)
        if g is None:
            continue
        n.note = REUSED_NOTE if g.note == "estimated" else f"as in the geometric fit ({g.note})"
        if g.declared > 0 and n.declared > 0:  # the calibration saw the reused sigma as declared: undo
            n.variance_factor *= (n.declared / g.declared) ** 2
            n.declared = g.declared
            n.p_value = fit_test(n.variance_factor * n.redundancy, n.redundancy)
    statistic = sum(n.variance_factor * n.redundancy for n in result.noise.values())
    result.fit_test = {**result.fit_test, "statistic": float(statistic),
                       "p_value": fit_test(statistic, result.fit_test.get("redundancy", 0.0))}
    return result


def _extrapolated(u: float, previous: float | None) -> float:
    """The update factor of a component's sigma, extrapolated to the rounds' fixed point (Aitken).

    Under a robust loss (Huber) each round moves a sigma only part of the way (on Series B by
    factors 0.43, 0.74, 0.87, 0.94: a contraction ~0.47, seven rounds to settle to 1%). Where two
    successive factors ``previous``, ``u`` shrink geometrically on a log scale at the rate
    ``rho = log u / log previous`` (0 < rho < 0.9), the remaining rounds sum to
    ``u ** (1 / (1 - rho))``; otherwise ``u``.
    """
    if previous is None or abs(np.log(previous)) < 1e-3 or abs(np.log(u)) < 1e-6:
        return u
    rho = float(np.log(u) / np.log(previous))
    return float(u ** (1.0 / (1.0 - rho))) if 0.0 < rho < 0.9 else u


def fit_model(ds, model, options: CalibrationOptions, spec: JointErrorSpec, geometric):
    """The model ``spec`` calibrated on ``ds`` at its own noise, started at ``geometric``'s.

    ``options`` as for the geometric fit ``geometric`` (a :class:`CalibrationResult` of ``ds``);
    where that fit had the declared noise, so has this one (nothing is estimated). With a map
    (``spec.harmonics``) the covariance is the estimate's scatter
    (:func:`fgcal.estimation.robust_cov.scatter_covariance`), not the posterior.
    """
    fixed = replace(options, estimate_noise=False, noise=NoiseMode.DECLARED,
                    noise_scale=geometric.options.get("noise_scale") or options.noise_scale)

    def fit(spec_, opts_):
        return _reused_noise(calibrate(ds, model, replace(opts_, joint_errors=spec_)), geometric)

    first = fit(spec, fixed)
    res = first if geometric.noise_mode != NoiseMode.ESTIMATED.value else own_noise(fit, first, spec, fixed)
    if spec.harmonics:  # a MAP estimate: its covariance at the scatter the data show (not the posterior's)
        scatter_covariance(ds, model, res, fixed)
    return res


def own_noise(fit: Callable, first, spec: JointErrorSpec, options: CalibrationOptions):
    """Re-fit a model calibrated at another fit's noise at its own noise.

    Parameters
    ----------
    fit : callable
        ``fit(spec, options) -> CalibrationResult`` whose noise table is relative to the dataset's
        declared noise (``variance_factor``: squared residuals over redundancy at the declared sigma).
    first : CalibrationResult
        ``fit(spec, options)``: the model at the given fixed ``options.noise_scale``.
    spec : JointErrorSpec
        The model's joint errors as chosen (the map prior at the given noise).
    options : CalibrationOptions
        With the fixed ``noise_scale`` (per component: used sigma over declared) ``first`` had.

    Returns
    -------
    CalibrationResult
        At its own noise: ``noise_mode`` ``estimated``, ``options["noise_scale"]`` its scales,
        ``joint_errors["prior_scale"]`` the factor on the map prior (also in its spec).
    """
    scale = dict(options.noise_scale or {})
    res, k_total = first, 1.0
    last: dict = {}  # each component's previous update factor
    for _ in range(MAX_ROUNDS):
        new, num, den = {}, 0.0, 0.0
        for name, n in res.noise.items():
            if n.redundancy < MIN_REDUNDANCY or not n.declared > 0 or not np.isfinite(n.variance_factor):
                continue
            new[name] = float(np.sqrt(n.variance_factor))  # the residuals' sigma over the declared one
        if not new or all(abs(v / float(scale.get(c, 1.0)) - 1) < TOLERANCE for c, v in new.items()):
            break
        for name, s in list(new.items()):
            old = float(scale.get(name, 1.0))
            u = s / old
            new[name] = old * _extrapolated(u, last.get(name))
            last[name] = u
            red = res.noise[name].redundancy
            num += red * (new[name] / old) ** 2
            den += red
        k = float(np.sqrt(num / den))
        k_total *= k
        scale.update(new)
        if spec.harmonics:
            spec = replace(spec, map_sigma=spec.map_sigma * k)
        res = fit(spec, replace(options, noise_scale=dict(scale)))
    else:
        log.warning("the model's own noise did not settle in %d rounds", MAX_ROUNDS)
    res.noise_mode = NoiseMode.ESTIMATED.value
    res.options["noise"] = NoiseMode.ESTIMATED.value
    res.options["noise_scale"] = {c: float(v) for c, v in scale.items()}
    for name, n in res.noise.items():
        if name in scale and n.redundancy >= MIN_REDUNDANCY:
            n.note = OWN_NOTE
            n.estimated = float(n.declared * np.sqrt(n.variance_factor))
    statistic = sum(n.variance_factor * n.redundancy for n in res.noise.values())
    res.fit_test = {**res.fit_test, "statistic": float(statistic),
                    "p_value": fit_test(statistic, res.fit_test.get("redundancy", 0.0))}
    res.joint_errors = {**res.joint_errors, "prior_scale": float(k_total)}
    log.info("at its own noise (%s); map prior x %.3g", ", ".join(f"{c} x {v:.3g}" for c, v in scale.items()),
             k_total)
    return res
