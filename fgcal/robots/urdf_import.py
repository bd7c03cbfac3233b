"""Robots from URDF: the chain between two links, converted to the paper's convention.

A URDF places each joint by an ``origin`` (xyz, rpy) in its parent link and moves it about (or
along) an ``axis``. Calibration needs the *minimal* geometry: the joint axes as lines. At q = 0 the
axes are found in the URDF's base-link frame and the chain is rebuilt in the paper's convention
(standard Denavit-Hartenberg with Hayati's beta where consecutive axes are parallel): link k runs
along the common normal of axes k and k+1. Both descriptions move the same rigid bodies about the
same lines and agree at q = 0, so they agree at every q. The constant frame change ``C_k`` from
the rebuilt frame of joint k to the URDF's joint frame is kept, so that a calibrated chain can be
written back as a copy of the user's URDF (:mod:`fgcal.robots.urdf`).

Lengths become millimetres (URDF: metres); prismatic readings are millimetres. Parsing uses the
standard library's XML parser; nothing of ROS is needed. No file I/O here but
:func:`load_urdf_model` (which reads one file).
"""
from __future__ import annotations

import io
import logging
import xml.etree.ElementTree as ET
from collections import Counter
from pathlib import Path

import numpy as np

from fgcal.errors import ModelError
from fgcal.robots.euler_block import euler_dict
from fgcal.robots.model import JointType, RobotModel
from fgcal.robots.transforms import rot, to_euler_zyx_trans
from fgcal.util.yamlio import read_text_file, short_repr

__all__ = ["UrdfJoint", "load_urdf_model", "model_from_urdf", "parse_urdf", "rpy_matrix", "urdf_chain"]

log = logging.getLogger(__name__)

MAX_URDF_BYTES = 20 * 1024 * 1024
NEAR_PARALLEL = 0.05  # |z_k x z_k+1| below which consecutive axes are rebuilt with Hayati's beta (2.9 deg)
_MOVING = {"revolute": JointType.REVOLUTE, "continuous": JointType.REVOLUTE, "prismatic": JointType.PRISMATIC}


def rpy_matrix(r, p, y) -> np.ndarray:
    """URDF ``rpy``: ``Rz(yaw) Ry(pitch) Rx(roll)`` (rad)."""
    return rot(2, y) @ rot(1, p) @ rot(0, r)


class UrdfJoint:
    """One URDF joint: name, type, parent and child links, origin (4, 4; mm), unit axis, limits."""

    __slots__ = ("axis", "child", "kind", "lower", "mimic", "name", "origin", "parent", "upper")

    def __init__(self, name, kind, parent, child, origin, axis, lower, upper, mimic):
        self.name, self.kind, self.parent, self.child = name, kind, parent, child
        self.origin, self.axis, self.lower, self.upper, self.mimic = origin, axis, lower, upper, mimic


def _floats(text, n, where) -> np.ndarray:
    try:
        values = np.array([float(v) for v in (text or "").split()], dtype=float)
    except ValueError:
        raise ModelError(f"{where}: expected {n} numbers, got {short_repr(text, 40)}") from None
    if values.shape != (n,) or not np.all(np.isfinite(values)):
        raise ModelError(f"{where}: expected {n} finite numbers, got {short_repr(text, 40)}")
    return values


def _limit(text, where) -> float:
    """A joint limit (rad or m): one finite number."""
    return float(_floats(text, 1, where)[0])


def parse_urdf(text: str, source: str = "<urdf>") -> tuple[str, dict[str, UrdfJoint], list[str]]:
    """The robot name, joints by name and link names of a URDF document.

    Raises
    ------
    ModelError
        Naming ``source`` and the element at fault.
    """
    if "<!ENTITY" in text:  # URDFs declare none; expanded ones made 18 MB a 1.5 GB document, below expat's guard
        raise ModelError(f"{source}: declares XML entities (<!ENTITY ...>); a URDF has none: refusing to expand them")
    links: list[str] = []
    joints: dict = {}
    name_of_robot = None
    depth = 0
    root = None
    # Streamed (iterparse): each top-level <link> and <joint> is read at its end and cleared, so the
    # document's tree is never held whole (a URDF of 100,000 frames took 14 times its size).
    try:
        for event, e in ET.iterparse(io.StringIO(text), events=("start", "end")):
            if event == "start":
                depth += 1
                if depth == 1:
                    root = e
                    if e.tag != "robot":
                        raise ModelError(f"{source}: the root element is <{e.tag}>, expected <robot>")
                    name_of_robot = e.get("name")
                continue
            depth -= 1
            if depth != 1:
                continue
            if e.tag == "link":
                links.append(str(e.get("name")))
            elif e.tag == "joint":
                _read_joint(e, source, joints)
            e.clear()
            if root is not None:
                root.clear()  # the children read so far
    except ET.ParseError as exc:
        raise ModelError(f"{source}: not a valid URDF (XML): {exc}") from None
    if len(set(links)) < len(links):
        twice = sorted(k for k, n in Counter(links).items() if n > 1)
        raise ModelError(f"{source}: link name(s) {short_repr(', '.join(twice[:3]), 60)} used twice")
    return str(name_of_robot or "robot"), joints, links


def _read_joint(e, source: str, joints: dict) -> None:
    """One ``<joint>`` element into ``joints`` (by name)."""
    name, kind = e.get("name"), e.get("type")
    where = f"{source}: joint {short_repr(name, 60)}"
    if name in joints:
        raise ModelError(f"{where}: joint name used twice")
    parent, child = e.find("parent"), e.find("child")
    if not name or kind is None or parent is None or child is None:
        raise ModelError(f"{where}: needs a name, a type, <parent link=...> and <child link=...>")
    T = np.eye(4)
    o = e.find("origin")
    if o is not None:
        T[:3, 3] = 1000.0 * _floats(o.get("xyz", "0 0 0"), 3, f"{where}: origin xyz")
        T[:3, :3] = rpy_matrix(*_floats(o.get("rpy", "0 0 0"), 3, f"{where}: origin rpy"))
    a = e.find("axis")
    axis = _floats(a.get("xyz", "1 0 0"), 3, f"{where}: axis") if a is not None else np.array([1.0, 0, 0])
    norm = np.linalg.norm(axis)
    if kind in _MOVING and norm < 1e-9:
        raise ModelError(f"{where}: axis is zero")
    lim = e.find("limit")
    scale = 1000.0 if kind == "prismatic" else 1.0
    lower = upper = None
    if lim is not None and kind != "continuous":
        lower = scale * _limit(lim.get("lower"), f"{where}: limit lower") if lim.get("lower") is not None else None
        upper = scale * _limit(lim.get("upper"), f"{where}: limit upper") if lim.get("upper") is not None else None
    joints[name] = UrdfJoint(name, kind, parent.get("link"), child.get("link"), T, axis / max(norm, 1e-300),
                             lower, upper, e.find("mimic") is not None)


def urdf_chain(joints: dict[str, UrdfJoint], links: list[str], base: str | None, tip: str | None,
               source: str) -> list[UrdfJoint]:
    """The joints from link ``base`` to link ``tip`` (the root and the only leaf by default)."""
    by_child = {j.child: j for j in joints.values()}
    parents = {j.parent for j in joints.values()}
    roots = [k for k in links if k not in by_child]
    leaves = [k for k in links if k not in parents]
    if base is None:
        if len(roots) != 1:
            raise ModelError(f"{source}: {len(roots)} root links ({', '.join(roots)}); name the chain's base link")
        base = roots[0]
    if tip is None:
        if len(leaves) != 1:
            raise ModelError(f"{source}: more than one leaf link ({', '.join(leaves)}); pick the chain with "
                             "chain: {base: LINK, tip: LINK} in dataset.yaml")
        tip = leaves[0]
    for name in (base, tip):
        if name not in links:
            raise ModelError(f"{source}: no link named {name!r}")
    chain, link, seen = [], tip, set()
    while link != base:
        if link not in by_child or link in seen:
            raise ModelError(f"{source}: link {tip!r} is not below link {base!r}")
        seen.add(link)
        j = by_child[link]
        chain.append(j)
        link = j.parent
    chain.reverse()
    for j in chain:
        if j.kind not in _MOVING and j.kind != "fixed":
            raise ModelError(f"{source}: joint {j.name!r} is of type {j.kind!r}; a calibration chain has "
                             "revolute, continuous, prismatic and fixed joints only")
        if j.mimic and j.kind in _MOVING:
            raise ModelError(f"{source}: joint {j.name!r} mimics another joint; give the coupling in a model "
                             "file (coupling: matrix) instead")
    if not any(j.kind in _MOVING for j in chain):
        raise ModelError(f"{source}: no moving joint between {base!r} and {tip!r}")
    return chain


def _feet(p1, z1, p2, z2):
    """Closest points of two non-parallel lines ``p + s z``."""
    w0 = p1 - p2
    b, d, e = z1 @ z2, z1 @ w0, z2 @ w0
    den = 1.0 - b * b
    s = (b * e - d) / den
    t = (e - b * d) / den
    return p1 + s * z1, p2 + t * z2, s


def _signed_angle(u, v, axis) -> float:
    return float(np.arctan2(np.cross(u, v) @ axis, u @ v))


def _frame(R, p) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


def model_from_urdf(text: str, source: str = "<urdf>", base: str | None = None, tip: str | None = None,
                    name: str | None = None) -> RobotModel:
    """A :class:`RobotModel` (paper convention) of the chain ``base`` -> ``tip`` of a URDF.

    The world frame is the base link's; the tool frame is the tip link's. Slot names use the
    URDF's joint names. ``model.extra["urdf"]`` keeps what :func:`fgcal.robots.urdf.calibrated_urdf`
    needs to write a calibrated copy of the document.
    """
    robot_name, joints, links = parse_urdf(text, source)
    chain = urdf_chain(joints, links, base, tip, source)
    base = base or chain[0].parent
    tip = tip or chain[-1].child
    moving = [j for j in chain if j.kind in _MOVING]
    # Joint frames J_k (before motion) and the tip frame, in the base-link frame, at q = 0.
    T = np.eye(4)
    J = []
    for j in chain:
        T = T @ j.origin
        if j.kind in _MOVING:
            J.append(T.copy())
    T_tip = T
    z = [Jk[:3, :3] @ j.axis for Jk, j in zip(J, moving)]
    o = [Jk[:3, 3] for Jk in J]
    n = len(moving)

    # Rebuild the chain link by link: F is the paper's frame of joint k (z on the axis).
    z0 = z[0]
    seed = np.array([1.0, 0, 0]) if abs(z0[0]) < 0.9 else np.array([0, 1.0, 0])
    x0 = seed - (seed @ z0) * z0
    x0 /= np.linalg.norm(x0)
    F = _frame(np.column_stack([x0, np.cross(z0, x0), z0]), o[0])
    frames, rows = [F], []
    for k in range(n - 1):
        zk, zn = F[:3, 2], z[k + 1]
        xk, pk = F[:3, 0], F[:3, 3]
        if np.linalg.norm(np.cross(zk, zn)) < NEAR_PARALLEL and abs(zk @ zn) > 0:
            # (nearly) parallel: Hayati, d = 0; the next frame is where axis k+1 meets the xy plane of
            # this one, tilted by alpha, beta (0 for exactly parallel axes): no d of metres
            t = -(zk @ (o[k + 1] - pk)) / (zk @ zn)
            foot_next = o[k + 1] + t * zn
            v = foot_next - pk
            a = float(np.linalg.norm(v))
            x_mid = v / a if a > 1e-9 else xk
            if a <= 1e-9:
                a = 0.0
            theta = _signed_angle(xk, x_mid, zk)
            u = np.column_stack([x_mid, np.cross(zk, x_mid), zk]).T @ zn
            beta = float(np.arcsin(np.clip(u[0], -1.0, 1.0)))
            alpha = float(np.arctan2(-u[1], u[2]))
            x_local = np.array([np.cos(beta), np.sin(alpha) * np.sin(beta), -np.cos(alpha) * np.sin(beta)])
            x_new = np.column_stack([x_mid, np.cross(zk, x_mid), zk]) @ x_local
            rows.append((theta, 0.0, beta, a, alpha))
            F = _frame(np.column_stack([x_new, np.cross(zn, x_new), zn]), foot_next)
            frames.append(F)
            continue
        c1, c2, d = _feet(pk, zk, o[k + 1], zn)
        x_new = np.cross(zk, zn)
        x_new /= np.linalg.norm(x_new)
        a = float((c2 - c1) @ x_new)
        foot_next = c2
        theta = _signed_angle(xk, x_new, zk)
        alpha = _signed_angle(zk, zn, x_new)
        rows.append((theta, float(d), 0.0, a, alpha))
        F = _frame(np.column_stack([x_new, np.cross(zn, x_new), zn]), foot_next)
        frames.append(F)

    # Link 1's theta and d are the base's: fold them in (as model files do).
    theta1, d1 = (rows[0][0], rows[0][1]) if rows else (0.0, 0.0)
    A_b = frames[0] @ _frame(rot(2, theta1), np.array([0.0, 0.0, d1])) if rows else frames[0]
    if rows:
        rows[0] = (0.0, 0.0) + rows[0][2:]
    A_t = np.linalg.inv(frames[-1]) @ T_tip
    tool_offset = None
    if abs(A_t[2, 0]) > 1 - 1e-6:
        # The tool's x axis lies along the last joint axis, where the paper's ZYX angles are
        # singular: calibrate a frame turned by 90 deg about y, and keep the turn as a constant.
        tool_offset = _frame(rot(1, np.pi / 2), np.zeros(3))
        A_t = A_t @ np.linalg.inv(tool_offset)
    try:
        nominal = np.concatenate([to_euler_zyx_trans(A_b), np.array(rows, dtype=float).reshape(-1),
                                  to_euler_zyx_trans(A_t)])
    except ValueError as exc:  # the base frame at the ZYX singularity (found by tests/test_properties.py)
        raise ModelError(f"{source}: the chain's base or tool frame cannot be written as ZYX angles ({exc}); "
                         "check the first joint's <axis> and <origin>") from None
    limits = []
    for j in moving:
        wide = 4 * np.pi if _MOVING[j.kind] is JointType.REVOLUTE else 1e4
        lo = j.lower if j.lower is not None else -wide
        hi = j.upper if j.upper is not None else wide
        if lo < -wide or hi > wide:  # beyond two turns (10 m): no limit in practice, and no joint draws there
            log.warning("%s: joint %s: limits %.6g..%.6g taken as %.6g..%.6g", source, j.name, lo, hi,
                        max(lo, -wide), min(hi, wide))
            lo, hi = max(lo, -wide), min(hi, wide)
        if not lo < hi:
            raise ModelError(f"{source}: joint {j.name!r}: limit lower {lo} is not below upper {hi}")
        limits.append((lo, hi))
    # C_k: rebuilt frame -> URDF joint frame, constant and commuting with the motion about z.
    Fk = [frames[0] @ _frame(rot(2, theta1), np.array([0.0, 0.0, d1]))] + frames[1:] if rows else frames
    C = [np.linalg.inv(Fk[k]) @ J[k] for k in range(n)]
    names = tuple(j.name for j in moving)
    clash = [x for x in names if x in ("base", "tool")]
    if clash:
        raise ModelError(f"{source}: a joint named {clash[0]!r} clashes with fgcal's base/tool parameters")
    # the chain's base frame in the base link's: the robot's own base frame is the base link
    extra = {"urdf": {"text": text, "base": base, "tip": tip,
                      "frame_changes": [np.round(c, 15).tolist() for c in C]}, "mounting": euler_dict(A_b)}
    model = RobotModel(name=name or robot_name, nominal=nominal, joint_limits=np.array(limits),
                       description=f"from URDF {Path(source).name}: chain {base} -> {tip}",
                       joint_types=tuple(_MOVING[j.kind] for j in moving), link_names=names[:-1],
                       joint_names=names, extra=extra, tool_offset=tool_offset)
    _check_same_kinematics(model, chain, source)
    return model


def _urdf_forward(chain, q) -> np.ndarray:
    """Plain URDF forward kinematics (mm) of ``chain`` at readings ``q`` (n,), for the self-check."""
    T = np.eye(4)
    k = 0
    for j in chain:
        T = T @ j.origin
        if j.kind in _MOVING:
            M = np.eye(4)
            if _MOVING[j.kind] is JointType.REVOLUTE:
                w = j.axis * q[k]
                theta = np.linalg.norm(w)
                if theta > 0:
                    K = np.array([[0, -j.axis[2], j.axis[1]], [j.axis[2], 0, -j.axis[0]], [-j.axis[1], j.axis[0], 0]])
                    M[:3, :3] = np.eye(3) + np.sin(q[k]) * K + (1 - np.cos(q[k])) * K @ K
            else:
                M[:3, 3] = j.axis * q[k]
            T = T @ M
            k += 1
    return T


def _check_same_kinematics(model: RobotModel, chain, source: str) -> None:
    """The rebuilt chain must reproduce the URDF at a few joint sets: a failure is a bug, say so."""
    rng = np.random.default_rng(0)
    lo, hi = model.joint_limits[:, 0], model.joint_limits[:, 1]
    q = rng.uniform(np.maximum(lo, -np.pi), np.minimum(hi, np.pi), size=(5, model.n_joints))
    ours = model.forward(model.nominal, q)
    for qi, Ti in zip(q, ours):
        if not np.allclose(_urdf_forward(chain, qi), Ti, atol=1e-6):
            raise ModelError(f"{source}: internal error: the converted chain does not reproduce the URDF")


def load_urdf_model(path, base: str | None = None, tip: str | None = None) -> RobotModel:
    """Read a URDF file (a regular file of at most 20 MB) and convert the chain ``base`` -> ``tip``."""
    path = Path(path)
    text = read_text_file(path, ModelError, MAX_URDF_BYTES)
    return model_from_urdf(text, source=str(path), base=base, tip=tip, name=path.stem)
