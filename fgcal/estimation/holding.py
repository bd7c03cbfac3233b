"""Which parameters to hold, by a rule that does not depend on the start, and what holding costs.

:func:`held_parameters` decides on the information of the graph linearised at the data's
starting state (nominal chain, base fitted to the measurements) with the *declared* noise, no
robust weights and no outlier exclusion: the choice is a function of the poses, the levels and
the model only, the same for every option that changes only the noise or the solver.

:func:`holding_cost` says what a held parameter costs: if it deviates by its typical amount
(:class:`~fgcal.robots.deviations.Deviations`) and the free parameters absorb what they can at the
calibration poses, the RMS position error that remains at new poses (random joint sets within
the limits, seeded). Zero means the parameter is truly redundant (another one stands in for it
everywhere); a large value means the pose set, not the robot, is the limitation. No I/O here.
"""
from __future__ import annotations

import logging

import numpy as np

from fgcal.estimation.graph import Graph, State
from fgcal.estimation.setup_schur import marginal_information
from fgcal.robots.deviations import Deviations
from fgcal.robots.identifiability import analyse, analyse_information, identification_jacobian
from fgcal.robots.model import ParameterSet, RobotModel

__all__ = ["held_parameters", "holding_cost", "priors_the_data_decide", "typical_geometry", "unseen_parameters"]

log = logging.getLogger(__name__)


def held_parameters(graph, state, decide=None) -> dict[str, list[str]]:
    """Unidentifiable parameters of ``graph`` at ``state``, with the parameters each is confused with.

    ``graph`` must carry the declared noise; robust weights and exclusions are switched off for the
    decision. ``decide(graph, state)`` (default: :func:`~fgcal.robots.identifiability.analyse_information`
    of the parameters' information) names them.
    """
    robust, excluded = graph.robust, graph.excluded
    graph.robust, graph.excluded = None, {}
    try:
        if decide is not None:
            return decide(graph, state)
        return analyse_information(graph.parameter_information(state), graph.params.names).redundant
    finally:
        graph.robust, graph.excluded = robust, excluded


def _hold_order(names) -> list[int]:
    """Column order for blaming: the tool's angles last, so they are held first.

    Position-only data see a point on the tool, not its orientation: holding the tool's angles
    and keeping its translation keeps that point linear in the parameters wherever the solve goes
    (holding translations instead leaves a rotation that degenerates away from the start).
    """
    late = [i for i, n in enumerate(names) if n in ("tool.phi", "tool.theta", "tool.psi")]
    return [i for i in range(len(names)) if i not in late] + late


def _identifiability(graph: Graph, state: State, lin=None, rtol: float = 1e-6):
    """What the information of ``graph`` at ``state`` identifies (geometry only; the set-up unknowns
    marginalised per fixture block), its columns in :func:`_hold_order`."""
    names = list(graph.params.names)[:graph.n_geo]  # a joint-error block has its own prior: geometry only
    order = _hold_order(names)
    info = graph.parameter_information(state, lin)
    if graph.S:  # the set-up unknowns are estimated with the robot: their information is marginalised
        g, s = np.arange(graph.n_geo), np.arange(graph.n_geo + graph.K, graph.n_geo + graph.K + graph.S)
        info = marginal_information(info, g, s)  # per fixture block (fgcal.estimation.setup_schur)
    S = info[np.ix_(order, order)]
    return analyse_information(S, [names[i] for i in order], rtol=rtol)


# At a typical geometry a direction redundant by structure stays at rounding level (1e-16 of the
# largest eigenvalue); one a typical deviation opens (a ball 0.5 mm off the last axis) is ~1e-7.
STRUCTURAL_RTOL = 1e-11


def _unidentifiable(graph: Graph, state: State, lin=None) -> dict[str, list[str]]:
    return _identifiability(graph, state, lin).redundant


def unseen_parameters(model: RobotModel, names, measurement, n_configurations: int = 64,
                      rtol: float = 1e-8) -> dict[str, list[str]]:
    """The parameters of ``names`` that ``measurement`` can see at no pose, with their partners.

    What a measurement type sees of the chain does not depend on the poses alone: a reflector at
    one tool point sees nothing of the tool's orientation (its angles move the point as the tool
    translation does, or not at all), whatever the poses. The identification Jacobian at
    ``n_configurations`` joint sets spread over the limits (a fixed seed: the answer depends on
    the model and the measurement only) names them, in the batch's blame order (the tool's
    angles held first, :func:`_hold_order`). What the poses of a
    particular dataset cannot separate besides is for :func:`held_parameters` to decide.

    Parameters
    ----------
    names : sequence of str
        Candidate slot names.
    measurement : "pose", "position" or ndarray, shape (B, 3)
        As :func:`~fgcal.robots.identifiability.identification_jacobian`.
    """
    names = [n for n in names if n in set(model.slot_names)]
    if not names:
        return {}
    names = [names[i] for i in _hold_order(names)]
    rng = np.random.default_rng(20260101)
    lo, hi = model.joint_limits[:, 0], model.joint_limits[:, 1]
    span = np.where(model.joint_is_angle, np.minimum(hi - lo, 2 * np.pi), hi - lo)
    q = lo + rng.uniform(0.0, 1.0, size=(n_configurations, model.n_joints)) * span
    J = identification_jacobian(ParameterSet(model, tuple(names)), q, measurement=measurement)
    norms = np.linalg.norm(J, axis=0)
    live = norms > rtol * max(norms.max(initial=0.0), 1e-300)  # a column of rounding noise sees nothing
    scale = np.where(live, 1.0 / np.where(live, norms, 1.0), 0.0)
    return analyse(J, names, scale=scale, rtol=rtol).redundant


def holding_cost(model: RobotModel, slots, free, held, q_calib, measurement, n_new: int = 200,
                 deviations: Deviations = Deviations(), seed: int = 0) -> dict[str, float]:
    """RMS position error (mm) at new poses left by each held parameter, and by all of them (``"all"``).

    Parameters
    ----------
    slots : ndarray, shape (S,)
        The calibrated chain (internal units).
    free, held : sequence of str
        Estimated and held parameter names. Only the geometric ones (slots of ``model``) enter: a
        joint-error block (``j2.compliance``, :mod:`fgcal.estimation.joint_errors`) moves the joint
        variables, not a slot, and is left out of the free set; a held name that is not a slot
        gets ``nan``.
    q_calib : ndarray, shape (N, n_joints)
        Calibration poses (rad).
    measurement : "pose" or ndarray, shape (B, 3)
        What was measured (see :func:`~fgcal.robots.identifiability.identification_jacobian`); the error at
        new poses is taken at the same tool points (the tool origin for ``"pose"``).
    """
    if not held:
        return {}
    slots_of = set(model.slot_names)
    free = [n for n in free if n in slots_of]
    others = [n for n in held if n not in slots_of]
    held = [n for n in held if n in slots_of]
    if others:
        log.info("no holding cost for %s (not geometric parameters)", ", ".join(others))
    if not held:
        return {**{n: float("nan") for n in others}, "all": float("nan")}
    names = list(free) + list(held)
    params = ParameterSet(model, tuple(names))
    J = identification_jacobian(params, q_calib, slots, measurement)
    rng = np.random.default_rng(seed)
    lim = model.joint_limits
    q_new = rng.uniform(lim[:, 0], lim[:, 1], size=(n_new, lim.shape[0]))
    J_new = identification_jacobian(params, q_new, slots, "position" if isinstance(measurement, str) else measurement)
    nf = len(free)
    dev = deviations.sigmas(held)
    Jf = J[:, :nf]
    # the free parameters' least-squares answer to a held deviation: -pinv(Jf) J_h delta
    absorb = np.linalg.lstsq(Jf, J[:, nf:], rcond=None)[0]
    M = (J_new[:, nf:] - J_new[:, :nf] @ absorb) * dev[None, :]  # error per typical deviation of each held
    n_points = J_new.shape[0] // 3
    out = {h: float(np.sqrt(np.sum(M[:, k] ** 2) / n_points)) for k, h in enumerate(held)}
    out["all"] = float(np.sqrt(np.sum(M**2) / n_points))
    out.update({n: float("nan") for n in others})
    return out



def typical_geometry(model: RobotModel, seed: int = 0) -> np.ndarray:
    """Slots (S,) of an arm deviating from ``model``'s nominal by typical amounts
    (:class:`~fgcal.robots.deviations.Deviations`, a fixed seed): where a parameter that the
    nominal geometry cannot separate (a ball on the last joint's axis there) is tested again."""
    ident = [n for n in model.identifiable_names() if n in set(model.slot_names)]
    slots = model.nominal.copy()
    slots[[model.slot(n) for n in ident]] += np.random.default_rng(seed).normal(size=len(ident)) * \
        Deviations().sigmas(ident)
    return slots


def priors_the_data_decide(graph, state, priors: dict, lin=None) -> dict[str, float]:
    """Of the typical-deviation ``priors`` ({name: sigma}, internal units) those the data determine better.

    At the solution ``state``, each prior'd parameter's marginal sigma from the graph's information
    without its own prior (the others kept): where it is below the prior's sigma, the data decide it
    and the prior only pulls it toward the nominal, which for a set-up guess (a reflector's offset
    guessed 5 mm off) is a guess, not a typical robot. A simulated local grid with one reflector:
    the prior (0.5 mm) on ``tool.pz`` about guesses 6-8 mm off cost 10-14% at held-out poses; an
    all-free least squares from the same start was start-independent. Returns ``{name: the data's
    sigma}`` (internal units) of those whose prior is to be dropped.
    """
    names = list(graph.params.names)
    S = graph.parameter_information(state, lin)
    out = {}
    for n, sd in priors.items():
        if n not in names or not np.isfinite(sd) or sd <= 0:
            continue
        i = names.index(n)
        info = S.copy()
        info[i, i] -= 1.0 / sd**2
        d = np.sqrt(np.maximum(np.abs(np.diag(info)), 1e-300))
        ev, vec = np.linalg.eigh(info / np.outer(d, d))
        if ev[0] <= 1e-12 * ev[-1]:  # without its prior the information is singular: the prior is needed
            continue
        var = float(np.sum(vec[i] ** 2 / ev) / d[i] ** 2)
        if np.isfinite(var) and var < sd**2:
            out[n] = float(np.sqrt(var))
    return out
