"""Levenberg-Marquardt on the batched graph (or GTSAM's, with ``engine="gtsam"``). No I/O here."""
from __future__ import annotations

import logging

import numpy as np

from fgcal.errors import FgcalError
from fgcal.estimation.graph import Graph, State
from fgcal.estimation.graph_types import COST_ROUNDING, Linearisation
from fgcal.estimation.options import CalibrationOptions

__all__ = ["COST_ROUNDING", "levenberg_marquardt"]

TRUSTED_DECREASE = 100  # the damping's fall after a step the model predicted (else 10)

log = logging.getLogger(__name__)


def levenberg_marquardt(graph: Graph, state: State, max_iterations=100, tolerance=1e-12, lin=None,
                        damping: float = 1e-4):
    """Minimise the graph's cost; returns ``(state, iterations, converged)``.

    ``lin``: the linearisation at ``state`` when the caller has it; ``damping``: the first step's
    (relative to the diagonal of the normal equations; a start near the optimum takes a small
    one, else the steps fall short of Gauss-Newton's by about half: the parameters' reduced
    information is ~1e-4 of the diagonal under the 1e-4 mm kinematic sigma). The solve stops when a step
    (or the Gauss-Newton model's prediction of it) changes the cost by no more than
    ``tolerance`` relative, or by no more than rounding: such a step is not tried again damped.
    """
    lin = graph.linearise(state) if lin is None else lin
    new_lin: Linearisation | None = None
    cost = lin.cost
    for it in range(1, max_iterations + 1):
        for _ in range(30):
            try:
                new, d_theta, predicted = graph.step(state, lin, damping)
            except np.linalg.LinAlgError:
                damping *= 10
                continue
            if damping <= 1e-3 and 0 <= predicted <= tolerance * max(cost, 1e-300):
                return state, it, True  # at the minimum: what is left to gain is rounding
            if graph.nz:
                lin.cache.clear()  # its normal equations are formed again if this step is rejected
            else:
                lin = _normal_only(graph, lin)  # a rejected step needs only them (small without per-pose variables)
            new_lin = graph.linearise(new)
            new_cost = new_lin.cost
            if np.isfinite(new_cost) and new_cost <= cost:
                break
            if np.isfinite(new_cost) and new_cost - cost <= COST_ROUNDING * cost and predicted <= COST_ROUNDING * cost:
                return state, it, True  # the change is rounding, not a worse point
            graph.forget(new_lin)  # a rejected state's linearisation: not kept while the next is formed
            new_lin = None
            damping *= 10
        else:
            log.warning("Levenberg-Marquardt: no step reduces the cost (damping %.3g)", damping)
            return state, it, False
        assert new_lin is not None  # the loop stopped on an accepted step
        gain = cost - new_cost
        state, lin, new_lin = new, new_lin, None  # one name for it: the next step may release it (_normal_only)
        # A step whose decrease the Gauss-Newton model predicted to 10 % says the model holds here:
        # the damping falls faster (a weak direction, the scale of contacts fixed by the plates'
        # distances alone, converges by damping / (damping + its share of the diagonal) a step).
        rho = gain / predicted if predicted > 0 else 0.0
        damping = max(damping / (TRUSTED_DECREASE if abs(rho - 1.0) < 0.1 else 10), 1e-12)
        small_step = np.max(np.abs(d_theta)) < 1e-12 * (1 + np.max(np.abs(state.theta)))
        if gain <= tolerance * max(cost, 1e-300) or small_step or new_cost < 1e-24:
            return state, it, True
        cost = new_cost
    return state, max_iterations, False


def _normal_only(graph: Graph, lin):
    """``lin`` reduced to what another step from its state needs (its normal equations, cost and
    residuals), and forgotten by the graph: its (N, m, P) Jacobian is not kept while the next state
    is linearised (with a joint-error map on 8,000 poses, 160 MB)."""
    graph.normal_equations(lin)  # formed, kept in its cache
    graph.forget(lin)
    n, mt, _ = lin.J_stored.shape  # (a view of J_stored would keep all of it)
    return Linearisation(lin.r, np.zeros((n, mt, 0)), lin.J_local, lin.prior_r, lin.prior_J, lin.cost, lin.raw,
                         {"normal": lin.cache["normal"]})


def _solve(graph: Graph, state: State, options: CalibrationOptions, lin=None, damping: float = 1e-4):
    if options.engine == "batch":
        return levenberg_marquardt(graph, state, options.max_iterations, options.tolerance, lin=lin, damping=damping)
    if options.engine == "gtsam":
        from fgcal.estimation.gtsam_graph import gtsam_levenberg_marquardt

        return gtsam_levenberg_marquardt(graph, state, options.max_iterations, options.tolerance)
    raise FgcalError(f"unknown engine {options.engine!r} (batch, gtsam)")
