"""Identifiability of kinematic parameters from a set of poses.

The identification Jacobian stacks, for every pose, the derivative of what is measured (a full
pose, or the positions of tool-frame points) with respect to the estimated parameters. Its
columns are scaled (to unit norm by default, or by expected parameter errors) so that singular
values compare lengths and angles fairly. A rank below the parameter count means some parameter
cannot be separated from others; :func:`analyse` names it and the parameters it is confused with.
No I/O here.
"""
from __future__ import annotations

import numpy as np

from fgcal.robots.jacobian_rank import (
    Identifiability,
    analyse,
    analyse_information,
    minimal_parameters,
    slot_jacobian,
)
from fgcal.robots.model import ParameterSet

__all__ = ["Identifiability", "analyse", "analyse_information", "compact_jacobian", "identification_jacobian",
           "minimal_parameters"]


def identification_jacobian(params: ParameterSet, q, slots=None, measurement="pose",
                            orientation_scale: float = 100.0) -> np.ndarray:
    """Stacked Jacobian of the measurements with respect to the parameters.

    Parameters
    ----------
    params : ParameterSet
        The estimated parameters (P of them).
    q : array_like, shape (N, n)
        Joint readings (rad, mm).
    slots : array_like, shape (S,), optional
        Where to linearise (mm, rad); the nominal by default.
    measurement : {"pose", "position"} or array_like, shape (B, 3)
        ``"pose"``: 6 rows per pose (position in mm, rotation in rad times ``orientation_scale``
        mm so that both rows are lengths); ``"position"``: the tool origin only; an array: the
        world positions of these tool-frame points (mm), 3B rows per pose.
    orientation_scale : float
        Lever arm (mm) that turns rotation rows into length rows.

    Returns
    -------
    ndarray, shape (M, P)
        Rows in mm per internal unit (mm or rad).
    """
    x = params.model.nominal if slots is None else slots
    return slot_jacobian(params.model.chain, x, q, params.index, measurement, orientation_scale)


def compact_jacobian(params: ParameterSet, q, measurement="pose", chunk: int = 2000, **kw) -> np.ndarray:
    """A (P, P) matrix with the same singular values and column relations as the stacked Jacobian.

    The triangular factor R of ``J = Q R``, accumulated over chunks of ``chunk`` poses, so that
    memory does not grow with the number of poses; :func:`analyse` gives the same answer on it.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    R = None
    for start in range(0, len(q), chunk):
        J = identification_jacobian(params, q[start:start + chunk], measurement=measurement, **kw)
        R = np.asarray(np.linalg.qr(J if R is None else np.vstack([R, J]), mode="r"))
    if R is None:
        return np.zeros((0, len(params.names)))
    return R
