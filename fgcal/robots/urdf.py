"""URDF export of a (calibrated) chain.

Two forms:

* :func:`to_urdf` writes any model's chain: a fixed joint ``world -> base_link`` with the base
  transform, one joint per actuated joint whose origin is the previous link's fixed part
  (``M_k = Rz(theta_k) Tz(d_k) Tx(a_k) Rx(alpha_k) Ry(beta_k)``), and a fixed joint to a ``tool``
  link. Joint names are the model's.
* :func:`calibrated_urdf` writes a calibrated *copy* of the URDF a model was imported from: the
  same links, joints, limits, efforts, velocities, inertials and visuals, with the calibrated
  origins of the actuated joints 2..n, a ``world`` root (the measuring instrument's frame) placed
  by the calibrated base, and a ``tool`` link on the tip link (the calibrated tool frame).

Both take a ``tool_point``: the centre of the ball that made a contact calibration's contacts
(mm, tool frame); the ``tool`` link is then there (the tool frame moved by it, DESIGN.md 8.2).

Lengths are written in metres, as URDF requires, with round-trip precision. No I/O here.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from xml.sax.saxutils import quoteattr

import numpy as np

from fgcal.robots.base_frame import base_transform, mounting
from fgcal.robots.model import EULER_FIELDS, RobotModel
from fgcal.robots.transforms import euler_zyx_trans, rot
from fgcal.robots.ur_kinematics import is_ur, ur_kinematics, ur_urdf
from fgcal.robots.urdf_origin import origin_element, rpy, xyz_rpy

__all__ = ["calibrated_urdf", "chain_origins", "export_urdf", "origin_element", "rpy", "to_urdf", "ur_to_urdf"]


def chain_origins(model: RobotModel, slots) -> list[np.ndarray]:
    """The n + 1 fixed transforms (4, 4), mm: ``A_b, M_1 ... M_{n-1}, A_t``."""
    x = np.asarray(slots, dtype=float)
    out = [euler_zyx_trans(*[x[model.slot(f"base.{f}")] for f in EULER_FIELDS])]
    for j in model.link_names:
        v = {f: x[model.slot(f"{j}.{f}")] for f in ("theta", "d", "a", "alpha", "beta")}
        M = np.eye(4)
        Rz = rot(2, v["theta"])
        M[:3, :3] = Rz @ rot(0, v["alpha"]) @ rot(1, v["beta"])
        M[:3, 3] = Rz @ np.array([v["a"], 0.0, v["d"]])
        out.append(M)
    out.append(euler_zyx_trans(*[x[model.slot(f"tool.{f}")] for f in EULER_FIELDS]))
    return out


def _at_point(tool_point) -> np.ndarray:
    """Trans(tool_point) (4, 4): the tool link moved from the tool frame to a ball centre (mm)."""
    T = np.eye(4)
    if tool_point is not None:
        T[:3, 3] = np.asarray(tool_point, dtype=float)
    return T


def to_urdf(model: RobotModel, slots, name: str | None = None, tool_point=None) -> str:
    """A URDF document (string) of the chain with geometry ``slots`` (S,) mm/rad; its ``tool`` link at
    ``tool_point`` (3,) mm in the tool frame (the tool frame itself by default).

    ``base_link`` is the robot's own base frame (:func:`fgcal.robots.compensate.base_transform`: a
    table's base frame, at the mounting face), placed in the ``world`` (the measuring instrument's
    frame) by the calibrated base; the first joint's origin is what loading folded into the base.
    Joints carry the model's names. A UR (:func:`fgcal.robots.ur_kinematics.is_ur`) is written in
    ur_description's frames and names instead (:func:`ur_to_urdf`). Effort and velocity limits are
    not part of a model file; they are written as 1e6 (effectively unlimited) rather than 0, which
    URDF consumers (MoveIt, Gazebo) read as "cannot move".
    """

    if is_ur(model):
        return ur_to_urdf(model, slots, name, tool_point)
    name = name or model.name
    origins = chain_origins(model, slots)
    joint_names = list(model.joint_names)
    child_names = [_unique(f"link_{j}", ["world", "base_link", "tool"]) for j in joint_names]
    mounts = [_unique(m, joint_names) for m in ("base_mount", "tool_mount")]
    lines = ['<?xml version="1.0"?>', f"<robot name={quoteattr(name)}>",
             "  <!-- written by fgcal: joint origins carry the calibrated geometry; lengths in metres;"
             " effort and velocity limits unknown to fgcal (1e6). base_link is the robot's own base frame"
             " (the model table's base frame, at the mounting face), placed in world (the measuring instrument's"
             " frame) by the calibrated base; tool is the calibrated tool frame -->",
             '  <link name="world"/>', '  <link name="base_link"/>',
             f'  <joint name={quoteattr(mounts[0])} type="fixed"><parent link="world"/><child link="base_link"/>'
             f"{origin_element(base_transform(model, slots))}</joint>"]
    parent = "base_link"
    limits = model.joint_limits.copy()
    prismatic = ~model.joint_is_angle
    limits[prismatic] /= 1000.0
    for k, (jname, kind) in enumerate(zip(model.joint_names, model.joint_types, strict=True)):
        M = mounting(model) if k == 0 else origins[k]
        lo, hi = limits[k]
        child = child_names[k]
        lines.append(f"  <link name={quoteattr(child)}/>")
        lines.append(f'  <joint name={quoteattr(jname)} type="{kind.value}"><parent link={quoteattr(parent)}/>'
                     f"<child link={quoteattr(child)}/>{origin_element(M)}<axis xyz=\"0 0 1\"/>"
                     f'<limit lower="{float(lo)!r}" upper="{float(hi)!r}" effort="1e6" velocity="1e6"/></joint>')
        parent = child
    lines.append('  <link name="tool"/>')
    lines.append(f'  <joint name={quoteattr(mounts[1])} type="fixed"><parent link={quoteattr(parent)}/><child link="tool"/>'
                 f"{origin_element(origins[-1] @ model.tool_offset_matrix @ _at_point(tool_point))}</joint>")
    lines.append("</robot>")
    return "\n".join(lines) + "\n"


def ur_to_urdf(model: RobotModel, slots, name: str | None = None, tool_point=None) -> str:
    """A UR's calibrated chain in ur_description's frames and joint names (:func:`fgcal.robots.ur_kinematics.ur_urdf`),
    with a ``world`` root (the measuring instrument's frame) placing ``base_link`` (the mounting face)
    by the calibrated base, and a ``tool`` link on ``tool0`` (the calibrated tool frame, or the ball
    centre ``tool_point`` (3,) mm in it)."""

    kin = ur_kinematics(model, slots)
    text = ur_urdf(kin, name or model.name, model.joint_limits, tool=kin.tcp @ _at_point(tool_point))
    # base_link in the instrument frame: the robot's own base frame (the UR's Base for a table) is kin.own_base in it
    placement = base_transform(model, slots) @ np.linalg.inv(kin.own_base)
    head, rest = text.split('  <link name="base_link"/>', 1)
    world = ('  <link name="world"/>\n  <link name="base_link"/>\n  <joint name="world-base_link" type="fixed">'
             f'<parent link="world"/><child link="base_link"/>{origin_element(placement)}</joint>')
    head = head.replace("lengths in metres -->", "world is the measuring instrument's frame (placed by the calibrated "
                        "base); tool the calibrated tool frame; lengths in metres -->")
    return head + world + rest


def _joint_frames(model: RobotModel, slots) -> list[np.ndarray]:
    """World frames (4, 4) of the chain's joints before their motion, at q = 0 (mm)."""
    chain = model.chain
    R_before, p_before, _ = chain.forward_frames(slots, np.zeros((1, model.n_joints)))
    firsts = []
    for k in range(model.n_joints):
        # The first operation of link k (Rz(theta_k ...)), or the last joint's own motion.
        ops = [i for i, op in enumerate(chain.ops) if op.joint == k]
        first = ops[0] - (1 if model.joint_types[k].value == "prismatic" and k < model.n_joints - 1 else 0)
        firsts.append(first)
    out = []
    for i in firsts:
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R_before[i, 0], p_before[i, 0]
        out.append(T)
    return out


def calibrated_urdf(model: RobotModel, slots, tool_point=None) -> str:
    """A calibrated copy of the URDF ``model`` was imported from (see the module docstring); its
    ``tool`` link at ``tool_point`` (3,) mm in the tool frame (the tool frame by default)."""
    from fgcal.robots.urdf_import import parse_urdf, urdf_chain

    info = model.extra["urdf"]
    text = info["text"]
    _, joints, links = parse_urdf(text, model.name)
    chain = urdf_chain(joints, links, info["base"], info["tip"], model.name)
    C = [np.array(c, dtype=float) for c in info["frame_changes"]]
    F = _joint_frames(model, slots)
    Jw = [Fk @ Ck for Fk, Ck in zip(F, C)]  # calibrated URDF joint frames at q = 0 (world)
    root = ET.fromstring(text)
    elements = {e.get("name"): e for e in root.findall("joint")}
    moving = [j for j in chain if j.kind != "fixed"]
    index = {j.name: k for k, j in enumerate(moving)}
    # Walk the chain: the parent-link frame of each joint, with fixed joints as they are.
    T_parent = None
    k_prev = -1
    for j in chain:
        if j.kind == "fixed":
            if T_parent is not None:
                T_parent = T_parent @ j.origin
            continue
        k = index[j.name]
        if k > 0:
            assert T_parent is not None  # set by joint k - 1
            origin = np.linalg.inv(T_parent) @ Jw[k]
            _setorigin_element(elements[j.name], origin)
        T_parent = Jw[k]
        k_prev = k
    assert k_prev == model.n_joints - 1
    # world -> URDF root: the root's calibrated placement, so that joint 1 lands on Jw[0].
    to_first = np.eye(4)
    for j in _path_to_root(joints, links, chain[0].parent) + chain[:chain.index(moving[0]) + 1]:
        to_first = to_first @ j.origin
    world_root = Jw[0] @ np.linalg.inv(to_first)
    roots = [lk for lk in links if lk not in {j.child for j in joints.values()}]
    if roots[0] == "world":
        # The URDF's own root is called world: it becomes the instrument frame, and the joint below
        # it on the way to the chain carries the calibrated placement.
        first = (_path_to_root(joints, links, chain[0].parent) + chain)[0]
        _setorigin_element(elements[first.name], world_root @ first.origin)
    else:
        world = _unique("world", links)  # a link of that name elsewhere in the URDF keeps its name
        _add_link(root, world, first=True)
        links = [*links, world]
        _add_fixed(root, _unique(f"{world}_to_{roots[0]}", joints), world, roots[0], world_root)
    # tip -> tool: the calibrated tool frame relative to the tip link.
    T_world_tip = Jw[-1]
    after = chain[chain.index(moving[-1]) + 1:]
    for j in after:
        T_world_tip = T_world_tip @ j.origin
    x = np.asarray(slots, dtype=float)
    A_t = euler_zyx_trans(*[x[model.slot(f"tool.{f}")] for f in EULER_FIELDS])
    tool = np.linalg.inv(T_world_tip) @ F[-1] @ A_t @ model.tool_offset_matrix @ _at_point(tool_point)
    tool_name = _unique("tool" if "tool" not in links else "fgcal_tool", links)
    _add_link(root, tool_name)
    _add_fixed(root, _unique(f"{tool_name}_mount", [*joints, *(e.get("name") for e in root.findall("joint"))]),
               info["tip"], tool_name, tool)
    root.insert(0, ET.Comment(" calibrated by fgcal: actuated joint origins, world root (measuring instrument) and "
                              "tool link; lengths in metres "))
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def _unique(name: str, taken) -> str:
    """``name``, or ``name_2``, ``name_3`` ... when ``taken`` (names of links or joints) has it."""
    taken = set(taken)
    k, out = 1, name
    while out in taken:
        k += 1
        out = f"{name}_{k}"
    return out


def _path_to_root(joints, links, link) -> list:
    by_child = {j.child: j for j in joints.values()}
    path = []
    while link in by_child:
        j = by_child[link]
        path.append(j)
        link = j.parent
    return path[::-1]


def _setorigin_element(element, T) -> None:
    o = element.find("origin")
    if o is None:
        o = ET.SubElement(element, "origin")
    o.set("xyz", xyz_rpy(T)[0])
    o.set("rpy", xyz_rpy(T)[1])


def _add_link(root, name, first=False) -> None:
    e = ET.Element("link", {"name": name})
    if first:
        root.insert(0, e)
    else:
        root.append(e)


def _add_fixed(root, name, parent, child, T) -> None:
    e = ET.SubElement(root, "joint", {"name": name, "type": "fixed"})
    ET.SubElement(e, "parent", {"link": parent})
    ET.SubElement(e, "child", {"link": child})
    xyz, angles = xyz_rpy(T)
    ET.SubElement(e, "origin", {"xyz": xyz, "rpy": angles})


def export_urdf(model: RobotModel, slots, tool_point=None) -> str:
    """The calibrated URDF: a copy of the user's URDF when the model came from one, else :func:`to_urdf`;
    the ``tool`` link at ``tool_point`` (3,) mm in the tool frame when given (a contact calibration's ball)."""
    if "urdf" in model.extra:
        return calibrated_urdf(model, slots, tool_point)
    return to_urdf(model, slots, tool_point=tool_point)
