"""A measurement type of your own: a height gauge that reads the z coordinate of a tool ball.

A kinematic measurement type is one class (:class:`fgcal.measurements.base.KinematicMeasurement`)
that says, once, everything about it: its level and file, its columns and their parsing, its
error with Jacobians, its sigma, how it is simulated and verified. Registered with
:func:`fgcal.measurements.types.register`, it is read and written with the dataset, simulated,
solved in the batch graph with its own estimated noise, and verified, with no edit to fgcal.

Run: ``python examples/custom_measurement_type.py [WORKDIR]``.
"""
from __future__ import annotations

import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import fgcal
from fgcal.measurements import types
from fgcal.measurements.base import KinematicMeasurement, NoiseComponent, ObservationRows, Terms
from fgcal.measurements.cells import ball_name, number
from fgcal.robots.kinematics import tool_points

GAUGE_NOISE = 0.03  # mm: what the simulated gauge really scatters (the dataset declares 0.01)


@dataclass
class HeightObservations(ObservationRows):
    """Rows of ``heights.csv``: pose, ball, z (mm)."""

    pose: np.ndarray
    ball: np.ndarray
    z: np.ndarray
    line: np.ndarray | None = None

    ROW_SHAPES = {"z": ()}  # the protocol's class attribute: the shape of a row of each field


class HeightMeasurement(KinematicMeasurement):
    """The world z (mm) of a tool ball's centre, as a height gauge reads it."""

    level = "heights"
    file = "heights.csv"
    columns = ("pose", "ball", "z")
    width = 1  # error rows per observation
    per_ball = True
    title = "ball heights"
    noun = "height"
    noise_components = (NoiseComponent("heights", slice(0, 1), "height"),)

    def error(self, theta, q, data, index, held, chain):
        """Predicted minus measured z (mm) and its Jacobians in the parameters and the joints."""
        from factors.errors import ball_centre_error

        offset, z = data
        p, J_t, J_q = ball_centre_error(theta, q, offset, np.zeros((len(z), 3)), index, held, chain)
        return p[:, 2:3] - np.asarray(z, dtype=float).reshape(-1, 1), J_t[:, 2:3], J_q[:, 2:3]

    def declared_sigmas(self, noise):
        return {"height": noise.cmm_sigma}

    def sigma(self, sigmas):
        return np.array([sigmas.height])

    def terms(self, obs, tooling, row_of_pose):
        return Terms(np.array([row_of_pose[p] for p in obs.pose.tolist()], dtype=int),
                     (tooling.offsets(obs.ball).reshape(-1, 3), obs.z))

    def design_data(self, forward, offsets):
        return offsets, tool_points(forward, offsets[:, None, :])[:, 0, 2]

    def simulate(self, T, offsets, rng, noise):
        z = tool_points(T, offsets[:, None, :])[:, 0, 2]
        return (z + rng.normal(size=len(z)) * GAUGE_NOISE)[:, None]

    def parse(self, where, record, balls):
        return ball_name(record["ball"], where, balls), np.array([number(record["z"], where, "z")])

    def observations(self, pose, ball, values, line=None):
        return HeightObservations(pose, ball, np.asarray(values, dtype=float).reshape(-1), line)

    def rows(self, obs):
        return ([int(p), b, float(z)] for p, b, z in zip(obs.pose, obs.ball, obs.z, strict=True))

    def metric(self, e):
        return np.abs(np.asarray(e)[:, 0]), None

    def residual_summary(self, e):
        return {"heights_mm": np.asarray(e)[:, 0].tolist()}


def main(work: Path) -> int:
    gauge = HeightMeasurement()
    types.register(gauge)
    try:
        # A PUMA 560 measured by a CMM (ball centres) and by the gauge (heights), exact joint readings.
        data = fgcal.simulate("puma560", poses=30, seed=3, levels="centres,heights", joint_resolution=0.0,
                              out=work / "with-heights", force=True)
        print(f"{data.n_poses} poses: {len(data.centres)} centres, {len(data.heights)} heights "
              f"({(work / 'with-heights' / 'heights.csv').read_text().splitlines()[0]})")
        result = fgcal.calibrate(work / "with-heights")
        heights = result.noise["heights"]
        print(f"height gauge noise: declared {heights.declared:.3g} mm, estimated {heights.used:.3g} mm "
              f"(simulated {GAUGE_NOISE})")
        truth = np.array([data.truth[n] for n in result.names])
        z = (result.estimate - truth) / result.sigma
        print(f"estimates against the simulated truth: RMS {np.sqrt(np.mean(z ** 2)):.2f} sigma "
              f"over {len(z)} parameters")
        ok = abs(heights.used / GAUGE_NOISE - 1) < 0.3 and np.sqrt(np.mean(z ** 2)) < 2.0
    finally:
        types.unregister(gauge)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="fgcal-example-"))))
