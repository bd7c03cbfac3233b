"""URDF export of a (calibrated) chain: the joint origins carry the geometry.

``T = A_b Rz(q1) M_1 Rz(q2) M_2 ... M_5 Rz(q6) A_t`` with ``M_n = Rz(theta_n) Tz(d_n) Tx(a_n)
Rx(alpha_n) Ry(beta_n)``: a fixed joint ``world -> base_link`` with ``A_b``, revolute joints
about z whose origins are ``M_{n-1}`` (identity for joint 1), and a fixed joint to the tool with
``A_t``. Lengths are written in metres, as URDF requires. No I/O here.
"""
from __future__ import annotations

from xml.sax.saxutils import quoteattr

import numpy as np

from .model import EULER_FIELDS, RobotModel, slot
from .transforms import euler_zyx_trans, rot

__all__ = ["chain_origins", "to_urdf", "rpy"]


def rpy(R) -> tuple[float, float, float]:
    """URDF roll, pitch, yaw (rad) of a rotation matrix: ``R = Rz(yaw) Ry(pitch) Rx(roll)``."""
    R = np.asarray(R, dtype=float)
    s = -R[2, 0]
    if abs(s) > 1 - 1e-12:  # gimbal lock: put everything in roll
        pitch = np.copysign(np.pi / 2, s)
        return float(np.arctan2(-R[1, 2], R[1, 1])), float(pitch), 0.0
    return float(np.arctan2(R[2, 1], R[2, 2])), float(np.arcsin(s)), float(np.arctan2(R[1, 0], R[0, 0]))


def chain_origins(slots) -> list[np.ndarray]:
    """The seven fixed transforms (4, 4), mm: ``A_b, M_1 ... M_5, A_t``."""
    x = np.asarray(slots, dtype=float)
    out = [euler_zyx_trans(*[x[slot(f"base.{f}")] for f in EULER_FIELDS])]
    for n in range(1, 6):
        v = {f: x[slot(f"j{n}.{f}")] for f in ("theta", "d", "a", "alpha", "beta")}
        M = np.eye(4)
        Rz = rot(2, v["theta"])
        M[:3, :3] = Rz @ rot(0, v["alpha"]) @ rot(1, v["beta"])
        M[:3, 3] = Rz @ np.array([v["a"], 0.0, v["d"]])
        out.append(M)
    out.append(euler_zyx_trans(*[x[slot(f"tool.{f}")] for f in EULER_FIELDS]))
    return out


def _origin(T) -> str:
    xyz = " ".join(f"{v / 1000.0:.12g}" for v in T[:3, 3])
    return f'<origin xyz="{xyz}" rpy="{" ".join(f"{v:.15g}" for v in rpy(T[:3, :3]))}"/>'


def to_urdf(model: RobotModel, slots, name: str | None = None) -> str:
    """A URDF document (string) of the chain with geometry ``slots`` (37,) mm/rad."""
    name = name or model.name
    origins = chain_origins(slots)
    lines = ['<?xml version="1.0"?>', f"<robot name={quoteattr(name)}>",
             "  <!-- written by fgcal: joint origins carry the calibrated geometry; lengths in metres -->",
             '  <link name="world"/>', '  <link name="base_link"/>',
             '  <joint name="base_mount" type="fixed"><parent link="world"/><child link="base_link"/>'
             f"{_origin(origins[0])}</joint>"]
    parent = "base_link"
    for n in range(1, 7):
        M = np.eye(4) if n == 1 else origins[n - 1]
        lo, hi = model.joint_limits[n - 1]
        lines.append(f'  <link name="link{n}"/>')
        lines.append(f'  <joint name="joint{n}" type="revolute"><parent link="{parent}"/><child link="link{n}"/>'
                     f'{_origin(M)}<axis xyz="0 0 1"/>'
                     f'<limit lower="{lo:.15g}" upper="{hi:.15g}" effort="0" velocity="0"/></joint>')
        parent = f"link{n}"
    lines.append('  <link name="tool"/>')
    lines.append(f'  <joint name="tool_mount" type="fixed"><parent link="link6"/><child link="tool"/>'
                 f"{_origin(origins[6])}</joint>")
    lines.append("</robot>")
    return "\n".join(lines) + "\n"
