"""A transform as URDF writes it: roll, pitch, yaw angles and the ``<origin xyz=... rpy=.../>`` element.

Lengths in metres (as URDF requires) with round-trip precision, from transforms in mm. Shared by
the URDF export (:mod:`fgcal.robots.urdf`) and the UR kinematics files
(:mod:`fgcal.robots.ur_kinematics`). No I/O here.
"""
from __future__ import annotations

import numpy as np

from fgcal.util.numbers import format_number

__all__ = ["origin_element", "rpy", "xyz_rpy"]


def rpy(R) -> tuple[float, float, float]:
    """URDF roll, pitch, yaw (rad) of a rotation matrix: ``R = Rz(yaw) Ry(pitch) Rx(roll)``."""
    R = np.asarray(R, dtype=float)
    s = -R[2, 0]
    if abs(s) > 1 - 1e-12:  # gimbal lock: put everything in roll
        pitch = np.copysign(np.pi / 2, s)
        return float(np.arctan2(-R[1, 2], R[1, 1])), float(pitch), 0.0
    return float(np.arctan2(R[2, 1], R[2, 2])), float(np.arcsin(s)), float(np.arctan2(R[1, 0], R[0, 0]))


def xyz_rpy(T) -> tuple[str, str]:
    """A transform ``T`` (4, 4; mm) as URDF's ``xyz`` (m) and ``rpy`` (rad) attribute texts."""
    return (" ".join(format_number(float(v) / 1000.0) for v in T[:3, 3]),
            " ".join(format_number(v) for v in rpy(T[:3, :3])))


def origin_element(T) -> str:
    """``<origin xyz=... rpy=.../>`` of a transform ``T`` (4, 4; mm): metres and URDF rpy, no negative zero."""
    xyz, angles = xyz_rpy(T)
    return f'<origin xyz="{xyz}" rpy="{angles}"/>'
