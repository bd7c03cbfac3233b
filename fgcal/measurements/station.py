"""Ball centres or reflector positions measured from another instrument station (DESIGN.md 8.3).

A ``station`` column in ``joints.csv`` names the station each pose was measured from; ``stations:``
in ``dataset.yaml`` lists them, the first being the world frame. A centre measured from station
``B`` is in B's frame; B's frame in the world (``station.B.phi ... pz``) is a set-up block
(:mod:`fgcal.measurements.setup`). The dataset keeps those rows of ``centres.csv`` as the level
``station_centres`` (the world station's stay ``centres``): 3 rows ``FK offset - T_B m`` (mm) with
``T_B m = R (m + p)`` as :func:`~fgcal.measurements.setup.station_transform` gives it. No I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from fgcal.errors import FgcalError
from fgcal.measurements.base import NoiseComponent, ObservationRows, Terms
from fgcal.measurements.contact import SetupMeasurement
from fgcal.measurements.posefit import rigid_fit
from fgcal.measurements.setup import station_transform
from fgcal.robots.kinematics import tool_points
from fgcal.robots.transforms import to_euler_zyx_trans

__all__ = ["STATION_POINT", "StationPoint", "StationPointObservations"]


@dataclass
class StationPointObservations(ObservationRows):
    """Centres measured from a station other than the world's: pose (M,), ball (M,), xyz (M, 3) mm in
    the station's frame, station (M,) names, line (M,)."""

    pose: np.ndarray
    ball: np.ndarray
    xyz: np.ndarray
    station: np.ndarray
    line: np.ndarray | None = None

    ROW_SHAPES = {"xyz": (3,)}

    def __post_init__(self):
        self.station = np.asarray(self.station, dtype=str).reshape(-1)
        super().__post_init__()


class StationPoint(SetupMeasurement):
    """A ball centre measured from a station: 3 rows ``FK offset - T_station m`` (mm)."""

    level = "station_centres"
    file = "centres.csv"
    columns = ("pose", "ball", "x", "y", "z")
    width = 3
    title = "ball centres from other stations"
    noun = "centre"
    fixture_type = "station"
    noise_key = None
    sigma_field = "station_centre"
    noise_components = (NoiseComponent("station_centres", slice(0, 3), "station_centre"),)
    derived = True  # split from centres.csv by the poses' stations, not read from a file of its own

    def declared_sigmas(self, noise) -> dict:
        # the same instrument as the world station's: its declared noise (estimated apart)
        return {self.sigma_field: float(noise.centre_sigma if noise.centre_sigma is not None else noise.cmm_sigma)}

    def blocks_of(self, obs) -> np.ndarray:
        return obs.station

    def block_starts(self, obs, T, tooling, unknown, where) -> dict:
        """Each unknown station by a rigid fit of its measured centres to those predicted at ``T``."""
        pred = tool_points(T, tooling.offsets(obs.ball)[:, None, :])[:, 0]
        out = {}
        for name in dict.fromkeys(obs.station.tolist()):
            if name not in unknown:
                continue
            sel = obs.station == name
            if sel.sum() < 3 or np.linalg.matrix_rank(obs.xyz[sel] - obs.xyz[sel].mean(0), tol=1e-6) < 2:
                raise FgcalError(f"{where}: station {name} needs three or more centres not on one line "
                                 f"(it has {int(sel.sum())})")
            fit = rigid_fit(obs.xyz[sel], pred[sel], sigma=1.0)  # the station's frame in the world
            try:
                out[name] = to_euler_zyx_trans(fit.T)
            except ValueError:
                raise FgcalError(f"{where}: station {name} is turned by 90 deg about y: its angles are "
                                 "singular (give it a start pose in stations:)") from None
        return out

    def terms(self, obs: StationPointObservations, tooling, row_of_pose, layout=None) -> Terms:
        pose = np.array([row_of_pose[p] for p in obs.pose.tolist()], dtype=int)
        start = np.array([layout.offset[s] for s in obs.station.tolist()], dtype=int)
        return Terms(pose, (tooling.offsets(obs.ball).reshape(-1, 3), obs.xyz, start))

    def setup_error(self, theta, q, data, s, index, held, chain):
        offset, xyz, start = data
        p_fk, J_t, J_q = self._ball_points(theta, q, offset, index, held, chain)
        m = len(start)
        e = np.empty((m, 3))
        J_s = np.empty((m, 3, 6))
        for k in np.unique(start):
            rows = np.nonzero(start == k)[0]
            R, p, dR = station_transform(s[k:k + 6])
            # a design's noiseless centre (xyz None) is where the station sees the predicted one
            local = xyz[rows] + p if xyz is not None else p_fk[rows] @ R
            e[rows] = p_fk[rows] - local @ R.T
            J_s[rows, :, :3] = -np.einsum("aij,nj->nia", dR, local)
            J_s[rows, :, 3:] = -R
        cols = start[:, None] + np.arange(6)
        return e, J_t, J_q, J_s, cols

    def design_data(self, forward, offsets, fixture=None, setup=None, radius: float = 0.0) -> tuple:
        """The payload of M noiseless centres from the stations ``fixture`` (M,), with the set-up
        vector: ``(offsets, xyz in each station's frame, block starts, s)``; ``forward`` (M, 4, 4)
        the tool poses, ``setup`` the layout (its start: the stations at the geometry designed for).
        Without ``forward`` (the design's information, :mod:`fgcal.studies.design_info`) xyz is None:
        :meth:`setup_error` takes each centre where its station sees the predicted one (error zero,
        the Jacobians of a noiseless measurement there)."""
        if fixture is None or setup is None:
            raise FgcalError("design for centres from several stations needs each pose's station "
                             "(design on the dataset's own poses)")
        fixture = np.asarray(fixture, dtype=str).reshape(-1)
        offsets = np.asarray(offsets, dtype=float).reshape(-1, 3)
        start = np.array([setup.offset[f] for f in fixture.tolist()], dtype=int)
        if forward is None:
            return offsets, None, start, setup.start
        world = tool_points(forward, offsets[:, None, :])[:, 0]
        local = np.empty_like(world)
        for k in np.unique(start):
            rows = start == k
            R, p, _ = station_transform(setup.start[k:k + 6])
            local[rows] = world[rows] @ R - p  # T x = R (x + p): x = R^T w - p
        return offsets, local, start, setup.start

    def observations(self, pose, ball, values, line=None):
        raise NotImplementedError("station centres are split from centres.csv by joints.csv's station column")

    def block_observations(self, pose, ball, block, values) -> StationPointObservations:
        """Centres from the stations ``block`` (M,): pose ids (M,), balls (M,), ``values`` (M, 3) mm in
        each station's frame (as the online engines hold them, :attr:`fgcal.online.records.PoseData.block_rows`)."""
        return StationPointObservations(np.asarray(pose, dtype=int).reshape(-1),
                                        np.asarray(ball, dtype=str).reshape(-1),
                                        np.asarray(values, dtype=float).reshape(-1, 3), block)

    def rows(self, obs: Any):
        return ([int(p), b, *map(float, x)] for p, b, x in zip(obs.pose, obs.ball, obs.xyz))

    def metric(self, e):
        return np.linalg.norm(e, axis=1), None

    def residual_summary(self, e) -> dict:
        return {"station_centres_mm": np.asarray(e).ravel().tolist()}


STATION_POINT = StationPoint()
