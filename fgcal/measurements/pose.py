"""Measured tool poses: a 6-DoF tracker (or three balls fitted to a pose by the instrument).

File ``poses.csv``: ``pose,x,y,z,qw,qx,qy,qz`` (mm; unit quaternion, instrument frame), one row per
pose. Error: ``[log(R_fk R_meas^T) (rad); p_fk - p_meas (mm)]`` (6 rows),
:func:`factors.errors.pose_error`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgcal.errors import DatasetError
from fgcal.measurements.base import KinematicMeasurement, NoiseComponent, ObservationRows, Terms
from fgcal.measurements.cells import number
from fgcal.robots.transforms import matrix_to_quaternion, pose_matrices

__all__ = ["POSE", "PoseMeasurement", "PoseObservations", "small_rotation"]


@dataclass
class PoseObservations(ObservationRows):
    """Measured tool poses (world): position (mm) and unit quaternion ``(qw, qx, qy, qz)``."""

    pose: np.ndarray
    xyz: np.ndarray
    quat: np.ndarray
    line: np.ndarray | None = None

    ROW_SHAPES = {"xyz": (3,), "quat": (4,)}

    def matrices(self) -> np.ndarray:
        """The poses as homogeneous transforms ``(K, 4, 4)`` (mm)."""
        return pose_matrices(self.xyz, self.quat)


def small_rotation(v) -> np.ndarray:
    """The rotation matrix (3, 3) of the rotation vector ``v`` (rad), by Rodrigues' formula."""
    angle = np.linalg.norm(v)
    if angle == 0:
        return np.eye(3)
    k = v / angle
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


_AXES = np.array([[0.0, 0, 0], [100.0, 0, 0], [0, 100.0, 0], [0, 0, 100.0]])  # points that fix a pose


class PoseMeasurement(KinematicMeasurement):
    """A full tool pose: 3 rotation rows (rad) then 3 position rows (mm)."""

    level = "poses"
    file = "poses.csv"
    columns = ("pose", "x", "y", "z", "qw", "qx", "qy", "qz")
    width = 6
    per_ball = False
    title = "tool poses"
    noun = "pose"
    noise_components = (NoiseComponent("poses", slice(3, 6), "pose_position"),
                        NoiseComponent("poses_rotation", slice(0, 3), "pose_rotation", "deg", float(np.degrees(1.0))))

    def error(self, theta, q, data, index, held, chain):
        from factors.errors import pose_error

        return pose_error(theta, q, data[0], index, held, chain)

    def sigma(self, sigmas) -> np.ndarray:
        return np.array([sigmas.pose_rotation] * 3 + [sigmas.pose_position] * 3)

    def reported_sigma(self, sigmas) -> tuple:
        return float(sigmas.pose_position), float(np.degrees(sigmas.pose_rotation))

    def terms(self, obs: PoseObservations, tooling, row_of_pose) -> Terms:
        pose = np.array([row_of_pose[p] for p in obs.pose.tolist()], dtype=int)
        return Terms(pose, (obs.matrices(),))

    def world_points(self, terms: Terms) -> dict:
        return {i: (_AXES, _AXES @ T[:3, :3].T + T[:3, 3]) for i, T in zip(terms.pose.tolist(), terms.data[0])}

    def design_data(self, forward, offsets) -> tuple:
        return (np.asarray(forward, dtype=float),)

    def simulate(self, T, offsets, rng, noise) -> np.ndarray:
        sp = noise.pose_position_sigma or 0.0
        so = np.radians(noise.pose_orientation_sigma or 0.0)
        out = []
        for Tk in np.asarray(T, dtype=float).reshape(-1, 4, 4):  # per pose: rotation, then position
            R = small_rotation(rng.normal(size=3) * so) @ Tk[:3, :3]
            out.append(np.concatenate([Tk[:3, 3] + rng.normal(size=3) * sp, matrix_to_quaternion(R)]))
        return np.array(out).reshape(-1, 7)

    def parse(self, where, record, balls):
        q = np.array([number(record[c], where, c) for c in ("qw", "qx", "qy", "qz")])
        norm = np.linalg.norm(q)
        if abs(norm - 1.0) > 1e-3:
            raise DatasetError(f"{where}: quaternion (qw, qx, qy, qz) has norm {norm:.6g}, expected 1")
        return "", np.concatenate([[number(record[c], where, c) for c in "xyz"], q / norm])

    def observations(self, pose, ball, values, line=None):
        values = np.asarray(values, dtype=float).reshape(-1, 7)
        return PoseObservations(pose, values[:, :3], values[:, 3:], line)

    def rows(self, obs: PoseObservations):
        quat = obs.quat / np.linalg.norm(obs.quat, axis=1, keepdims=True)
        return ([int(p), *map(float, x), *map(float, qq)] for p, x, qq in zip(obs.pose, obs.xyz, quat))

    def metric(self, e):
        return np.linalg.norm(e[:, 3:], axis=1), np.degrees(np.linalg.norm(e[:, :3], axis=1))

    def residual_summary(self, e) -> dict:
        e = np.asarray(e)
        return {"poses_position_mm": e[:, 3:].ravel().tolist(), "poses_rotation_deg": np.degrees(e[:, :3]).ravel().tolist()}


POSE = PoseMeasurement()
