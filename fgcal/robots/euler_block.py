"""A transform as a model file's Euler block: ``{phi, theta, psi (deg), px, py, pz (mm)}``.

Written by the model files (:mod:`fgcal.robots.robot_file`) and by the URDF import
(:mod:`fgcal.robots.urdf_import`, a model's mounting). No I/O here.
"""
from __future__ import annotations

import math

import numpy as np

from fgcal.robots.model import EULER_FIELDS
from fgcal.robots.transforms import euler_zyx_trans, to_euler_zyx_trans

__all__ = ["euler_any", "euler_dict"]


def euler_dict(T) -> dict:
    """``T`` (4, 4) as a model file's ``{phi, theta, psi (deg), px, py, pz (mm)}`` block."""
    v = euler_any(np.asarray(T, dtype=float))
    return {f: round(float(math.degrees(x) if i < 3 else x), 12) + 0.0  # no -0.0
            for i, (f, x) in enumerate(zip(EULER_FIELDS, v))}


def euler_any(T) -> np.ndarray:
    """ZYX Euler angles and local translation of ``T``, including at pitch +-90 deg (then psi = 0)."""
    R = T[:3, :3]
    if abs(R[2, 0]) < 1 - 1e-12:
        return to_euler_zyx_trans(T)
    theta = -math.copysign(math.pi / 2, R[2, 0])
    phi = math.atan2(-R[0, 1], R[1, 1])
    out = np.array([phi, theta, 0.0, 0.0, 0.0, 0.0])
    out[3:] = (euler_zyx_trans(*out)[:3, :3]).T @ T[:3, 3]
    return out
