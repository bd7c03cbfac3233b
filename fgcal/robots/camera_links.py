"""Cameras in an exported URDF and beside it (DESIGN.md 8.4): the mount as a link
``camera_NAME_optical`` (OpenCV's optical frame: z forward, x right, y down) on the instrument's
``world`` link (eye-to-hand) or on the calibrated tool link (eye-in-hand), and the intrinsics as a
ROS ``camera_info``-style YAML (``plumb_bob``: k1, k2, p1, p2, k3). No file I/O here.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np

from fgcal.util.yamlio import dump_yaml

__all__ = ["add_camera_links", "camera_info_yaml", "optical_link"]


def optical_link(name: str) -> str:
    """The URDF link of camera ``name``."""
    return f"camera_{name}_optical"


def _rpy(R) -> tuple[float, float, float]:
    """URDF roll, pitch, yaw (rad) with ``R = Rz(yaw) Ry(pitch) Rx(roll)``."""
    return (float(np.arctan2(R[2, 1], R[2, 2])), float(-np.arcsin(np.clip(R[2, 0], -1.0, 1.0))),
            float(np.arctan2(R[1, 0], R[0, 0])))


def add_camera_links(urdf: str, cameras) -> str:
    """``urdf`` (an fgcal export: a ``world`` root and a ``tool`` or ``fgcal_tool`` link) with a fixed
    joint and a link per camera. ``cameras``: ``(name, mount ("world" | "tool"), T (4, 4) mm)``, the
    camera frame in the world or in the tool frame.

    Raises
    ------
    ValueError
        If the URDF has no link to mount a camera on.
    """
    root = ET.fromstring(urdf)
    links = {e.get("name") for e in root.findall("link")}
    tool = "fgcal_tool" if "fgcal_tool" in links else "tool"
    for name, mount, T in cameras:
        parent = "world" if mount == "world" else tool
        if parent not in links:
            raise ValueError(f"the URDF has no link {parent!r} to mount camera {name} on")
        link = optical_link(name)
        ET.SubElement(root, "link", {"name": link})
        joint = ET.SubElement(root, "joint", {"name": f"{link}_mount", "type": "fixed"})
        T = np.asarray(T, dtype=float)
        ET.SubElement(joint, "origin", {"xyz": " ".join(repr(float(v) / 1000.0) for v in T[:3, 3]),
                                        "rpy": " ".join(repr(v) for v in _rpy(T[:3, :3]))})
        ET.SubElement(joint, "parent", {"link": parent})
        ET.SubElement(joint, "child", {"link": link})
    ET.indent(root)
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def camera_info_yaml(name: str, width: int, height: int, k) -> str:
    """A ROS ``camera_info`` YAML of intrinsics ``k`` (9,): ``fx, fy, cx, cy`` (px), ``k1, k2, p1, p2, k3``."""
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = (float(v) for v in k)
    return dump_yaml({
        "image_width": int(width), "image_height": int(height), "camera_name": name,
        "camera_matrix": {"rows": 3, "cols": 3, "data": [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]},
        "distortion_model": "plumb_bob",
        "distortion_coefficients": {"rows": 1, "cols": 5, "data": [k1, k2, p1, p2, k3]},
        "rectification_matrix": {"rows": 3, "cols": 3, "data": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]},
        "projection_matrix": {"rows": 3, "cols": 4,
                              "data": [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0]},
    })
