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

import numpy as np

from fgcal.robots.identifiability import analyse_information, identification_jacobian
from fgcal.robots.model import ParameterSet, RobotModel
from fgcal.robots.deviations import Deviations

__all__ = ["held_parameters", "holding_cost"]


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


def holding_cost(model: RobotModel, slots, free, held, q_calib, measurement, n_new: int = 200,
                 deviations: Deviations = Deviations(), seed: int = 0) -> dict[str, float]:
    """RMS position error (mm) at new poses left by each held parameter, and by all of them (``"all"``).

    Parameters
    ----------
    slots : ndarray, shape (S,)
        The calibrated chain (internal units).
    free, held : sequence of str
        Estimated and held parameter names.
    q_calib : ndarray, shape (N, n_joints)
        Calibration poses (rad).
    measurement : "pose" or ndarray, shape (B, 3)
        What was measured (see :func:`~fgcal.robots.identifiability.identification_jacobian`); the error at
        new poses is taken at the same tool points (the tool origin for ``"pose"``).
    """
    if not held:
        return {}
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
    return out
