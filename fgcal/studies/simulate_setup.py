"""Simulated set-ups without an instrument in the world frame (DESIGN.md 8.2, 8.3).

What ``fgcal simulate`` writes besides the paper's CMM measurements:

* a two-socket tool (MUKCa's plate): ``placements`` plates, each with two sockets
  ``socket_distance`` mm apart in a random horizontal direction (fixtures ``pK/hole_0``,
  ``pK/hole_1`` and a known distance between them), each socket visited in ``configs`` varied
  joint configurations;
* a datum point (fixture ``datum``): ``datum`` configurations at one point, unknown or known with
  a sigma;
* a plane-touch set (fixture ``table``): ``plane`` contacts of the tool ball on a plane tilted by up
  to ``plane_tilt`` deg, spread over a disc of ``patch_radius`` mm;
* stations (DESIGN.md 8.3): the poses of a reflector (or ball centres) split over ``stations``
  instrument stations in turn, each measuring in its own frame; the first is the world.

A seating puts the true ball centre at the fixture point plus N(0, ``contact_sigma``) per axis
(on a plane: ``tool.radius`` + N(0, ``contact_sigma``) along the normal), reached by a
position-only inverse kinematics of the *actual* robot from a random start; the joint readings
are the exact joints plus N(0, repeatability), rounded to the joint resolution, as the
controller reports them. Units: mm and rad inside, mm and deg in what is returned. No I/O here.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from fgcal.errors import FgcalError
from fgcal.measurements.contact import ContactObservations
from fgcal.measurements.setup import DistanceConstraint, FixtureSpec, SetupSpec
from fgcal.robots.model import RobotModel
from fgcal.robots.single_pose import jacobians_one
from fgcal.robots.transforms import rot

__all__ = ["ContactPoses", "SetupSimulation", "reach", "simulate_contacts", "station_truths", "to_station_frame"]

log = logging.getLogger(__name__)

MIN_JOINT_SEPARATION_DEG = 20.0  # two configurations at one socket differ by more (norm of the joints' change)
MIN_ROTATION_DEG = 10.0          # ... and their tool frames by more than this rotation
TRIES_PER_CONFIG = 12            # IK attempts (random starts) per wanted configuration
GIVE_UP_AFTER = 3                # ... but none more after this many per configuration found nothing
MAX_DRAWS = 50                   # fixture locations drawn before giving up


@dataclass(frozen=True)
class SetupSimulation:
    """What to simulate of a set-up (all counts 0 / 1: nothing).

    Attributes
    ----------
    placements : int
        Two-socket plates.
    socket_distance : float
        Distance between a plate's two sockets (mm).
    distance_sigma : float
        The sigma declared with that distance (mm): the plate's tolerance (the simulated sockets
        are exactly ``socket_distance`` apart).
    configs : int
        Configurations per socket and at the datum.
    datum : int
        Configurations at a datum point (0: no datum).
    datum_sigma : float or None
        None: the datum's position is unknown; 0: known exactly (``fixed``); else known with this
        sigma (mm), a prior.
    plane : int
        Contacts on a plane (0: none).
    plane_tilt : float
        The plane's normal is tilted from the world's z by up to this (deg).
    patch_radius : float
        Contacts are spread over a disc of this radius (mm).
    contact_sigma : float
        Seating error per axis (mm).
    ball : str or None
        The tool ball that touches (default: the tooling's first).
    stations : int
        Instrument stations the centres are measured from (1: the world alone).
    """

    placements: int = 0
    socket_distance: float = 50.0
    distance_sigma: float = 0.005
    configs: int = 10
    datum: int = 0
    datum_sigma: float | None = None
    plane: int = 0
    plane_tilt: float = 10.0
    patch_radius: float = 200.0
    contact_sigma: float = 0.02
    ball: str | None = None
    stations: int = 1

    @property
    def has_contacts(self) -> bool:
        return self.placements > 0 or self.datum > 0 or self.plane > 0


@dataclass
class ContactPoses:
    """Simulated contacts: the exact joints (N, n) rad/mm of the actual robot, the contacts (pose
    index 0..N-1, ball, fixture), the set-up spec and the true fixtures (``dataset.yaml`` form)."""

    q: np.ndarray
    contacts: ContactObservations
    plane_contacts: ContactObservations | None
    setup: SetupSpec
    truth: dict


def _sampling_limits(model: RobotModel) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = model.joint_limits[:, 0], model.joint_limits[:, 1]
    wide = model.joint_is_angle & (hi - lo > 2 * np.pi)
    return np.where(wide, np.maximum(lo, -np.pi), lo), np.where(wide, np.minimum(hi, np.pi), hi)


def _ball_point(model: RobotModel, slots, q, ball) -> tuple[np.ndarray, np.ndarray]:
    """The ball centre (3,) mm at joints ``q`` (n,) and its Jacobian in the joints (3, n)."""
    jac = jacobians_one(model.chain, slots, q, offsets=np.asarray(ball, dtype=float)[None])
    return jac.points[0, 0], jac.point_joints[0, 0]


def reach(model: RobotModel, slots, target, ball, q_start, tol_mm: float = 1e-10,
          max_steps: int = 80) -> np.ndarray | None:
    """Joints (n,) within the limits putting tool point ``ball`` (3,) at ``target`` (3,) mm, or None.

    Damped least squares (Levenberg-Marquardt on the minimum-norm step, the joints clipped into
    their limits) from ``q_start``, to ``tol_mm``; None when it stalls (a target out of reach, a
    limit in the way). The problem is underdetermined (n joints, 3 equations): the start picks
    the configuration.
    """
    lo, hi = model.joint_limits[:, 0], model.joint_limits[:, 1]
    target = np.asarray(target, dtype=float)
    q = np.clip(np.asarray(q_start, dtype=float), lo, hi)
    p, J = _ball_point(model, slots, q, ball)
    e = p - target
    err = float(np.linalg.norm(e))
    damping = 1e2  # mm^2 against J J^T ~ (1000 mm/rad)^2
    for k in range(max_steps):
        if err <= tol_mm:
            return q
        if k == max_steps // 3 and err > 1.0:  # far off after a third of the steps: out of reach from here
            return None
        step = J.T @ np.linalg.solve(J @ J.T + damping * np.eye(3), e)
        q_new = np.clip(q - step, lo, hi)
        p_new, J_new = _ball_point(model, slots, q_new, ball)
        e_new = p_new - target
        err_new = float(np.linalg.norm(e_new))
        if err_new < err:
            q, J, e, err = q_new, J_new, e_new, err_new
            damping = max(damping / 10.0, 1e-12)
        else:
            damping *= 10.0
            if damping > 1e12:
                break
    return q if err <= tol_mm else None


def _angle_deg(Ra, Rb) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1.0) / 2.0, -1.0, 1.0))))


def _configurations(model, slots, target, ball, rng, count, keep=None, near=()) -> list[np.ndarray]:
    """Up to ``count`` varied joint sets reaching ``target()`` (a new seating each time): each from a
    random start (or, every other try, from one of the joint sets ``near`` moved by N(0, 0.3 rad)),
    pairwise more than ``MIN_JOINT_SEPARATION_DEG`` and ``MIN_ROTATION_DEG`` apart; ``keep(T)`` may
    refuse a tool pose."""
    lo, hi = _sampling_limits(model)
    found: list = []
    frames: list = []
    for attempt in range(TRIES_PER_CONFIG * count):
        if len(found) == count or (not found and attempt >= GIVE_UP_AFTER * count):
            break  # done, or a target nothing reaches: let the caller draw another
        if len(near) and attempt % 2 == 0:
            start = near[rng.integers(len(near))] + rng.normal(size=model.n_joints) * 0.3
        else:
            start = rng.uniform(lo, hi)
        q = reach(model, slots, target(), ball, start)
        if q is None:
            continue
        T = model.forward(slots, q[None])[0]
        if keep is not None and not keep(T):
            continue
        qd = model.joints_to_file_units(q)
        if any(np.linalg.norm(qd - model.joints_to_file_units(qk)) <= MIN_JOINT_SEPARATION_DEG
               or _angle_deg(T[:3, :3], Tk[:3, :3]) <= MIN_ROTATION_DEG for qk, Tk in zip(found, frames, strict=True)):
            continue
        found.append(q)
        frames.append(T)
    return found


def _random_point(model, slots, ball, rng) -> np.ndarray:
    lo, hi = _sampling_limits(model)
    return _ball_point(model, slots, rng.uniform(lo, hi), ball)[0]


def _horizontal(rng) -> np.ndarray:
    a = rng.uniform(0.0, 2 * np.pi)
    return np.array([np.cos(a), np.sin(a), 0.0])


def simulate_contacts(model: RobotModel, slots, rng: np.random.Generator, s: SetupSimulation, ball_name: str,
                      ball, radius: float) -> ContactPoses:
    """The contacts of ``s`` on the actual robot ``slots`` (S,) with tool ball ``ball`` (3,) mm.

    Raises
    ------
    FgcalError
        If a fixture cannot be reached in ``s.configs`` configurations after ``MAX_DRAWS`` draws.
    """
    sig = s.contact_sigma
    q_all: list = []
    point_rows: list = []  # (pose index, fixture)
    plane_rows: list = []
    fixtures: dict = {}
    distances = []
    truth: dict = {}

    def seat(p):
        return lambda: p + rng.normal(size=3) * sig

    for k in range(s.placements):
        for _ in range(MAX_DRAWS):
            s0 = _random_point(model, slots, ball, rng)
            s1 = s0 + s.socket_distance * _horizontal(rng)
            sets = []
            for p in (s0, s1):
                found = _configurations(model, slots, seat(p), ball, rng, s.configs)
                if len(found) < s.configs:
                    break
                sets.append(found)
            if len(sets) == 2:
                break
        else:
            raise FgcalError(f"simulate: plate {k}: no two sockets {s.socket_distance:g} mm apart reachable in "
                             f"{s.configs} configurations each ({MAX_DRAWS} draws); ask for fewer --configs")
        for j, (p, found) in enumerate(zip((s0, s1), sets, strict=True)):
            name = f"p{k}/hole_{j}"
            fixtures[name] = FixtureSpec(name, "point")
            truth[name] = {"type": "point", "position": [float(v) for v in p]}
            point_rows += [(len(q_all) + i, name) for i in range(len(found))]
            q_all += found
        distances.append(DistanceConstraint(f"p{k}/hole_0", f"p{k}/hole_1", float(s.socket_distance),
                                            float(s.distance_sigma)))
    if s.datum > 0:
        for _ in range(MAX_DRAWS):
            p = _random_point(model, slots, ball, rng)
            found = _configurations(model, slots, seat(p), ball, rng, s.datum)
            if len(found) == s.datum:
                break
        else:
            raise FgcalError(f"simulate: no datum point reachable in {s.datum} configurations ({MAX_DRAWS} draws)")
        known = s.datum_sigma is not None
        fixtures["datum"] = FixtureSpec("datum", "point", p.copy() if known else None,
                                        s.datum_sigma if known and s.datum_sigma else None,
                                        bool(known and s.datum_sigma == 0))
        truth["datum"] = {"type": "point", "position": [float(v) for v in p]}
        point_rows += [(len(q_all) + i, "datum") for i in range(len(found))]
        q_all += found
    if s.plane > 0:
        q_plane, n, d = _plane_contacts(model, slots, rng, s, ball, radius)
        fixtures["table"] = FixtureSpec("table", "plane")
        truth["table"] = {"type": "plane", "normal": [float(v) for v in n], "offset": float(d)}
        plane_rows = [(len(q_all) + i, "table") for i in range(len(q_plane))]
        q_all += q_plane

    def obs(rows):
        return ContactObservations(np.array([r[0] for r in rows], dtype=int), np.full(len(rows), ball_name),
                                   np.array([r[1] for r in rows], dtype=str))

    return ContactPoses(np.array(q_all).reshape(-1, model.n_joints), obs(point_rows),
                        obs(plane_rows) if plane_rows else None, SetupSpec(fixtures, tuple(distances)), truth)


def _plane_basis(n) -> tuple[np.ndarray, np.ndarray]:
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(n, a)
    u /= np.linalg.norm(u)
    return u, np.cross(n, u)


def _plane_contacts(model, slots, rng, s: SetupSimulation, ball, radius) -> tuple[list, np.ndarray, float]:
    """Joint sets of ``s.plane`` contacts on a plane through a reachable point, the plane's unit
    normal (3,) and offset ``d`` (mm; ``n . x = d``). The tool's origin stays on the normal's side."""
    for _ in range(MAX_DRAWS):
        c0 = _random_point(model, slots, ball, rng)
        tilt, az = np.radians(rng.uniform(0.0, s.plane_tilt)), rng.uniform(0.0, 2 * np.pi)
        n = np.array([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)])
        x0 = c0 - radius * n
        u, v = _plane_basis(n)
        found: list = []
        for _attempt in range(4 * s.plane):
            if len(found) == s.plane:
                break
            rho, phi = s.patch_radius * np.sqrt(rng.uniform()), rng.uniform(0.0, 2 * np.pi)
            x = x0 + rho * (np.cos(phi) * u + np.sin(phi) * v)
            centre = x + (radius + rng.normal() * s.contact_sigma) * n
            got = _configurations(model, slots, lambda c=centre: c, ball, rng, 1,
                                  keep=lambda T, c=centre, n=n: float(n @ (T[:3, 3] - c)) >= 0.0, near=found)
            found += got
        if len(found) == s.plane:
            return found, n, float(n @ x0)
    raise FgcalError(f"simulate: no plane with {s.plane} reachable contacts ({MAX_DRAWS} draws); ask for fewer "
                     "--plane contacts or a smaller --patch-radius")


def station_truths(rng: np.random.Generator, names) -> dict:
    """A random pose (6,) (phi, theta, psi rad; px, py, pz mm) per station: turned anywhere about
    the vertical, levelled to N(0, 0.5 deg), moved up to 1 m."""
    out = {}
    for name in names:
        angles = np.array([rng.uniform(-np.pi, np.pi), *np.radians(rng.normal(size=2) * 0.5)])
        out[name] = np.concatenate([angles, rng.uniform(-1000.0, 1000.0, 3)])
    return out


def to_station_frame(world, entries) -> np.ndarray:
    """Points (M, 3) mm in the world seen in a station's frame ``entries`` (6,): ``x = R^T w - p`` for
    the station's ``T x = R (x + p)`` (:func:`fgcal.measurements.setup.station_transform`)."""
    R = rot(2, entries[0]) @ rot(1, entries[1]) @ rot(0, entries[2])
    return np.asarray(world, dtype=float) @ R - entries[3:6]
