"""Using a calibration: joint commands that bring the calibrated robot to target tool poses.

The calibrated model is inverted numerically (:func:`fgcal.ik.solve_numeric`) from a seed: the
joints the user would have commanded with the nominal model, or, for a PUMA-structured arm, the
closed-form solution of the nominal model in the branch that keeps the joints within limits
(closest to ``prefer`` when given). No I/O here.
"""
from __future__ import annotations

import numpy as np

from .errors import FgcalError
from .ik import BRANCHES, IKError, solve_numeric, solve_puma
from .kinematics import forward
from .model import RobotModel
from .transforms import pose_difference

__all__ = ["compensate"]


def _puma_seeds(model: RobotModel, T, prefer=None) -> list[np.ndarray]:
    """Closed-form nominal solutions within the joint limits, nearest to ``prefer`` first."""
    found = []
    for branch in BRANCHES:
        try:
            q = solve_puma(model, T, branch)
        except IKError:
            continue
        if model.in_limits(q)[0]:
            cost = 0.0 if prefer is None else float(np.sum(np.angle(np.exp(1j * (q - prefer))) ** 2))
            found.append((cost, len(found), q))
    return [q for _, _, q in sorted(found, key=lambda f: f[:2])]


def compensate(model: RobotModel, slots, targets, seeds=None):
    """Joint commands (rad) for the calibrated geometry ``slots`` to reach ``targets``.

    Parameters
    ----------
    model : RobotModel
        Nominal model (joint limits, and the closed-form seed where it applies).
    slots : array_like, shape (37,)
        Calibrated geometry (mm, rad).
    targets : array_like, shape (N, 4, 4)
        Target tool poses in the world frame (mm).
    seeds : array_like, shape (N, 6), optional
        Starting joints (rad), for example the uncompensated commands.

    Returns
    -------
    q : ndarray, shape (N, 6)
    position_error_mm, orientation_error_deg : ndarray, shape (N,)
        How far the calibrated model at ``q`` is from each target (numerical residual).

    Raises
    ------
    FgcalError
        When a target has no seed and the closed form does not apply, or cannot be reached.
    """
    targets = np.asarray(targets, dtype=float).reshape(-1, 4, 4)
    out = np.zeros((len(targets), 6))
    for i, T in enumerate(targets):
        given = None if seeds is None else np.asarray(seeds[i], dtype=float)
        candidates = [given] if given is not None and np.all(np.isfinite(given)) else []
        try:
            candidates += _puma_seeds(model, T, prefer=candidates[0] if candidates else None)
        except IKError:
            pass  # not a PUMA-structured arm: only the given seed
        if not candidates:
            raise FgcalError(f"target {i + 1}: no seed joints (give q1..q6 columns: the closed form needs the "
                             "PUMA structure and a solution within the joint limits)")
        last = None
        for seed in candidates:
            try:
                out[i] = solve_numeric(model, T, seed, slots=slots)
                break
            except IKError as exc:
                last = exc
        else:
            raise FgcalError(f"target {i + 1}: {last} from {len(candidates)} seed(s); it may lie beyond the joint "
                             "limits of the calibrated robot") from None
    d, delta = pose_difference(forward(slots, out), targets)
    return out, np.linalg.norm(d, axis=1), np.degrees(np.linalg.norm(delta, axis=1))
