"""What a chain's Jacobians hold: tool poses and their derivatives at N joint readings.

Returned by :meth:`fgcal.robots.kinematics.Chain.jacobians` and by
:func:`fgcal.robots.single_pose.jacobians_one`. Units: mm, rad.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ChainJacobians"]


@dataclass
class ChainJacobians:
    """Tool poses and their Jacobians at N joint readings.

    Attributes
    ----------
    T : ndarray, shape (N, 4, 4)
        Tool poses (mm).
    pose_slots : ndarray, shape (N, 6, S)
        d[p; w] / d slots (mm per mm, mm per rad; rad per mm, rad per rad).
    pose_joints : ndarray, shape (N, 6, n)
        d[p; w] / d readings.
    points : ndarray, shape (N, B, 3) or None
        World positions of the requested tool-frame points.
    point_slots : ndarray, shape (N, B, 3, S) or None
    point_joints : ndarray, shape (N, B, 3, n) or None
    """

    T: np.ndarray
    pose_slots: np.ndarray
    pose_joints: np.ndarray
    points: np.ndarray | None = None
    point_slots: np.ndarray | None = None
    point_joints: np.ndarray | None = None
