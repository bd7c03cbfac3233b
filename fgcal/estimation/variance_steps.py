"""The step of each variance component's sigma from one noise round to the next (quasi-Newton on the variance factors).

Foerstner's update (:func:`fgcal.estimation.noise.update_sigmas`) multiplies a component's variance
by its variance factor ``f`` (squared whitened residuals over redundancy): a fixed-point iteration
whose rate is one minus the component's share of its rows' variance. Where that share is small the
iteration crawls: a component the data show none of (a UR10's exact joint readings declared with a
0.001 deg resolution) has, in one dimension, ``f = k / (v + k)`` at variance ``v`` beside the others'
``k``; each round then adds ``1 / k`` to ``1 / v``, and ``f`` is still 0.95 after 40 rounds (UR10
centres: 84 iterations, 40 rounds, unsettled). A component that is there, next to one that is not
(contacts with the seating's noise in the joints), converges at a rate of 0.7 a round.

Here the equations ``log f_k(x) = 0`` in ``x_k = log v_k`` (every component ``k``) are solved by a
quasi-Newton step whose Jacobian Broyden's update learns from the rounds (starting at ``-I``:
Foerstner's step; the slope of ``log f_k`` in its own ``log v_k`` is minus that share, between 0
and -1, and the components move each other's factors: a pose's probes and its joints, a plane's
contacts and the joints). Where the share is small a component's step is longer than Foerstner's,
by at most :data:`MAX_STRETCH`, and never longer than :data:`MAX_STEP`; where the Newton step goes
the other way or is shorter, it is Foerstner's. A factor below 1 whose Newton step is longer still
(less variance hardly brings it up to 1: the likelihood's maximum is at zero) sends the sigma to its
floor, ``SCALE_LIMITS[0]`` times the declared one; there its rows have next to no redundancy, but
:func:`update_sigmas` still follows its factor, which brings it back up if the data do show some of
it. Exclusions of gross errors change the problem: the rounds' Jacobian starts again
(:meth:`VarianceSteps.forget`). UR10 bench data declared with a 0.001 deg resolution (3,000
equations): 8-11 rounds, 19-33 iterations, where Foerstner's took 35-40 rounds (84-102 iterations).
No I/O here.
"""
from __future__ import annotations

import logging
import math

import numpy as np

from fgcal.estimation.noise import MIN_REDUNDANCY, SCALE_LIMITS, component_table

__all__ = ["MAX_STEP", "MAX_STRETCH", "VarianceSteps", "update_sigmas"]

log = logging.getLogger(__name__)

MAX_STRETCH = 20.0  # the Newton step over Foerstner's at most (a slope of -0.05); beyond it and f < 1: the floor
MAX_STEP = math.log(100.0)  # |change of log variance| in one round at most: the sigma up or down 10x


class VarianceSteps:
    """The components' last round (names, log relative variances, log variance factors) and the Jacobian
    of the factors in the variances that Broyden's updates learnt from the rounds so far.

    One instance serves the rounds of one solve (:func:`fgcal.estimation.rounds._solve_rounds`).
    """

    def __init__(self) -> None:
        self.forget()

    def forget(self) -> None:
        """Drop the rounds so far: the measurements changed (exclusions), a secant across them would mislead."""
        self.names: tuple[str, ...] = ()
        self.x = self.F = np.zeros(0)
        self.J = np.zeros((0, 0))

    def log_steps(self, points: dict[str, tuple[float, float]]) -> dict[str, float]:
        """The change of ``log v`` of each component ``name: (log v, f)`` of this round (``v`` its variance
        over the declared one, ``f > 0`` its variance factor).

        A quasi-Newton step on ``log f = 0`` with the Jacobian ``J`` of ``log f`` in ``log v`` from
        Broyden's update through the rounds (it starts at ``-I``, Foerstner's step ``log f``): the
        components move each other's factors (a pose's probes and joints; a plane's contacts and
        the joints), and one component's own secant, blind to the others' moves, sent a real noise
        to its floor. A component's step is Foerstner's where the Newton step goes the other way or
        is shorter; at most :data:`MAX_STRETCH` times as long, and :data:`MAX_STEP`.
        """
        names = tuple(points)
        x = np.array([points[n][0] for n in names])
        F = np.log([points[n][1] for n in names])
        step = F.copy()  # Foerstner's
        if names == self.names:
            dx, dF = x - self.x, F - self.F
            if float(dx @ dx) > 1e-24:
                self.J = self.J + np.outer(dF - self.J @ dx, dx) / float(dx @ dx)  # Broyden's "good" update
            try:
                newton = np.linalg.solve(self.J, -F)
            except np.linalg.LinAlgError:
                newton = step
            longer = (np.sign(newton) == np.sign(F)) & (np.abs(newton) > np.abs(F))
            step = np.where(longer, np.clip(newton, -MAX_STRETCH * np.abs(F), MAX_STRETCH * np.abs(F)), F)
            # less variance hardly brings f up to 1: the likelihood's maximum is at zero, the floor
            step[(F < 0) & (newton < -MAX_STRETCH * np.abs(F))] = -np.inf
        else:
            self.J = -np.eye(len(names))
        self.names, self.x, self.F = names, x, F
        return {n: float(v if v == -np.inf else np.clip(v, -MAX_STEP, MAX_STEP)) for n, v in zip(names, step)}


def update_sigmas(sigmas, comps, declared, tolerance: float = 0.01, steps: VarianceSteps | None = None):
    """Rescale each estimable component toward a variance factor of 1.

    Without ``steps`` by the square root of its variance factor (Foerstner's update); with them
    (one :class:`~fgcal.estimation.variance_steps.VarianceSteps` over a solve's rounds) by the
    quasi-Newton step of :meth:`VarianceSteps.log_steps`, which settles a component the data show little of
    in a few rounds where Foerstner's crawls. Returns ``(new sigmas, changed)``; ``changed`` is
    False when every factor is within ``tolerance`` of 1 (converged).
    """
    eligible = {}
    for name, (ssq, red) in comps.items():
        field = component_table()[name][2]
        current = np.asarray(getattr(sigmas, field), dtype=float)  # per joint for the joints
        decl = np.asarray(getattr(declared, field), dtype=float)
        if np.any(current <= 0) or not red > 0:
            continue
        # At its floor a component's rows have next to no redundancy, but its factor is still the test of
        # whether more of it would fit (the likelihood's slope at zero): there it may come back up.
        at_floor = steps is not None and bool(np.all(current <= SCALE_LIMITS[0] * decl * (1 + 1e-9)))
        if red < MIN_REDUNDANCY and not at_floor:
            continue
        f = ssq / red
        if np.isfinite(f) and f > 0:
            eligible[name] = (field, current, decl, f)
    if steps is None:
        log_steps = {n: math.log(e[3]) for n, e in eligible.items()}
    else:  # every round's point enters Broyden's update, a settled one's too
        log_steps = steps.log_steps({n: (2.0 * math.log(float(np.max(c / d))), f) for n, (_, c, d, f) in eligible.items()})
    changed = False
    new = {}
    for name, (field, current, decl, f) in eligible.items():
        if abs(f - 1.0) < tolerance:
            continue
        value = np.clip(current * math.exp(0.5 * log_steps[name]), SCALE_LIMITS[0] * decl, SCALE_LIMITS[1] * decl)
        if np.all(value <= SCALE_LIMITS[0] * decl) and np.any(value != current):
            log.info("%s: less noise does not bring its variance factor (%.3g) up to 1: the data show none of "
                     "it, held at its floor (%g x the declared sigma)", name, f, SCALE_LIMITS[0])
        if np.any(value != current):
            new[field] = value if value.ndim else float(value)
            changed = True
    return sigmas.replaced(**new), changed
