"""A calibration dataset in memory: joint readings and measurements at three levels.

See DESIGN.md section 3 for the files. Here everything is in file units (mm, deg) as read;
conversion to internal units happens where the maths needs it. No I/O here (see
:mod:`fgcal.io.dataset_io`).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fgcal.measurements.contact import ContactObservations
from fgcal.measurements.distance import DistanceObservations
from fgcal.measurements.pixels import PixelObservations
from fgcal.measurements.point import PointObservations
from fgcal.measurements.pose import PoseObservations
from fgcal.measurements.setup import SetupSpec
from fgcal.measurements.station import StationPointObservations
from fgcal.measurements.types import LEVELS, all_levels
from fgcal.robots.model import Tooling

__all__ = ["FORMAT", "LEVELS", "Dataset", "DistanceObservations", "Noise", "PointObservations", "PoseObservations"]

FORMAT = "fgcal-dataset/1"


@dataclass(frozen=True)
class Noise:
    """Measurement noise of a dataset.

    Attributes
    ----------
    cmm_sigma : float
        Standard deviation of each coordinate of a measured point (mm).
    joint_resolution : float
        Resolution the joint readings are rounded to (deg); 0 for exact readings.
    repeatability : float
        Standard deviation of the joints' landing error not seen by the readings (deg).
    pose_position_sigma, pose_orientation_sigma : float or None
        Noise of a measured pose (mm, deg), when ``poses.csv`` is given.
    centre_sigma : float or None
        Noise of each coordinate of a ball centre (mm) when centres were fitted to probe points
        rather than measured directly; ``cmm_sigma`` applies when it is None.
    distance_sigma : float or None
        Noise of a ballbar length (mm); ``cmm_sigma`` applies when it is None.
    extra : tuple of (str, float)
        Noise keys declared by measurement types beyond the built-in ones
        (:attr:`fgcal.measurements.base.KinematicMeasurement.noise_key`), such as ``contact_sigma``
        (mm): the seating error per axis of a ball in a fixture or on a plane.
    """

    cmm_sigma: float = 0.01
    joint_resolution: float = 0.01
    repeatability: float = 0.0
    pose_position_sigma: float | None = None
    pose_orientation_sigma: float | None = None
    centre_sigma: float | None = None
    distance_sigma: float | None = None
    extra: tuple = ()

    def items(self) -> dict:
        """The noise as ``dataset.yaml`` writes it: the given fields and the extra keys."""
        out = {k: v for k, v in vars(self).items() if k != "extra" and v is not None}
        out.update({k: v for k, v in self.extra if v is not None})
        return out

    @property
    def joint_sigma_deg(self) -> float:
        """Standard deviation of a joint reading (deg): rounding (res / sqrt 12) and repeatability."""
        return float(np.hypot(self.joint_resolution / np.sqrt(12.0), self.repeatability))


@dataclass
class Dataset:
    """Joint readings of N poses and whatever was measured at them.

    Attributes
    ----------
    robot : str
        Built-in model name, or a model file path (relative paths are relative to the dataset).
    tooling : Tooling
    noise : Noise
    provenance : dict
        Free-form: where the data came from (simulator settings, instrument, date, ...).
    pose_ids : ndarray of int, shape (N,)
    joints_deg : ndarray, shape (N, n)
        Joint readings as the controller gave them (deg).
    probes, centres : PointObservations or None
    poses : PoseObservations or None
    distances : DistanceObservations or None
        Ballbar lengths (distances.csv); the world origin is the pivot.
    contacts, plane_contacts : ContactObservations or None
        The tool ball at a fixture point, or on a plane (both in contacts.csv).
    station_centres : StationPointObservations or None
        Centres measured from a station other than the world's (DESIGN.md 8.3).
    pixels : PixelObservations or None
        Target points seen by cameras (``pixels.csv``, DESIGN.md 8.4).
    setup : SetupSpec
        The set-up's fixtures, stations and known distances (``fixtures:``, ``stations:``,
        ``constraints:``); a station's block has type ``station``.
    stations : ndarray of str, shape (N,), or None
        The station each pose was measured from (``joints.csv``'s ``station`` column).
    world_station : str or None
        The first of ``stations:``: the world frame.
    truth : dict of str to float or None
        True parameter values (mm, deg) of a simulated robot; all 37 slots.
    truth_outliers : list of (int, str, int)
        Simulated gross errors: (pose, ball, index of the probe point within that ball).
    path : Path or None
        Directory the dataset was read from.
    chain : dict or None
        ``{"base": LINK, "tip": LINK}``: the chain of a URDF robot with more than one leaf.
    """

    robot: str
    tooling: Tooling
    noise: Noise
    provenance: dict
    pose_ids: np.ndarray
    joints_deg: np.ndarray
    probes: PointObservations | None = None
    centres: PointObservations | None = None
    poses: PoseObservations | None = None
    distances: DistanceObservations | None = None
    contacts: ContactObservations | None = None
    plane_contacts: ContactObservations | None = None
    station_centres: StationPointObservations | None = None
    pixels: PixelObservations | None = None
    setup: SetupSpec = field(default_factory=SetupSpec)
    stations: np.ndarray | None = None
    world_station: str | None = None
    truth: dict[str, float] | None = None
    truth_outliers: list = field(default_factory=list)
    path: Path | None = None
    chain: dict | None = None

    def __post_init__(self):
        self.pose_ids = np.asarray(self.pose_ids, dtype=int).reshape(-1)
        q = np.asarray(self.joints_deg, dtype=float)
        self.joints_deg = q if q.ndim == 2 else q.reshape(-1, 6)
        if len(self.pose_ids) != len(self.joints_deg):
            raise ValueError("pose_ids and joints_deg must have the same length")
        if self.stations is not None:
            self.stations = np.asarray(self.stations, dtype=str).reshape(-1)
            if len(self.stations) != len(self.pose_ids):
                raise ValueError("stations must have one name per pose")

    @property
    def n_poses(self) -> int:
        return len(self.pose_ids)

    @property
    def n_joints(self) -> int:
        return self.joints_deg.shape[1]

    @property
    def joints_rad(self) -> np.ndarray:
        """Joint readings (N, n) in radians, for all-revolute arms (else ``model.joints_to_internal``)."""
        return np.radians(self.joints_deg)

    def row_of(self, pose_ids) -> np.ndarray:
        """Row index into ``pose_ids`` of each of ``pose_ids`` (all must exist)."""
        order = np.argsort(self.pose_ids)
        pos = np.searchsorted(self.pose_ids, pose_ids, sorter=order)
        return order[np.asarray(pos)]

    def select(self, pose_ids) -> Dataset:
        """A dataset with only the given poses (and their measurements)."""
        keep = np.isin(self.pose_ids, pose_ids)
        out = Dataset(robot=self.robot, tooling=self.tooling, noise=self.noise, provenance=dict(self.provenance),
                      pose_ids=self.pose_ids[keep], joints_deg=self.joints_deg[keep], truth=self.truth,
                      truth_outliers=[o for o in self.truth_outliers if o[0] in set(self.pose_ids[keep].tolist())],
                      path=self.path, chain=self.chain, setup=self.setup,
                      stations=None if self.stations is None else self.stations[keep], world_station=self.world_station)
        for level in all_levels():
            obs = getattr(self, level, None)
            if obs is not None:
                setattr(out, level, obs.subset(np.isin(obs.pose, self.pose_ids[keep])))
        return out

    def split_station_centres(self) -> None:
        """Move the centres measured from a station other than the world's into ``station_centres``."""
        if self.stations is None or self.centres is None:
            return
        station_of = dict(zip(self.pose_ids.tolist(), self.stations.tolist()))
        st = np.array([station_of[p] for p in self.centres.pose.tolist()], dtype=str)
        other = st != self.world_station
        if other.any():
            c = self.centres
            assert c.line is not None  # read from a file
            self.station_centres = StationPointObservations(c.pose[other], c.ball[other], c.xyz[other], st[other],
                                                            c.line[other])
            self.centres = c.subset(~other) if (~other).any() else None

    def levels(self) -> list[str]:
        """The measurement levels present: a subset of :data:`LEVELS`."""
        return [lv for lv in all_levels() if getattr(self, lv, None) is not None]
