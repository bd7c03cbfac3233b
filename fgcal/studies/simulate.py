"""The paper's POSE program: a simulated robot with known deviations, measured by a CMM.

1. The actual robot: the nominal model plus seeded random deviations of the identifiable
   parameters (:func:`draw_truth`).
2. A pose plan (:mod:`fgcal.studies.plans`): random joint sets whose balls the CMM can reach, or
   the paper's experiment, 12 points of a parallelepiped each reached in four arm configurations.
3. Measurement as in the paper (:func:`measure`): per pose, the reachable balls (3 by default)
   are each probed at 4 points on their accessible side; CMM noise is added to every point and
   the joint readings are rounded to the controller's resolution.

Everything is driven by an explicit ``numpy.random.Generator``. Units: mm and rad inside, deg
in the returned :class:`~fgcal.measurements.dataset.Dataset`. No I/O here.
"""
from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from fgcal.errors import FgcalError
from fgcal.measurements.contact import ContactObservations
from fgcal.measurements.dataset import Dataset, Noise, PointObservations
from fgcal.measurements.setup import FixtureSpec, SetupSpec
from fgcal.measurements.types import all_levels, kinematic_levels
from fgcal.robots.deviations import Deviations
from fgcal.robots.kinematics import tool_points
from fgcal.robots.model import RobotModel, Tooling
from fgcal.studies.plans import UP, ball_access, paper_plan, random_plan
from fgcal.studies.simulate_setup import SetupSimulation, simulate_contacts, station_truths, to_station_frame

__all__ = ["CONTACT_LEVELS", "SetupSimulation", "SimulationSettings", "draw_truth", "measure", "simulate"]

CONTACT_LEVELS = ("contacts", "plane_contacts")  # simulated by fgcal.studies.simulate_setup, not per pose
EXACT_SEATING_SIGMA = 1e-6  # mm: the contact_sigma declared for exact seatings (a dataset refuses 0)

log = logging.getLogger(__name__)


def draw_truth(model: RobotModel, rng: np.random.Generator, deviations: Deviations = Deviations(),
               names=None) -> np.ndarray:
    """Slot vector (S,) of an actual robot: nominal plus Gaussian deviations of ``names``.

    Only the identifiable parameters deviate by default, so the truth is recoverable exactly.
    """
    names = model.identifiable_names() if names is None else list(names)
    x = model.nominal.copy()
    idx = [model.slot(n) for n in names]
    x[idx] += rng.normal(size=len(idx)) * deviations.sigmas(names)
    return x


def _cap_directions(axis, n_points: int, rng) -> np.ndarray:
    """``n_points`` unit vectors on a cap around ``axis``: its pole, then a ring 45-75 deg away."""
    axis = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    def cross(a, b):  # np.cross costs ~20 us of overhead on 3-vectors, this ~2 us
        return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])

    e1 = cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    e2 = cross(axis, e1)
    dirs = [axis]
    n_ring = n_points - 1
    start = rng.uniform(0, 2 * np.pi)
    for i in range(n_ring):
        polar = np.radians(rng.uniform(45.0, 75.0))
        az = start + 2 * np.pi * i / max(n_ring, 1) + rng.uniform(-0.2, 0.2)
        dirs.append(np.cos(polar) * axis + np.sin(polar) * (np.cos(az) * e1 + np.sin(az) * e2))
    return np.array(dirs[:n_points])


def measure(model: RobotModel, slots, q_commanded, rng: np.random.Generator, tooling: Tooling, noise: Noise,
            volume=None, n_balls: int = 3, probes_per_ball: int = 4, outlier_fraction: float = 0.0,
            outlier_size: float = 0.5, levels=("probes",), pose_ids=None):
    """Measure the actual robot ``slots`` at commanded joints as the paper did.

    Parameters
    ----------
    q_commanded : array_like, shape (N, n)
        Joint sets the robot is sent to (rad). The arm lands at ``q + N(0, repeatability)``;
        the controller reports ``q`` rounded to ``joint_resolution``.
    levels : sequence of str
        What to write: ``"probes"`` and any registered measurement type's level
        (:mod:`fgcal.measurements.types`), each simulated by its type with its noise from ``noise``.
    outlier_fraction : float
        Fraction of probe points displaced by ``outlier_size`` mm along the surface normal.

    Returns
    -------
    pose_ids : ndarray of int, shape (N',)
    joints_deg : ndarray, shape (N', n)
    probes : PointObservations or None
    observed : dict of level to observations
        The other levels' measurements.
    outliers : list of (pose, ball, probe index)
    skipped : list of str
        Poses dropped because fewer than ``n_balls`` balls were reachable on the actual robot.
    """
    q_commanded = np.atleast_2d(np.asarray(q_commanded, dtype=float))
    n = len(q_commanded)
    ids = np.arange(1, n + 1) if pose_ids is None else np.asarray(pose_ids, dtype=int)
    # Repeatability and resolution are in each joint's file unit (deg, or mm for prismatic joints).
    q_actual = q_commanded + rng.normal(size=q_commanded.shape) * model.joints_to_internal(
        np.full(model.n_joints, noise.repeatability))
    reading = model.joints_to_file_units(q_commanded)
    if noise.joint_resolution > 0:
        reading = np.round(reading / noise.joint_resolution) * noise.joint_resolution
    T = model.forward(slots, q_actual)
    ok, upness, centres = ball_access(T, tooling, volume)
    names = np.array(tooling.names)
    kinds = kinematic_levels(levels)
    keep: list[int] = []
    probe_rows: list = []
    outliers: list = []
    skipped: list = []
    rows: dict[str, list] = {kind.level: [] for kind in kinds}  # (pose id, ball, values) per measurement
    for i in range(n):
        visible = np.nonzero(ok[i])[0]
        if len(visible) < n_balls:
            skipped.append(f"pose {ids[i]}: only {len(visible)} ball(s) reachable on the actual robot")
            continue
        keep.append(i)
        balls = visible[np.argsort(-upness[i, visible], kind="stable")[:n_balls]]
        for b in sorted(balls):
            c = centres[i, b]
            if "probes" in levels:
                outward = T[i, :3, :3] @ (tooling.balls[names[b]] / np.linalg.norm(tooling.balls[names[b]]))
                dirs = _cap_directions(outward + UP, probes_per_ball, rng)
                pts = c + tooling.radius * dirs + rng.normal(size=dirs.shape) * noise.cmm_sigma
                for k in range(probes_per_ball):
                    if outlier_fraction > 0 and rng.uniform() < outlier_fraction:
                        # A bad touch reads off along the surface normal, in or out.
                        pts[k] += outlier_size * rng.choice([-1.0, 1.0]) * dirs[k]
                        outliers.append((int(ids[i]), str(names[b]), k))
                    probe_rows.append((ids[i], names[b], pts[k]))
            for kind in kinds:
                if kind.per_ball:
                    values = kind.simulate(T[i:i + 1], tooling.balls[names[b]][None], rng, noise)
                    rows[kind.level].append((ids[i], names[b], values[0]))
        for kind in kinds:
            if not kind.per_ball:
                rows[kind.level].append((ids[i], "", kind.simulate(T[i:i + 1], np.zeros((1, 3)), rng, noise)[0]))

    probes = None
    if "probes" in levels and probe_rows:
        probes = PointObservations(np.array([r[0] for r in probe_rows], dtype=int),
                                   np.array([r[1] for r in probe_rows], dtype=str),
                                   np.array([r[2] for r in probe_rows]))
    observed = {kind.level: kind.observations(np.array([r[0] for r in rows[kind.level]], dtype=int),
                                              np.array([r[1] for r in rows[kind.level]], dtype=str),
                                              np.array([r[2] for r in rows[kind.level]]))
                for kind in kinds if rows[kind.level]}
    kept = np.array(keep, dtype=int)
    return ids[kept], reading[kept], probes, observed, outliers, skipped


def _pivot_at_origin(model: RobotModel, slots, q, tooling: Tooling) -> np.ndarray:
    """``slots`` with the world moved so that its origin is a ballbar pivot amid the balls' positions.

    The pivot sits 300 mm below the mean of the balls' centres at the planned joints, so that the
    bar's length varies over the poses.
    """
    centres = tool_points(model.forward(slots, q), tooling.offsets()).reshape(-1, 3)
    return model.with_world_origin_at(slots, centres.mean(axis=0) - np.array([0.0, 0.0, 300.0]))


@dataclass(frozen=True)
class SimulationSettings:
    """Everything :func:`simulate` needs besides the model and the random generator."""

    n_poses: int | None = None
    plan: str = "random"
    noise: Noise = Noise()
    deviations: Deviations = Deviations()
    n_balls: int = 3
    probes_per_ball: int = 4
    outlier_fraction: float = 0.0
    outlier_size: float = 0.5
    levels: tuple = ("probes",)
    setup: SetupSimulation = field(default_factory=SetupSimulation)


def simulate(model: RobotModel, rng: np.random.Generator, settings: SimulationSettings = SimulationSettings(),
             robot_ref: str | None = None, seed=None, truth=None):
    """Simulate a calibration experiment; returns ``(dataset, notes)``.

    ``truth`` (S,) mm/rad reuses an actual robot (for a verification set of the same robot, as
    the paper ran POSE twice; a ballbar keeps that truth's pivot); a new one is drawn otherwise.
    ``notes`` lists what was skipped (poses the CMM could not reach) so callers can say so.
    ``settings.setup`` adds contacts (two-socket plates, a datum, a plane: poses after the
    instrument's, :mod:`fgcal.studies.simulate_setup`) and splits the centres over stations; the
    true fixtures and stations are in ``provenance["setup_truth"]`` (``dataset.yaml``'s notation).
    """
    s = settings
    tooling = _check_settings(model, s)
    regular = tuple(lv for lv in s.levels if lv not in CONTACT_LEVELS)
    new_robot = truth is None
    if not new_robot and s.setup.stations > 1:  # new stations would bear the names of the calibration's
        raise FgcalError("--stations with --truth: a verification set of the same robot is measured from the "
                         "world station (its other stations' frames would be new); omit --stations")
    truth = draw_truth(model, rng, s.deviations) if truth is None else np.asarray(truth, dtype=float)
    notes: list = []
    noise = s.noise
    if "poses" in regular and noise.pose_position_sigma is None:
        # A pose from balls ~120 mm apart: position as a point, orientation ~ sigma / 100 mm.
        noise = Noise(noise.cmm_sigma, noise.joint_resolution, noise.repeatability,
                      noise.cmm_sigma, float(np.degrees(noise.cmm_sigma / 100.0)))
    ids = np.zeros(0, dtype=int)
    joints_deg = np.zeros((0, model.n_joints))
    probes, observed, outliers = None, {}, []
    if regular:
        q = _plan(model, truth, rng, s, new_robot, notes)
        volume = model.volume
        if "distances" in regular:  # the world is the pivot's frame; the plan already kept the volume
            if new_robot:  # a given truth keeps its pivot (a verification set of the same set-up)
                truth = _pivot_at_origin(model, truth, q, tooling)
            volume = None
        ids, joints_deg, probes, observed, outliers, skipped = measure(
            model, truth, q, rng, tooling, noise, volume, s.n_balls, s.probes_per_ball,
            s.outlier_fraction, s.outlier_size, regular)
        notes += [f"skipped {m}" for m in skipped]
    provenance = {"generator": "fgcal simulate", "plan": s.plan if regular else None, "seed": seed,
                  "deviations": asdict(s.deviations), "n_balls": s.n_balls, "probes_per_ball": s.probes_per_ball,
                  "outlier_fraction": s.outlier_fraction, "outlier_size_mm": s.outlier_size}
    truth_file = {name: float(v) for name, v in zip(model.slot_names, model.slots_to_file_units(truth))}
    setup_truth: dict = {}
    fixtures: dict = {}
    distances: tuple = ()
    contacts = plane_contacts = None
    if s.setup.has_contacts:
        ball = s.setup.ball or tooling.names[0]
        cp = simulate_contacts(model, truth, rng, s.setup, ball, tooling.balls[ball], tooling.radius)
        first = int(ids.max()) + 1 if len(ids) else 1
        contact_ids = first + np.arange(len(cp.q))
        ids = np.concatenate([ids, contact_ids])
        joints_deg = np.vstack([joints_deg, _readings(model, cp.q, rng, noise)])
        contacts = _renumber(cp.contacts, contact_ids)
        plane_contacts = None if cp.plane_contacts is None else _renumber(cp.plane_contacts, contact_ids)
        fixtures.update(cp.setup.fixtures)
        distances = cp.setup.distances
        setup_truth.update(cp.truth)
        noise = replace(noise, extra=tuple((k, v) for k, v in noise.extra if k != "contact_sigma")
                        + (("contact_sigma", float(s.setup.contact_sigma or EXACT_SEATING_SIGMA)),))
        provenance["contacts"] = {"placements": s.setup.placements, "socket_distance_mm": s.setup.socket_distance,
                                  "configs": s.setup.configs, "datum": s.setup.datum, "plane": s.setup.plane,
                                  "ball": ball}
    ds = Dataset(robot=robot_ref or model.name, tooling=tooling, noise=noise, provenance=provenance,
                 pose_ids=ids, joints_deg=joints_deg, probes=probes, truth=truth_file, truth_outliers=outliers)
    for level, obs in observed.items():
        setattr(ds, level, obs)
    ds.contacts = contacts if contacts is not None and len(contacts) else None
    ds.plane_contacts = plane_contacts
    if s.setup.stations > 1:
        fixtures.update(_split_over_stations(ds, rng, s.setup.stations, setup_truth))
    ds.setup = SetupSpec(fixtures, distances)
    if setup_truth:
        provenance["setup_truth"] = setup_truth
    return ds, notes


def _check_settings(model: RobotModel, s: SimulationSettings) -> Tooling:
    """The model's tooling, after checking ``s`` against it (one-line errors naming the option)."""
    tooling = model.tooling
    if tooling is None:
        raise FgcalError(f"robot model {model.name} has no tooling (balls) to measure (give a tool ball)")
    for lv in s.levels:
        if lv not in all_levels():
            raise FgcalError(f"unknown measurement level {lv!r} ({', '.join(all_levels())})")
    regular = [lv for lv in s.levels if lv not in CONTACT_LEVELS]
    if regular and (s.n_balls < 1 or s.n_balls > len(tooling.balls)):
        raise FgcalError(f"--balls must be between 1 and {len(tooling.balls)}")
    if s.probes_per_ball < 4 and "probes" in s.levels:
        raise FgcalError("--probes-per-ball must be at least 4 (a sphere needs 4 points)")
    if "probes" in s.levels and tooling.radius <= 0:
        raise FgcalError(f"robot model {model.name}: its tooling is a reflector (radius 0): simulate centres or "
                         "poses, not probes")
    u = s.setup
    if any(lv in CONTACT_LEVELS for lv in s.levels) != u.has_contacts:
        raise FgcalError("contacts are simulated with --sockets, --datum or --plane (the levels contacts, "
                         "plane_contacts come with them)")
    if u.has_contacts and not regular and (s.n_poses is not None or s.plan != "random"):
        raise FgcalError("--poses and --plan are the instrument's poses: contacts alone come from --sockets, "
                         "--configs, --datum and --plane (add --levels centres, say, for both)")
    if u.has_contacts and (u.ball or tooling.names[0]) not in tooling.balls:
        raise FgcalError(f"no tool ball {u.ball!r} ({', '.join(tooling.names)})")
    if u.placements > 0 and (u.configs < 1 or u.socket_distance <= 0 or u.distance_sigma <= 0):
        raise FgcalError("--configs must be at least 1, --socket-distance and --distance-sigma positive (mm)")
    if u.contact_sigma < 0 or (u.datum_sigma is not None and u.datum_sigma < 0) or u.patch_radius <= 0:
        raise FgcalError("--contact-sigma and --datum-sigma must not be negative, --patch-radius must be positive")
    if u.stations < 1:
        raise FgcalError("--stations must be at least 1")
    if u.stations > 1 and set(s.levels) - set(CONTACT_LEVELS) != {"centres"}:
        raise FgcalError("--stations: several stations measure ball centres or a reflector (--levels centres, "
                         "with contacts or not)")
    return tooling


def _plan(model: RobotModel, truth, rng, s: SimulationSettings, new_robot: bool, notes: list) -> np.ndarray:
    """The joint sets (N, n) the instrument's poses are commanded to."""
    tooling = model.tooling
    assert tooling is not None  # checked by _check_settings
    if s.plan == "random":
        n = 21 if s.n_poses is None else s.n_poses
        if n < 1:
            raise FgcalError("--poses must be at least 1")
        # A given ballbar truth has the pivot's frame for a world: the instrument volume means nothing there.
        plan_volume = None if ("distances" in s.levels and not new_robot) else model.volume
        return random_plan(model, truth, n, rng, tooling, plan_volume, s.n_balls)
    if s.plan == "paper":
        q, labels, skipped = paper_plan(model, rng, tooling, model.volume, n_balls=s.n_balls)
        notes += [f"paper plan: skipped {m}" for m in skipped]
        if s.n_poses is not None and s.n_poses != len(q):
            raise FgcalError(f"the paper plan has {len(q)} poses; omit --poses or use --plan random")
        return q
    raise FgcalError(f"unknown plan {s.plan!r} (random, paper)")


def _readings(model: RobotModel, q, rng, noise: Noise) -> np.ndarray:
    """What the controller reports (N, n) in file units at the exact joints ``q`` (rad, mm): plus
    N(0, repeatability), rounded to the resolution."""
    reading = model.joints_to_file_units(np.asarray(q) + rng.normal(size=np.shape(q)) * model.joints_to_internal(
        np.full(model.n_joints, noise.repeatability)))
    if noise.joint_resolution > 0:
        reading = np.round(reading / noise.joint_resolution) * noise.joint_resolution
    return reading


def _renumber(obs: ContactObservations, ids) -> ContactObservations:
    return ContactObservations(ids[obs.pose], obs.ball, obs.fixture)


def _split_over_stations(ds: Dataset, rng, count: int, setup_truth: dict) -> dict:
    """Spread the instrument's poses over ``count`` stations in turn (``S1`` is the world); move each
    other station's centres into its frame. Returns the stations' (unknown) blocks."""
    names = [f"S{k + 1}" for k in range(count)]
    poses = ds.centres.pose if ds.centres is not None else np.zeros(0, dtype=int)
    measured = list(dict.fromkeys(poses.tolist()))
    station_of = {p: names[k % count] for k, p in enumerate(measured)}
    ds.stations = np.array([station_of.get(p, names[0]) for p in ds.pose_ids.tolist()], dtype=str)
    ds.world_station = names[0]
    poses_true = station_truths(rng, names[1:])
    if ds.centres is not None:
        at = np.array([station_of[p] for p in poses.tolist()], dtype=str)
        xyz = ds.centres.xyz.copy()
        for name, entries in poses_true.items():
            xyz[at == name] = to_station_frame(xyz[at == name], entries)
        ds.centres = PointObservations(ds.centres.pose, ds.centres.ball, xyz)
    ds.split_station_centres()
    for name, e in poses_true.items():
        setup_truth[name] = {"type": "station",
                             "pose": [float(v) for v in np.degrees(e[:3])] + [float(v) for v in e[3:]]}
    return {name: FixtureSpec(name, "station") for name in names[1:]}
