"""What set-up blocks' entries mean in space (DESIGN.md 8.1, 8.3, 8.4): frames, plane normals, distances.

A station's (and a camera's or target's mount) orientation is ``Rz(phi) Ry(theta) Rx(psi)``
(:func:`zyx_rotation`, with its derivatives for the analytic Jacobians). A plane's normal is
parametrised about a reference normal ``n0`` (the given normal, else the start's fit) by two
tilts: ``n = normalise(n0 + tan(tilt_u) u + tan(tilt_v) v)`` with ``u, v`` orthonormal to ``n0``
(:func:`plane_basis`), so the parameters are free of the singularities of angle pairs. A known
distance between two fixture points is a residual ``|a - b| - distance``. Units: mm and rad.
No I/O here.
"""
from __future__ import annotations

import numpy as np

from fgcal.robots.transforms import rot

__all__ = ["distance_error", "plane_basis", "plane_normal", "station_transform", "zyx_rotation"]


def zyx_rotation(phi: float, theta: float, psi: float) -> tuple[np.ndarray, np.ndarray]:
    """``R = Rz(phi) Ry(theta) Rx(psi)`` (3, 3) and ``dR`` (3, 3, 3): its derivatives by phi, theta, psi (per rad)."""
    Rz, Ry, Rx = rot(2, phi), rot(1, theta), rot(0, psi)
    dR = np.stack([_rot_derivative(2, phi) @ Ry @ Rx, Rz @ _rot_derivative(1, theta) @ Rx,
                   Rz @ Ry @ _rot_derivative(0, psi)])
    return Rz @ Ry @ Rx, dR


def station_transform(entries) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A station's ``R`` (3, 3), ``p`` (3,) with ``T x = R (x + p)``, and ``dR`` (3, 3, 3) by phi, theta, psi."""
    R, dR = zyx_rotation(*entries[:3])
    return R, np.asarray(entries[3:6], dtype=float), dR


def distance_error(a, b, distance: float) -> tuple[float, np.ndarray]:
    """``|a - b| - distance`` (mm) of two points (3,) and its gradient in ``a`` (3,) (``-`` it in ``b``)."""
    diff = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    dist = float(np.linalg.norm(diff))
    return dist - float(distance), diff / max(dist, 1e-300)


def _rot_derivative(axis: int, angle: float) -> np.ndarray:
    """d/dangle of :func:`fgcal.robots.transforms.rot` (3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    D = np.zeros((3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    D[i, i] = D[j, j] = -s
    D[i, j] = -c
    D[j, i] = c
    return D


def plane_basis(n0) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors ``u, v`` orthonormal to the unit normal ``n0`` (a fixed, deterministic choice)."""
    n0 = np.asarray(n0, dtype=float)
    helper = np.eye(3)[int(np.argmin(np.abs(n0)))]
    u = np.cross(n0, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(n0, u)


def plane_normal(n0, tilts) -> tuple[np.ndarray, np.ndarray]:
    """The unit normal for tilts ``(tilt_u, tilt_v)`` (rad) about ``n0``, and ``dn/dtilt`` (3, 2)."""
    u, v = plane_basis(n0)
    tu, tv = np.tan(tilts[0]), np.tan(tilts[1])
    m = np.asarray(n0, dtype=float) + tu * u + tv * v
    norm = np.linalg.norm(m)
    n = m / norm
    dm = np.column_stack([u / np.cos(tilts[0]) ** 2, v / np.cos(tilts[1]) ** 2])
    return n, (np.eye(3) - np.outer(n, n)) @ dm / norm
