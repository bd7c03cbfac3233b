"""Ballbar lengths: a telescoping bar between a tool ball and a fixed pivot whose position is unknown.

File ``distances.csv``: ``pose,ball,length`` (mm, centre to centre), one row per pose and ball. The
dataset's world origin is the pivot (its position is estimated through the base transform).
Error: ``|FK(theta, q) offset| - length`` (mm, 1 row), :func:`factors.errors.distance_error`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgcal.errors import DatasetError
from fgcal.measurements.base import KinematicMeasurement, NoiseComponent, ObservationRows, Terms
from fgcal.measurements.cells import ball_name, number
from fgcal.robots.kinematics import tool_points

__all__ = ["DISTANCE", "DistanceMeasurement", "DistanceObservations"]


@dataclass
class DistanceObservations(ObservationRows):
    """Measured distances (mm), one row each: a telescoping ballbar between a tool ball and a fixed
    pivot whose position is unknown. The dataset's world frame has its origin at the pivot.

    Attributes
    ----------
    pose : ndarray of int, shape (M,)
    ball : ndarray of str, shape (M,)
        The tool ball at the bar's moving end.
    length : ndarray, shape (M,)
        Centre-to-centre length of the bar (mm).
    line : ndarray of int, shape (M,)
    """

    pose: np.ndarray
    ball: np.ndarray
    length: np.ndarray
    line: np.ndarray | None = None

    ROW_SHAPES = {"length": ()}


class DistanceMeasurement(KinematicMeasurement):
    """A ballbar length from the world origin (the pivot) to a tool ball: 1 row (mm)."""

    level = "distances"
    file = "distances.csv"
    columns = ("pose", "ball", "length")
    width = 1
    per_ball = True
    title = "ballbar lengths"
    noun = "length"
    noise_components = (NoiseComponent("distances", slice(0, 1), "distance"),)

    def error(self, theta, q, data, index, held, chain):
        from factors.errors import distance_error

        offset, length = data
        return distance_error(theta, q, offset, length, index, held, chain)

    def sigma(self, sigmas) -> np.ndarray:
        return np.array([sigmas.distance])

    def terms(self, obs: DistanceObservations, tooling, row_of_pose) -> Terms:
        pose = np.array([row_of_pose[p] for p in obs.pose.tolist()], dtype=int)
        return Terms(pose, (tooling.offsets(obs.ball).reshape(-1, 3), obs.length))

    def design_data(self, forward, offsets) -> tuple:
        return (offsets, np.linalg.norm(tool_points(forward, offsets[:, None, :])[:, 0], axis=1))

    def simulate(self, T, offsets, rng, noise) -> np.ndarray:
        sd = noise.distance_sigma if noise.distance_sigma is not None else noise.cmm_sigma
        length = np.linalg.norm(tool_points(T, offsets[:, None, :])[:, 0], axis=1)
        return (length + rng.normal(size=len(length)) * sd)[:, None]

    def parse(self, where, record, balls):
        b = ball_name(record["ball"], where, balls)
        value = number(record["length"], where, "length")
        if value <= 0:
            raise DatasetError(f"{where}: length must be positive (mm), got {value!r}")
        return b, np.array([value])

    def observations(self, pose, ball, values, line=None):
        return DistanceObservations(pose, ball, np.asarray(values, dtype=float).reshape(-1), line)

    def rows(self, obs: DistanceObservations):
        return ([int(p), b, float(v)] for p, b, v in zip(obs.pose, obs.ball, obs.length))

    def metric(self, e):
        return np.abs(np.asarray(e)[:, 0]), None

    def residual_summary(self, e) -> dict:
        return {"distances_mm": np.asarray(e)[:, 0].tolist()}


DISTANCE = DistanceMeasurement()
