"""Measured points: a ball centre (CMM) or a laser tracker's reflector, position only.

File ``centres.csv``: ``pose,ball,x,y,z`` (mm, instrument frame); one row per pose and ball.
Error: ``FK(theta, q) offset - xyz`` (mm, 3 rows), :func:`factors.errors.ball_centre_error`.
The same observations class carries probe points (:mod:`fgcal.measurements.probe`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgcal.measurements.base import KinematicMeasurement, NoiseComponent, ObservationRows, Terms
from fgcal.measurements.cells import ball_name, number
from fgcal.robots.kinematics import tool_points

__all__ = ["POINT", "PointMeasurement", "PointObservations"]


@dataclass
class PointObservations(ObservationRows):
    """Measured points, one row each: probe points or ball centres (world, mm).

    Attributes
    ----------
    pose : ndarray of int, shape (M,)
    ball : ndarray of str, shape (M,)
    xyz : ndarray, shape (M, 3)
    line : ndarray of int, shape (M,)
        Line in the source file (0 when made in memory), for error messages.
    """

    pose: np.ndarray
    ball: np.ndarray
    xyz: np.ndarray
    line: np.ndarray | None = None

    ROW_SHAPES = {"xyz": (3,)}


class PointMeasurement(KinematicMeasurement):
    """A ball centre or reflector position: 3 rows of ``FK offset - measured`` (mm)."""

    level = "centres"
    file = "centres.csv"
    columns = ("pose", "ball", "x", "y", "z")
    width = 3
    per_ball = True
    title = "ball centres"
    noun = "centre"
    noise_components = (NoiseComponent("centres", slice(0, 3), "centre"),)

    def error(self, theta, q, data, index, held, chain):
        from factors.errors import ball_centre_error

        offset, xyz = data
        return ball_centre_error(theta, q, offset, xyz, index, held, chain)

    def sigma(self, sigmas) -> np.ndarray:
        return np.full(3, sigmas.centre)

    def terms(self, obs: PointObservations, tooling, row_of_pose) -> Terms:
        pose = np.array([row_of_pose[p] for p in obs.pose.tolist()], dtype=int)
        return Terms(pose, (tooling.offsets(obs.ball).reshape(-1, 3), obs.xyz))

    def world_points(self, terms: Terms) -> dict:
        pose = np.asarray(terms.pose)
        offsets, xyz = (np.asarray(a, dtype=float).reshape(-1, 3) for a in terms.data)
        if not len(pose):
            return {}
        # Poses in the order of their first row, each pose's rows in their order: one sort, then
        # views of the sorted arrays (a fancy index per pose: 2.6 ms at 1,000 poses, now 0.36).
        _, first, inverse = np.unique(pose, return_index=True, return_inverse=True)
        order = np.argsort(first[inverse.ravel()], kind="stable")
        poses, offsets, xyz = pose[order].tolist(), offsets[order], xyz[order]
        cuts = (np.flatnonzero(np.diff(pose[order])) + 1).tolist()
        return {int(poses[a]): (offsets[a:z], xyz[a:z]) for a, z in zip([0, *cuts], [*cuts, len(order)])}

    def design_data(self, forward, offsets) -> tuple:
        return (offsets, tool_points(forward, offsets[:, None, :])[:, 0])

    def simulate(self, T, offsets, rng, noise) -> np.ndarray:
        c = tool_points(T, offsets[:, None, :])[:, 0]
        return c + rng.normal(size=c.shape) * noise.cmm_sigma

    def parse(self, where, record, balls):
        b = ball_name(record["ball"], where, balls)
        return b, np.array([number(record[c], where, c) for c in "xyz"])

    def observations(self, pose, ball, values, line=None):
        return PointObservations(pose, ball, np.asarray(values, dtype=float).reshape(-1, 3), line)

    def rows(self, obs: PointObservations):
        return ([int(p), b, *map(float, x)] for p, b, x in zip(obs.pose, obs.ball, obs.xyz))

    def metric(self, e):
        return np.linalg.norm(e, axis=1), None

    def residual_summary(self, e) -> dict:
        return {"centres_mm": np.asarray(e).ravel().tolist()}


POINT = PointMeasurement()
