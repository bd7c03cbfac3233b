"""The robot's own base frame: what loading folded into the chain's base, and where the calibrated base puts it.

Used by compensation (targets in the base frame), the URDF exports and the UR kinematics files.
Units: mm, rad. No I/O here.
"""
from __future__ import annotations

import numpy as np

from fgcal.robots.model import EULER_FIELDS, RobotModel
from fgcal.robots.transforms import euler_zyx_trans

__all__ = ["base_transform", "mounting"]


def mounting(model: RobotModel) -> np.ndarray:
    """The chain's base frame in the robot's own base frame (4, 4; mm): what loading folded into the base.

    A robot file's first link theta and d (and, in modified DH, its a and alpha) are folded into the
    base; a URDF's chain starts at the first joint, placed in the base link. The model keeps that
    transform (``model.extra["mounting"]``, from :mod:`fgcal.robots.robot_file` and
    :mod:`fgcal.robots.urdf_import`); identity when nothing was folded.
    """
    m = model.extra.get("mounting")
    if m is None:
        return np.eye(4)
    v = [float(m.get(f, 0.0)) for f in EULER_FIELDS]
    return euler_zyx_trans(*np.radians(v[:3]), *v[3:])


def base_transform(model: RobotModel, slots) -> np.ndarray:
    """The robot's own base frame in the instrument frame (4, 4; mm) for a slot vector (mm, rad).

    The frame of the robot's mounting flange as its maker or URDF defines it: for a URDF robot the
    base link; for a built-in robot or a DH table the table's base frame (joint 1's axis as z, at
    the mounting face: for the UR10 127.3 mm below the chain's first frame). It is the calibrated
    base (the chain's first frame) times the inverse of the nominal :func:`mounting`: the height of
    the mounting face along joint 1 cannot be told from the base placement by any measurement of
    the tool, so it keeps its nominal value.
    """
    x = np.asarray(slots, dtype=float)
    chain = euler_zyx_trans(*x[model.slot("base.phi"):model.slot("base.pz") + 1])
    return chain @ np.linalg.inv(mounting(model))
