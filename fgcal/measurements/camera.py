"""Cameras and calibration targets as set-up blocks, and the pinhole projection (DESIGN.md 8.4).

A camera block ``camera.NAME.*`` holds 15 entries: the mount pose ``px, py, pz`` (mm), ``phi,
theta, psi`` (rad inside, deg in files) with ``T = Trans(px, py, pz) Rz(phi) Ry(theta) Rx(psi)``
(the camera frame in the world for ``mount: world``, in the tool frame for ``mount: tool``), then
the intrinsics ``fx, fy, cx, cy`` (px) and OpenCV's distortion ``k1, k2, p1, p2, k3``. Only the
intrinsics named in ``estimate:`` are free. A target block ``target.NAME.*`` holds its pose (6
entries, the same convention): the target frame in the tool frame (``mount: tool``) or in the world.

The camera frame has x right, y down, z along the optical axis (OpenCV's); pixels have u right,
v down and the origin at the centre of the top-left pixel (OpenCV's convention). No I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fgcal.measurements.setup import FixtureSpec
from fgcal.measurements.setup_geometry import zyx_rotation

__all__ = [
    "CAMERA_SIZE",
    "INTRINSICS",
    "MOUNT",
    "CameraSpec",
    "TargetSpec",
    "mount_transform",
    "pose_matrix",
    "project",
]

MOUNT = ("px", "py", "pz", "phi", "theta", "psi")
INTRINSICS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
CAMERA_SIZE = len(MOUNT) + len(INTRINSICS)


def mount_transform(entries) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``R`` (3, 3), ``t`` (3,) of ``T = Trans(t) Rz(phi) Ry(theta) Rx(psi)`` and ``dR`` (3, 3, 3) by
    phi, theta, psi, from the entries ``[px, py, pz, phi, theta, psi]`` (mm, rad)."""
    e = np.asarray(entries, dtype=float)
    R, dR = zyx_rotation(*e[3:6])
    return R, e[:3].copy(), dR


def pose_matrix(entries) -> np.ndarray:
    """The 4x4 transform of mount-pose entries (mm, rad)."""
    R, t, _ = mount_transform(entries)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def pose_entries(T) -> np.ndarray:
    """``[px, py, pz, phi, theta, psi]`` (..., 6) (mm, rad) of 4x4 transforms (..., 4, 4) (ZYX angles;
    theta in [-90, 90] deg)."""
    T = np.asarray(T, dtype=float)
    R = T[..., :3, :3]
    theta = -np.arcsin(np.clip(R[..., 2, 0], -1.0, 1.0))
    phi = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    psi = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    return np.concatenate([T[..., :3, 3], np.stack([phi, theta, psi], axis=-1)], axis=-1)


def project(Xc, k) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pinhole projection with OpenCV's distortion of camera-frame points.

    Parameters
    ----------
    Xc : array_like, shape (M, 3)
        Points in the camera frame (mm); ``Z > 0`` in front of the camera.
    k : array_like, shape (M, 9) or (9,)
        ``fx, fy, cx, cy`` (px), ``k1, k2, p1, p2, k3``.

    Returns
    -------
    uv : ndarray, shape (M, 2)
        Pixels (u right, v down, origin at the centre of the top-left pixel).
    J_X : ndarray, shape (M, 2, 3)
        d uv / d Xc (px/mm).
    J_k : ndarray, shape (M, 2, 9)
        d uv / d intrinsics.
    """
    Xc = np.atleast_2d(np.asarray(Xc, dtype=float))
    k = np.broadcast_to(np.asarray(k, dtype=float), (len(Xc), 9))
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = k.T
    X, Y, Z = Xc.T
    x, y = X / Z, Y / Z
    r2 = x * x + y * y
    rad = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    drad = k1 + r2 * (2 * k2 + 3 * k3 * r2)
    xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    uv = np.column_stack([fx * xd + cx, fy * yd + cy])
    dxd_dx = rad + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x
    dxd_dy = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y
    dyd_dx = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y
    dyd_dy = rad + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x
    # d(x, y)/d(X, Y, Z)
    dn = np.zeros((len(Xc), 2, 3))
    dn[:, 0, 0] = 1 / Z
    dn[:, 0, 2] = -x / Z
    dn[:, 1, 1] = 1 / Z
    dn[:, 1, 2] = -y / Z
    dd = np.empty((len(Xc), 2, 2))
    dd[:, 0, 0], dd[:, 0, 1] = fx * dxd_dx, fx * dxd_dy
    dd[:, 1, 0], dd[:, 1, 1] = fy * dyd_dx, fy * dyd_dy
    J_X = dd @ dn
    J_k = np.zeros((len(Xc), 2, 9))
    J_k[:, 0, 0], J_k[:, 1, 1] = xd, yd
    J_k[:, 0, 2], J_k[:, 1, 3] = 1.0, 1.0
    r4 = r2 * r2
    J_k[:, 0, 4], J_k[:, 1, 4] = fx * x * r2, fy * y * r2
    J_k[:, 0, 5], J_k[:, 1, 5] = fx * x * r4, fy * y * r4
    J_k[:, 0, 6], J_k[:, 1, 6] = fx * 2 * x * y, fy * (r2 + 2 * y * y)
    J_k[:, 0, 7], J_k[:, 1, 7] = fx * (r2 + 2 * x * x), fy * 2 * x * y
    J_k[:, 0, 8], J_k[:, 1, 8] = fx * x * r4 * r2, fy * y * r4 * r2
    return uv, J_X, J_k


@dataclass(frozen=True)
class CameraSpec(FixtureSpec):
    """One camera of ``dataset.yaml``'s ``cameras:`` (a set-up block of type ``camera``).

    Attributes
    ----------
    mount : {"world", "tool"}
        Fixed in the instrument frame (eye-to-hand) or on the tool (eye-in-hand).
    width, height : int
        The image's size (px).
    intrinsics : ndarray, shape (9,)
        ``fx, fy, cx, cy, k1, k2, p1, p2, k3``: known values, or the start of those estimated.
    estimate : tuple of str
        The intrinsics estimated (the others are known).
    pixel_sigma : float
        Noise of a corner's pixel coordinates (px).
    start_pose : ndarray or None
        ``mount_pose:`` (mm, rad) given as a start only; ``value`` holds all 15 entries when the
        mount is known (``fixed``) or a prior (``sigma``).
    """

    mount: str = "world"
    width: int = 0
    height: int = 0
    intrinsics: np.ndarray = field(default_factory=lambda: np.zeros(9))
    estimate: tuple = ()
    pixel_sigma: float = 0.5
    start_pose: np.ndarray | None = None

    def entries_free(self, size: int) -> list:
        mount_free = not self.fixed
        return [mount_free] * len(MOUNT) + [c in self.estimate for c in INTRINSICS]

    def entries_prior_sigma(self, kind) -> np.ndarray:
        sig = np.full(CAMERA_SIZE, np.inf)
        if self.sigma is not None and self.value is not None:
            sig[:6] = np.where(kind.angles[:6], self.sigma / 1000.0, self.sigma)
        return sig

    def to_dict(self) -> dict:
        out: dict = {"type": "camera", "mount": self.mount, "width": int(self.width), "height": int(self.height),
                     "intrinsics": {c: float(v) for c, v in zip(INTRINSICS, self.intrinsics, strict=False)},
                     "estimate": list(self.estimate), "pixel_sigma": float(self.pixel_sigma)}
        return _with_mount(out, self.value[:6] if self.value is not None else self.start_pose, self)


def _with_mount(out: dict, pose, spec) -> dict:
    """``out`` (a camera's or target's ``dataset.yaml`` entry) with its ``mount_pose`` (``pose``
    (6,) mm, rad, written mm, deg) and ``spec``'s ``sigma`` and ``fixed``, where they are given."""
    if pose is not None:
        out["mount_pose"] = [float(v) for v in pose[:3]] + [float(v) for v in np.degrees(pose[3:6])]
    return {**out, **spec.prior_entries()}


@dataclass(frozen=True)
class TargetSpec(FixtureSpec):
    """One target of ``targets:`` (a set-up block of type ``target``).

    Attributes
    ----------
    mount : {"tool", "world"}
        Carried by the robot (eye-to-hand) or fixed in the world (eye-in-hand).
    points : dict
        Point name -> its position (3,) in the target frame (mm).
    start_pose : ndarray or None
        ``mount_pose:`` (mm, rad) given as a start only.
    """

    mount: str = "tool"
    points: dict = field(default_factory=dict)
    start_pose: np.ndarray | None = None

    @property
    def planar(self) -> bool:
        z = np.array([p[2] for p in self.points.values()]) if self.points else np.zeros(1)
        return bool(np.all(np.abs(z) < 1e-9))

    def to_dict(self) -> dict:
        out: dict = {"type": "target", "mount": self.mount,
                     "points": {n: [float(v) for v in p] for n, p in self.points.items()}}
        return _with_mount(out, self.value if self.value is not None else self.start_pose, self)
