"""The solve's rounds: the solve, then noise estimation and outlier exclusion alternated with re-solves
(:func:`_solve_rounds`, the loop of :func:`fgcal.estimation.calibrate.solve_calibration`). No I/O here.
"""
from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from fgcal.estimation.graph import Graph, State
from fgcal.estimation.group_noise import update_groups
from fgcal.estimation.noise import (
    NoiseMode,
    OutlierMode,
    components,
    find_outliers,
    included_leverage,
    readmissible,
)
from fgcal.estimation.options import CalibrationOptions
from fgcal.estimation.solve import _solve
from fgcal.estimation.variance_steps import VarianceSteps, update_sigmas

__all__ = ["LOOSE_TOLERANCE", "MAX_NOISE_ROUNDS", "MAX_READMISSIONS", "WARM_DAMPING"]

log = logging.getLogger(__name__)

MAX_NOISE_ROUNDS = 40
MAX_READMISSIONS = 3  # passes re-admitting exclusions that pass at the final noise (a fixed point, bounded)
WARM_DAMPING = 1e-9  # Levenberg-Marquardt's first damping from a start near the optimum (see levenberg_marquardt)
# The first solve's relative tolerance where noise or outlier rounds follow: the rounds' statistics
# (variance factors to 1 %, outlier tests) move by about this share, and the final solve is at the
# options' tolerance. On the contacts bench the first solve's last step (a relative decrease of 8e-11,
# the scale's direction fixed by the plates' distances alone) is one linearisation of ten.
LOOSE_TOLERANCE = 1e-9


def _solve_rounds(graph: Graph, state: State, options: CalibrationOptions, damping: float, noise_mode: NoiseMode,
                  outlier_mode: OutlierMode):
    """The solve, then noise estimation and outlier exclusion alternated with re-solves until neither
    changes, then the exclusions retested at the final noise (:func:`~fgcal.estimation.noise.readmissible`;
    at most :data:`MAX_READMISSIONS` times): ``(state, iterations, converged, rounds, declared sigmas)``."""
    # With rounds to follow, the first solve stops at LOOSE_TOLERANCE: a round that changes the noise or the
    # exclusions moves the optimum (its last steps were for nothing); one that changes nothing finishes it.
    loose = (noise_mode is NoiseMode.ESTIMATED or outlier_mode is OutlierMode.EXCLUDE) and options.engine == "batch" \
        and options.tolerance < LOOSE_TOLERANCE
    state, iterations, converged = _solve(graph, state, replace(options, tolerance=LOOSE_TOLERANCE) if loose else options,
                                          damping=damping)
    declared = graph.sigmas
    rounds = readmitted = finishing = 0
    steps = VarianceSteps()  # the rounds' quasi-Newton steps (Foerstner's alone crawls near zero)
    for rounds in range(1, MAX_NOISE_ROUNDS + 1):  # noqa: B007 (the count is returned)
        lin = graph.linearise(state)
        h = graph.row_leverage(state, graph.information_inverse(state, lin), lin)
        changed = False
        if outlier_mode is OutlierMode.EXCLUDE:
            for level, ks in find_outliers(graph, lin, h).items():
                mask = graph.excluded.setdefault(level, np.zeros(len(graph.row[level]), dtype=bool))
                mask[ks] = True
                changed = True
                steps.forget()  # other rows: the factors' last rounds are of another problem
        if noise_mode is NoiseMode.ESTIMATED:
            graph.sigmas, moved = update_sigmas(graph.sigmas, components(graph, lin, h), declared,
                                                  steps=steps)
            changed |= moved
            changed |= update_groups(graph, lin, h)  # each camera's share of the pixels' noise
        if not changed and outlier_mode is OutlierMode.EXCLUDE and readmitted < MAX_READMISSIONS:
            # Settled: every exclusion is tested again at this (final) noise and solution; those
            # within the limit come back, and the rounds go on to a fixed point.
            h_in = included_leverage(graph, state) if graph.excluded else None
            for level, ks in readmissible(graph, lin, h, h_in).items():
                graph.excluded[level][ks] = False
                steps.forget()
                log.info("%s: %d measurement(s) excluded at an earlier round's noise pass the test at the "
                         "final noise: re-admitted", level, len(ks))
                changed = True
            readmitted += changed
        if not changed and not loose:
            break
        finishing += not changed  # the loose first solve finished at the tolerance, then judged again
        loose = False
        # From the last optimum: lightly damped (a full damping here took 6 steps for what 2-3 do)
        del lin  # the solve may release its Jacobian while it linearises the next state
        state, it2, converged = _solve(graph, state, options, damping=min(damping, WARM_DAMPING))
        iterations += it2
    else:
        log.warning("noise estimation did not settle in %d rounds", MAX_NOISE_ROUNDS)
    return state, iterations, converged, rounds - finishing, declared
