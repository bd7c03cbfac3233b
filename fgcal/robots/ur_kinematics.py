"""Universal Robots' kinematics file (``kinematics:`` YAML of ur_description) to and from fgcal models.

ur_description builds a UR's chain from six joint origins read through ``kinematics_params_file``::

    base_link -> base_link_inertia          Rz(pi) (base_link is REP-103: x forward, the UR's Base x backward)
    base_link_inertia -> shoulder_link      O_1 Rz(q_1)     (shoulder_pan_joint, origin "shoulder")
    shoulder_link -> upper_arm_link         O_2 Rz(q_2)     (shoulder_lift_joint, "upper_arm")
    ...                                     O_6 Rz(q_6)     (wrist_3_joint, "wrist_3")
    wrist_3_link -> flange -> tool0         identity in total (rpy 0 -pi/2 -pi/2, then pi/2 0 pi/2)

with ``O_k = Trans(x, y, z) Rz(yaw) Ry(pitch) Rx(roll)`` (URDF rpy), metres and radians.
``base_link`` is the mounting face (for a UR10 127.3 mm below the first joint frame, which lies at
the shoulder height d1). ur_calibration writes the controller's DH calibration in this form after
its chain correction: each DH row is split into ``Rz(theta) Tz(d)`` and ``Tx(a) Rx(alpha)``, and
``O_k = [Tx(a_{k-1}) Rx(alpha_{k-1})] [Rz(theta_k) Tz(d_k)]`` once the huge d2, d3 of the real
DH are moved into the next joints.

fgcal's chain has that corrected form already: with joint variables ``v = q + c``, each link is
``Rz(v_k) D_k P_k`` with ``D_k = Rz(theta_k) Tz(d_k)`` (commutes with the motion) and
``P_k = Tx(a_k) Rx(alpha_k) Ry(beta_k)``; where axes are parallel (UR joints 2-3-4) Hayati's beta
replaces d, held at 0, so no d of metres appears. Regrouped::

    O_1 = Rz(-pi) G D_1 Rz(c_1),  O_k = P_{k-1} D_k Rz(c_k) (k = 2..5),  O_6 = P_5 Z Rz(c_6)

where ``G`` is the chain's first frame in base_link and ``Z = Rz(gamma) Tz(dz)`` is the part of the
constant transform ``K`` after the last joint that commutes with its motion. The rest,
``K' = Z^-1 K`` (no z offset, no yaw), cannot be a joint origin: it is the calibrated tool frame
in tool0, the TCP the controller holds (:attr:`UrKinematics.tcp`). Units inside: mm, rad.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field

import numpy as np

from fgcal.errors import ModelError
from fgcal.robots.base_frame import mounting
from fgcal.robots.model import EULER_FIELDS, RobotModel
from fgcal.robots.transforms import euler_zyx_trans, rot
from fgcal.robots.urdf_origin import origin_element, rpy
from fgcal.util.numbers import finite_number

__all__ = ["ROS_JOINTS", "UR_LINKS", "UrKinematics", "is_ur", "kinematics_text", "model_from_kinematics",
           "parse_kinematics", "rotation_from_angles", "ur_forward", "ur_kinematics", "ur_urdf"]

UR_LINKS = ("shoulder", "upper_arm", "forearm", "wrist_1", "wrist_2", "wrist_3")
ROS_JOINTS = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint",
              "wrist_3_joint")
ROS_LINKS = ("shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link", "wrist_2_link", "wrist_3_link")
_UR_TWISTS = np.radians([90.0, 0.0, 0.0, 90.0, -90.0])


@dataclass(frozen=True)
class UrKinematics:
    """The six joint origins of a UR in ur_description's convention.

    Attributes
    ----------
    origins : ndarray, shape (6, 4, 4)
        ``O_1 .. O_6`` (mm): joint k's origin in its parent link (``base_link_inertia`` for k = 1).
    hash : str
        The file's ``hash``: ur_calibration writes ``calib_`` and the controller's calibration
        checksum; the driver warns when it differs from the connected robot's.
    tcp : ndarray, shape (4, 4)
        The calibrated tool frame in ``tool0`` (mm): what no joint origin can hold (identity for a
        flange tool).
    own_base : ndarray, shape (4, 4)
        The model's own base frame (:func:`fgcal.robots.base_frame.base_transform`) in base_link
        (mm): ``Rz(pi)`` for a table (the UR's Base frame), identity for a URDF based at base_link.
    """

    origins: np.ndarray
    hash: str = ""
    tcp: np.ndarray = field(default_factory=lambda: np.eye(4))
    own_base: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self):
        o = np.asarray(self.origins, dtype=float)
        if o.shape != (6, 4, 4):
            raise ValueError(f"origins must have shape (6, 4, 4), got {o.shape}")
        object.__setattr__(self, "origins", o)
        object.__setattr__(self, "tcp", np.asarray(self.tcp, dtype=float))
        object.__setattr__(self, "own_base", np.asarray(self.own_base, dtype=float))


def _ros_names(names) -> bool:
    """The joint names are ur_description's (with any common tf prefix)."""
    names = tuple(names)
    if len(names) != 6 or not names[0].endswith(ROS_JOINTS[0]):
        return False
    prefix = names[0][: -len(ROS_JOINTS[0])]
    return names == tuple(prefix + j for j in ROS_JOINTS)


def is_ur(model: RobotModel) -> bool:
    """``model`` is a UR: six revolute, uncoupled joints, and either a URDF with ur_description's
    joint names or a table with the UR's structure (twists 90, 0, 0, 90, -90 deg; the table's base
    frame is then the UR's Base frame, ``base_link_inertia``)."""
    if model.n_joints != 6 or not np.all(model.joint_is_angle) or model.joint_map is not None:
        return False
    if "urdf" in model.extra:
        return _ros_names(model.joint_names)
    alphas = np.array([model.nominal[model.slot(f"{j}.alpha")] for j in model.link_names])
    betas = np.array([model.nominal[model.slot(f"{j}.beta")] for j in model.link_names])
    return bool(np.allclose(alphas, _UR_TWISTS, atol=0.05) and np.allclose(betas, 0.0, atol=0.05))


def _fixed_path(joints, upper: str, lower: str) -> np.ndarray | None:
    """Link ``lower`` in link ``upper`` (4, 4; mm) when ``lower`` is below ``upper`` through fixed joints only."""
    by_child = {j.child: j for j in joints.values()}
    T, link = np.eye(4), lower
    while link != upper:
        j = by_child.get(link)
        if j is None or j.kind != "fixed":
            return None
        T = j.origin @ T
        link = j.parent
    return T


def _urdf_frames(model: RobotModel) -> tuple[np.ndarray, np.ndarray]:
    """``(U, X)``: the chain's base link in ``base_link`` and ``tool0`` in the chain's tip link (mm)."""
    from fgcal.robots.urdf_import import parse_urdf

    info = model.extra["urdf"]
    _, joints, links = parse_urdf(info["text"], model.name)
    prefix = model.joint_names[0][: -len(ROS_JOINTS[0])]
    base_link, tool0 = prefix + "base_link", prefix + "tool0"
    for name in (base_link, tool0):
        if name not in links:
            raise ModelError(f"{model.name}: the URDF has no link {name!r} (ur_description's frames are needed)")
    U = _fixed_path(joints, info["base"], base_link)
    if U is not None:
        U = np.linalg.inv(U)
    else:
        U = _fixed_path(joints, base_link, info["base"])
    X = _fixed_path(joints, info["tip"], tool0)
    if X is None:
        inverse = _fixed_path(joints, tool0, info["tip"])
        X = None if inverse is None else np.linalg.inv(inverse)
    if U is None or X is None:
        raise ModelError(f"{model.name}: {base_link} and {tool0} must be joined to the chain ({info['base']} -> "
                         f"{info['tip']}) by fixed joints only")
    return U, X


def _z_part(K) -> tuple[np.ndarray, np.ndarray]:
    """``K = Z K'`` with ``Z = Rz(gamma) Tz(dz)`` and ``K'`` without z offset or yaw (ZYX)."""
    gamma = math.atan2(K[1, 0], K[0, 0])
    Z = np.eye(4)
    Z[:3, :3] = rot(2, gamma)
    Z[2, 3] = K[2, 3]
    return Z, np.linalg.solve(Z, K)


def ur_kinematics(model: RobotModel, slots, hash: str | None = None) -> UrKinematics:
    """The UR kinematics (joint origins and the TCP left over) of ``model`` with geometry ``slots``.

    Parameters
    ----------
    model : RobotModel
        A UR (:func:`is_ur`): a built-in UR or DH table (its base frame is the UR's Base frame, its
        tool frame the flange, as the built-in models define them), or
        a URDF with ur_description's joint names and its ``base_link`` and ``tool0`` links.
    slots : array_like, shape (37,)
        Geometry (mm, rad). The base slots (the instrument placement) do not enter: base_link is
        placed by the nominal mounting, which no measurement of the tool can tell apart.
    hash : str, optional
        The ``hash`` to write; by default ``fgcal_`` and 16 hex digits of the origins' values.
    """
    if not is_ur(model):
        raise ModelError(f"{model.name}: not a Universal Robots arm (six uncoupled revolute joints with the UR's "
                         "structure, or a URDF with ur_description's joint names)")

    x = np.asarray(slots, dtype=float)
    if "urdf" in model.extra:
        U, X = _urdf_frames(model)
    else:
        U, X = rot_z4(np.pi), np.eye(4)  # base_link <- the UR's Base frame (the table's); tool0 is the flange
    c = np.zeros(6) if model.joint_offset is None else model.joint_offset

    def link(j):
        v = {f: x[model.slot(f"{j}.{f}")] for f in ("theta", "d", "a", "alpha", "beta")}
        D = rot_z4(v["theta"])
        D[2, 3] = v["d"]
        P = np.eye(4)
        P[:3, :3] = rot(0, v["alpha"]) @ rot(1, v["beta"])
        P[0, 3] = v["a"]
        return D, P

    parts = [link(j) for j in model.link_names]
    A_t = euler_zyx_trans(*[x[model.slot(f"tool.{f}")] for f in EULER_FIELDS])
    Z, tcp = _z_part(A_t @ model.tool_offset_matrix @ X)
    origins = [rot_z4(-np.pi) @ U @ mounting(model) @ parts[0][0] @ rot_z4(c[0])]
    origins += [parts[k - 1][1] @ parts[k][0] @ rot_z4(c[k]) for k in range(1, 5)]
    origins.append(parts[4][1] @ Z @ rot_z4(c[5]))
    origins_arr = _ur_gauge(np.array(origins))
    if hash is None:
        digest = hashlib.sha256(np.round(origins_arr, 9).tobytes()).hexdigest()[:16]
        hash = f"fgcal_{digest}"
    return UrKinematics(origins_arr, hash, tcp, U)


def _ur_gauge(origins) -> np.ndarray:
    """The origins with each link frame 1..5 turned about its joint axis to the UR's own (nearest
    ``Rx(alpha_{k-1})``, alpha 90, 0, 0, 90, -90 deg), where ur_description's meshes sit. Turning link
    k's frame by g is ``O_k Rz(g)``, ``Rz(-g) O_{k+1}``: the same kinematics; tool0 stays."""
    out = np.array(origins, dtype=float)
    refs = [np.eye(3)] + [rot(0, a) for a in _UR_TWISTS]
    for k in range(5):
        M = refs[k].T @ out[k, :3, :3]
        g = math.atan2(M[0, 1] - M[1, 0], M[0, 0] + M[1, 1])
        out[k] = out[k] @ rot_z4(g)
        out[k + 1] = rot_z4(-g) @ out[k + 1]
    return out


def rot_z4(angle: float) -> np.ndarray:
    """``Rz(angle)`` as (4, 4)."""
    T = np.eye(4)
    T[:3, :3] = rot(2, angle)
    return T


def rotation_from_angles(roll: float, pitch: float, yaw: float, angles: str = "urdf") -> np.ndarray:
    """The rotation (3, 3) of a kinematics entry: ``urdf`` ``Rz(yaw) Ry(pitch) Rx(roll)`` (as
    ur_description reads the file) or ``eigen`` ``Rx(roll) Ry(pitch) Rz(yaw)`` (as ur_calibration's
    writer, Eigen's ``eulerAngles(0, 1, 2)``, computed them)."""
    if angles == "urdf":
        return rot(2, yaw) @ rot(1, pitch) @ rot(0, roll)
    if angles == "eigen":
        return rot(0, roll) @ rot(1, pitch) @ rot(2, yaw)
    raise ValueError(f"angles must be 'urdf' or 'eigen', got {angles!r}")


def ur_forward(kin: UrKinematics, q) -> np.ndarray:
    """tool0 in base_link (N, 4, 4; mm) at joint readings ``q`` (N, 6) rad, ur_description's chain."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    out = np.empty((len(q), 4, 4))
    for i, qi in enumerate(q):
        T = rot_z4(np.pi)
        for origin, qk in zip(kin.origins, qi, strict=True):
            T = T @ origin @ rot_z4(qk)
        out[i] = T
    return out


def _num(v: float) -> str:
    v = float(v)
    return "0" if v == 0.0 else repr(v)  # no negative zero


def _entry(T, indent: str) -> list[str]:
    r, p, y = rpy(T[:3, :3])
    lines = [f"{indent}{key}: {_num(round(value, 15))}"
             for key, value in zip(("x", "y", "z"), T[:3, 3] / 1000.0, strict=True)]
    angles = zip(("roll", "pitch", "yaw"), (r, p, y), strict=True)
    return lines + [f"{indent}{key}: {_num(value)}" for key, value in angles]


def kinematics_text(kin: UrKinematics, comment: str = "") -> str:
    """The ``kinematics:`` YAML document (metres, radians as URDF rpy) of ``kin``.

    Beside it, ``fgcal: tool_in_tool0:`` holds :attr:`UrKinematics.tcp` the same way (the
    calibrated tool frame in tool0; ur_description reads only ``kinematics``).
    """
    lines = [f"# {c}" for c in comment.splitlines()] + ["kinematics:"]
    for name, origin in zip(UR_LINKS, kin.origins, strict=True):
        lines.append(f"  {name}:")
        lines += _entry(origin, "    ")
    lines.append(f"  hash: {kin.hash}")
    lines += ["fgcal:", "  # the calibrated tool frame in tool0 (m, URDF rpy): the TCP, which no joint origin holds",
              "  tool_in_tool0:"] + _entry(kin.tcp, "    ")
    return "\n".join(lines) + "\n"


def parse_kinematics(data, source: str = "<kinematics>", angles: str = "urdf") -> UrKinematics:
    """:class:`UrKinematics` from a parsed kinematics file; one-line :class:`ModelError` naming ``source``."""
    if not isinstance(data, dict) or not isinstance(data.get("kinematics"), dict):
        raise ModelError(f"{source}: not a UR kinematics file (expected a top-level 'kinematics:' mapping)")
    k = data["kinematics"]
    origins = []
    for name in UR_LINKS:
        entry = k.get(name)
        if not isinstance(entry, dict):
            raise ModelError(f"{source}: kinematics.{name}: missing (expected x, y, z, roll, pitch, yaw)")
        values = []
        for key in ("x", "y", "z", "roll", "pitch", "yaw"):
            v = entry.get(key)
            if v is None or not finite_number(v):
                raise ModelError(f"{source}: kinematics.{name}.{key}: expected a finite number (m or rad), got {v!r}")
            values.append(float(v))
        if max(abs(v) for v in values[:3]) > 10.0:
            raise ModelError(f"{source}: kinematics.{name}: an offset of more than 10 m; the values are metres")
        origin = np.eye(4)
        origin[:3, :3] = rotation_from_angles(values[3], values[4], values[5], angles=angles)
        origin[:3, 3] = 1000.0 * np.array(values[:3])
        origins.append(origin)
    return UrKinematics(np.array(origins), str(k.get("hash", "")))


def ur_urdf(kin: UrKinematics, name: str = "ur", joint_limits=None, tool=None) -> str:
    """A URDF of ur_description's chain (links and joints by its names, no meshes) with ``kin``'s origins.

    ``joint_limits`` (6, 2) rad, +-2 pi by default; ``tool`` (4, 4; mm): a ``tool`` link on tool0
    (omitted when None).
    """

    limits = np.tile([-2 * np.pi, 2 * np.pi], (6, 1)) if joint_limits is None else np.asarray(joint_limits)
    lines = ['<?xml version="1.0"?>', f'<robot name="{name}">',
             "  <!-- ur_description's frames: base_link is the mounting face (REP-103, x forward); "
             "base_link_inertia the UR controller's Base frame (Rz(pi)); tool0 the flange; lengths in metres -->",
             '  <link name="base_link"/>', '  <link name="base_link_inertia"/>',
             '  <joint name="base_link-base_link_inertia" type="fixed"><parent link="base_link"/>'
             f'<child link="base_link_inertia"/>{origin_element(rot_z4(np.pi))}</joint>']
    parent = "base_link_inertia"
    for joint, link, origin, (lo, hi) in zip(ROS_JOINTS, ROS_LINKS, kin.origins, limits, strict=True):
        lines.append(f'  <link name="{link}"/>')
        lines.append(f'  <joint name="{joint}" type="revolute"><parent link="{parent}"/><child link="{link}"/>'
                     f'{origin_element(origin)}<axis xyz="0 0 1"/>'
                     f'<limit lower="{float(lo)!r}" upper="{float(hi)!r}" effort="1e6" velocity="1e6"/></joint>')
        parent = link
    flange = np.eye(4)
    flange[:3, :3] = rotation_from_angles(0.0, -np.pi / 2, -np.pi / 2)
    lines += ['  <link name="flange"/>', '  <link name="tool0"/>',
              '  <joint name="wrist_3-flange" type="fixed"><parent link="wrist_3_link"/><child link="flange"/>'
              f"{origin_element(flange)}</joint>",
              '  <joint name="flange-tool0" type="fixed"><parent link="flange"/><child link="tool0"/>'
              f"{origin_element(np.linalg.inv(flange))}</joint>"]
    if tool is not None:
        lines += ['  <link name="tool"/>', '  <joint name="tool0-tool" type="fixed"><parent link="tool0"/>'
                  f'<child link="tool"/>{origin_element(np.asarray(tool, dtype=float))}</joint>']
    lines.append("</robot>")
    return "\n".join(lines) + "\n"


def model_from_kinematics(kin: UrKinematics, name: str = "ur", joint_limits=None,
                          source: str = "<kinematics>") -> RobotModel:
    """A :class:`RobotModel` of the UR described by ``kin``: the chain base_link -> tool0 of
    :func:`ur_urdf` (world frame base_link, tool frame tool0, ur_description's joint names)."""
    from fgcal.robots.urdf_import import model_from_urdf

    model = model_from_urdf(ur_urdf(kin, name, joint_limits), source=source, base="base_link", tip="tool0",
                            name=name)
    extra = dict(model.extra)
    extra["ur_kinematics"] = {"hash": kin.hash}
    from dataclasses import replace

    return replace(model, extra=extra, description=f"UR kinematics from {source}"
                   + (f" (hash {kin.hash})" if kin.hash else ""))
