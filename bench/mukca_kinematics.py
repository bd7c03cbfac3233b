"""The URDF chain, forward kinematics and URDF output of the MUKCa baseline (``bench/mukca_baseline.py``):
the joints from a root link to a tip link as plain dicts, the ball centre with its Jacobian in each
joint's <origin> (x, y, z, roll, pitch, yaw), and the URDF with calibrated origins. Standalone: numpy only.
"""
import os
import xml.etree.ElementTree as ET

import numpy as np

ROOT_LINK = "panda_link0"
TIP_LINK = "ball_link"


# --------------------------------------------------------------------- URDF
def _floats(text, default):
    return [float(v) for v in text.split()] if text else list(default)


def parse_chain(urdf_path, root=ROOT_LINK, tip=TIP_LINK):
    """The joints from root to tip, in order, as plain dicts."""
    tree = ET.parse(urdf_path)
    by_child = {}
    for j in tree.getroot().findall("joint"):
        origin = j.find("origin")
        axis = j.find("axis")
        by_child[j.find("child").get("link")] = {
            "name": j.get("name"),
            "type": j.get("type"),
            "parent": j.find("parent").get("link"),
            "xyz": _floats(origin.get("xyz") if origin is not None else None, (0, 0, 0)),
            "rpy": _floats(origin.get("rpy") if origin is not None else None, (0, 0, 0)),
            "axis": _floats(axis.get("xyz") if axis is not None else None, (1, 0, 0)),
        }
    chain, link = [], tip
    while link != root:
        if link not in by_child:
            raise ValueError(f"{tip} is not below {root} in {urdf_path}")
        chain.append(by_child[link])
        link = by_child[link]["parent"]
    chain.reverse()
    for j in chain:
        if j["type"] not in ("revolute", "continuous", "fixed"):
            raise ValueError(f"joint type {j['type']} of {j['name']} not handled")
    return chain


def nominal_params(urdf_path):
    """Parameter dict for the nominal URDF (the format calibrate_mukca returns)."""
    chain = parse_chain(urdf_path)
    return {
        "urdf": os.path.abspath(urdf_path),
        "chain": chain,
        "origins": {j["name"]: list(j["xyz"]) + list(j["rpy"]) for j in chain},
        "optimised": [],
    }


# ----------------------------------------------------------------------- FK
def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _axis_angle(axis, q):
    """Rotation matrices (N,3,3) about a unit axis by angles q (N,)."""
    k = np.asarray(axis, float)
    k = k / np.linalg.norm(k)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    s, c = np.sin(q)[:, None, None], np.cos(q)[:, None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def fk(params, Q, jac_joints=()):
    """Ball centres (N,3) in metres for joint sets Q (N,7), in the root frame.

    With jac_joints, also d(centre)/d(x,y,z,roll,pitch,yaw) of each named
    joint's origin: array (N, 3, 6*len(jac_joints)).
    """
    Q = np.atleast_2d(np.asarray(Q, float))
    n = Q.shape[0]
    R = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    p = np.zeros((n, 3))
    frames = {}          # joint name -> (R, p, Rz, Ry, t) of the frame before its origin
    qi = 0
    for j in params["chain"]:
        o = params["origins"][j["name"]]
        t, (r_, p_, y_) = np.asarray(o[:3]), o[3:]
        Rz, Ry, Rx = _rz(y_), _ry(p_), _rx(r_)
        if j["name"] in jac_joints:
            frames[j["name"]] = (R.copy(), p.copy(), Rz, Ry, t)
        p = p + R @ t
        R = R @ (Rz @ Ry @ Rx)
        if j["type"] != "fixed":
            R = R @ _axis_angle(j["axis"], Q[:, qi])
            qi += 1
    if not jac_joints:
        return p
    J = np.zeros((n, 3, 6 * len(jac_joints)))
    ex, ey, ez = np.eye(3)
    for k, name in enumerate(jac_joints):
        A, a, Rz, Ry, t = frames[name]
        # s = R_origin u: the centre relative to the origin's translated point,
        # expressed in the parent frame
        s = np.einsum("nji,nj->ni", A, p - a) - t
        J[:, :, 6 * k:6 * k + 3] = A
        d_yaw = np.cross(ez, s)
        d_pitch = np.cross(ey, s @ Rz) @ Rz.T
        d_roll = np.cross(ex, s @ (Rz @ Ry)) @ (Rz @ Ry).T
        for c, d in ((3, d_roll), (4, d_pitch), (5, d_yaw)):
            J[:, :, 6 * k + c] = np.einsum("nij,nj->ni", A, d)
    return p, J


# -------------------------------------------------------------------- write
def write_urdf(params, out_path):
    """The URDF with the calibrated origins written in (like the authors' output)."""
    tree = ET.parse(params["urdf"])
    for j in tree.getroot().findall("joint"):
        if j.get("name") in params.get("optimised", []):
            o = params["origins"][j.get("name")]
            origin = j.find("origin")
            origin.set("xyz", " ".join(repr(v) for v in o[:3]))
            origin.set("rpy", " ".join(repr(v) for v in o[3:]))
    tree.write(out_path, xml_declaration=True, encoding="utf-8")
