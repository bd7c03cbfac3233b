"""An independent implementation of DESIGN.md section 1 with plain 4x4 matrices, for tests."""
import math

import numpy as np


def Rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def Ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s, 0], [0, 1, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1.0]])


def Rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def Trans(x, y, z):
    T = np.eye(4)
    T[:3, 3] = [x, y, z]
    return T


def euler(p, deg=True):
    """p: dict phi, theta, psi (deg), px, py, pz (mm)."""
    f = math.radians if deg else (lambda v: v)
    return Rz(f(p["phi"])) @ Ry(f(p["theta"])) @ Rx(f(p["psi"])) @ Trans(p["px"], p["py"], p["pz"])


def link(q_deg, row):
    """Rz(q + theta) Tz(d) Tx(a) Rx(alpha) Ry(beta), row in mm/deg."""
    r = math.radians
    return (Rz(r(q_deg + row.get("theta", 0))) @ Trans(0, 0, row.get("d", 0)) @ Trans(row.get("a", 0), 0, 0)
            @ Rx(r(row.get("alpha", 0))) @ Ry(r(row.get("beta", 0))))


def fk(base, links, tool, q_deg):
    """T = A_b A_1 ... A_n [Rz(q_6) when 5 links] A_t with everything in mm/deg."""
    T = euler(base)
    for i, row in enumerate(links):
        T = T @ link(q_deg[i], row)
    if len(links) == 5:
        T = T @ Rz(math.radians(q_deg[5]))
    return T @ euler(tool)


def fk_from_truth(truth: dict, q_deg):
    """FK from a truth.yaml parameter dict {name: value} (mm, deg) with all 37 slots."""
    base = {f: truth[f"base.{f}"] for f in ("phi", "theta", "psi", "px", "py", "pz")}
    tool = {f: truth[f"tool.{f}"] for f in ("phi", "theta", "psi", "px", "py", "pz")}
    links = [{f: truth[f"j{n}.{f}"] for f in ("theta", "d", "a", "alpha", "beta")} for n in range(1, 6)]
    return fk(base, links, tool, q_deg)
