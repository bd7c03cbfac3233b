"""An independent generator of contact data ("contacts": a tool ball seated in a fixture socket, or
touching a plane) for checking fgcal's contact measurement type.

Nothing here uses fgcal: the forward kinematics is its own URDF reader (xml.etree + numpy, mm), the
inverse kinematics is scipy's least_squares on that forward kinematics, and the dataset is written
as plain text in fgcal's dataset format (``fgcal-dataset/1``).

Units: lengths in mm; joint values in radians (revolute) or mm (prismatic) inside this module,
degrees (revolute) or mm (prismatic) in ``joints.csv`` and in every ``readings`` array returned.

Main entry points:

* :class:`UrdfChain` -- forward kinematics of the chain ``base -> tip`` of a URDF text.
* :func:`perturbed_urdf` -- the "true" robot: a copy of a URDF with the chain's joint origins moved.
* :func:`two_socket_dataset` -- plates with two sockets a known distance apart, each socket visited
  in many different joint configurations.
* :func:`plane_dataset` -- the tool ball touching an unknown plane at many places.
* :func:`new_poses` -- random joint sets and the true ball centres there (held-out accuracy checks).
* :func:`rigid_align`, :func:`aligned_rms` -- the best rigid motion between two point sets (Kabsch),
  since a contacts-only calibration fixes its world frame only up to a rigid motion.
"""
from __future__ import annotations

import math
import shutil
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

REVOLUTE = ("revolute", "continuous")
MOVABLE = REVOLUTE + ("prismatic",)


# ----------------------------------------------------------------------------------------------
# URDF forward kinematics
# ----------------------------------------------------------------------------------------------

def _floats(text, default):
    if text is None:
        return np.array(default, dtype=float)
    return np.array([float(v) for v in text.split()], dtype=float)


def rpy_matrix(r, p, y):
    """URDF fixed-axis roll-pitch-yaw: R = Rz(y) Ry(p) Rx(r)."""
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def axis_angle_matrix(axis, angle):
    """Rotation by ``angle`` about the unit vector ``axis`` (Rodrigues)."""
    x, y, z = axis
    c, s = math.cos(angle), math.sin(angle)
    C = 1.0 - c
    return np.array([[c + x * x * C, x * y * C - z * s, x * z * C + y * s],
                     [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
                     [z * x * C - y * s, z * y * C + x * s, c + z * z * C]])


@dataclass
class _Joint:
    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray  # 4x4, mm
    axis: np.ndarray    # unit, in the joint frame
    lower: float        # rad or mm
    upper: float


class UrdfChain:
    """Forward kinematics of the serial chain ``base -> tip`` of a URDF (text), in mm.

    ``base`` defaults to the URDF's root link (the only link that is no joint's child), ``tip`` to
    its only leaf. ``joint_names``/``joint_types``/``limits`` describe the movable joints of the
    chain in order from the base (revolute and continuous joints in rad, prismatic in mm).
    """

    def __init__(self, text: str, base: str | None = None, tip: str | None = None):
        root = ET.fromstring(text)
        links = [e.get("name") for e in root.findall("link")]
        by_child = {}
        for e in root.findall("joint"):
            o = e.find("origin")
            xyz = _floats(o.get("xyz") if o is not None else None, [0, 0, 0])
            rpy = _floats(o.get("rpy") if o is not None else None, [0, 0, 0])
            T = np.eye(4)
            T[:3, :3] = rpy_matrix(*rpy)
            T[:3, 3] = xyz * 1000.0
            a = e.find("axis")
            axis = _floats(a.get("xyz") if a is not None else None, [1, 0, 0])
            kind = e.get("type")
            if kind in MOVABLE:
                axis = axis / np.linalg.norm(axis)
            lim = e.find("limit")
            scale = 1000.0 if kind == "prismatic" else 1.0
            if kind == "continuous" and (lim is None or lim.get("lower") is None):
                lo, hi = -np.pi, np.pi
            elif lim is not None:
                lo, hi = float(lim.get("lower", 0.0)) * scale, float(lim.get("upper", 0.0)) * scale
            else:
                lo, hi = 0.0, 0.0
            j = _Joint(e.get("name"), kind, e.find("parent").get("link"), e.find("child").get("link"),
                       T, axis, lo, hi)
            by_child[j.child] = j
        roots = [k for k in links if k not in by_child]
        if base is None:
            if len(roots) != 1:
                raise ValueError(f"{len(roots)} root links; name the base")
            base = roots[0]
        if tip is None:
            parents = {j.parent for j in by_child.values()}
            leaves = [k for k in links if k not in parents]
            if len(leaves) != 1:
                raise ValueError(f"{len(leaves)} leaf links; name the tip")
            tip = leaves[0]
        chain, link = [], tip
        while link != base:
            if link not in by_child:
                raise ValueError(f"link {tip!r} is not below link {base!r}")
            chain.append(by_child[link])
            link = by_child[link].parent
        self.base, self.tip = base, tip
        self.joints = chain[::-1]  # every joint of the chain, fixed ones too
        self.movable = [j for j in self.joints if j.type in MOVABLE]
        self.joint_names = [j.name for j in self.movable]
        self.joint_types = ["prismatic" if j.type == "prismatic" else "revolute" for j in self.movable]
        self.is_revolute = np.array([t == "revolute" for t in self.joint_types])
        self.limits = np.array([[j.lower, j.upper] for j in self.movable])
        self.n = len(self.movable)

    # -- conversions between chain units (rad, mm) and readings (deg, mm) --
    def to_readings(self, q):
        q = np.asarray(q, dtype=float)
        return np.where(self.is_revolute, np.degrees(q), q)

    def from_readings(self, readings):
        r = np.asarray(readings, dtype=float)
        return np.where(self.is_revolute, np.radians(r), r)

    def _frames(self, q):
        """Tip transform and, per movable joint, its world axis and origin (for the Jacobian)."""
        T = np.eye(4)
        axes = np.empty((self.n, 3))
        origins = np.empty((self.n, 3))
        k = 0
        for j in self.joints:
            T = T @ j.origin
            if j.type in MOVABLE:
                R = T[:3, :3]
                axes[k] = R @ j.axis
                origins[k] = T[:3, 3]
                if j.type == "prismatic":
                    T = T.copy()
                    T[:3, 3] += axes[k] * q[k]
                else:
                    T = T.copy()
                    T[:3, :3] = R @ axis_angle_matrix(j.axis, q[k])
                k += 1
        return T, axes, origins

    def fk(self, q) -> np.ndarray:
        """Tip-link poses in the base-link frame (4x4, mm) at joint sets ``q`` (n,) or (N, n)."""
        q = np.asarray(q, dtype=float)
        if q.ndim == 1:
            return self._frames(q)[0]
        return np.array([self._frames(qi)[0] for qi in q])

    def point(self, q, p_tip) -> np.ndarray:
        """A point fixed in the tip link (mm) in the base frame, at ``q`` (n,) or (N, n)."""
        T = self.fk(q)
        return T[..., :3, :3] @ np.asarray(p_tip, float) + T[..., :3, 3]

    def point_and_jacobian(self, q, p_tip):
        """The tip point and d point / d q (3, n) at one joint set."""
        T, axes, origins = self._frames(np.asarray(q, dtype=float))
        p = T[:3, :3] @ np.asarray(p_tip, float) + T[:3, 3]
        r = p - origins
        cross = np.stack([axes[:, 1] * r[:, 2] - axes[:, 2] * r[:, 1],
                          axes[:, 2] * r[:, 0] - axes[:, 0] * r[:, 2],
                          axes[:, 0] * r[:, 1] - axes[:, 1] * r[:, 0]], axis=1)
        J = np.where(self.is_revolute[:, None], cross, axes).T
        return p, T, J


# ----------------------------------------------------------------------------------------------
# The true robot
# ----------------------------------------------------------------------------------------------

def perturbed_urdf(text: str, rng, base: str | None = None, tip: str | None = None,
                   mm: float = 0.5, deg: float = 0.05) -> str:
    """A copy of the URDF text with the origin of every joint of the chain ``base -> tip`` (movable
    and fixed) moved by N(0, ``mm``) per xyz component and turned by N(0, ``deg``) per rpy
    component. Joints outside the chain are left as they are."""
    names = {j.name for j in UrdfChain(text, base, tip).joints}
    root = ET.fromstring(text)
    for e in root.findall("joint"):
        if e.get("name") not in names:
            continue
        o = e.find("origin")
        if o is None:
            o = ET.SubElement(e, "origin")
        xyz = _floats(o.get("xyz"), [0, 0, 0]) + rng.normal(0.0, mm / 1000.0, 3)
        rpy = _floats(o.get("rpy"), [0, 0, 0]) + rng.normal(0.0, np.radians(deg), 3)
        o.set("xyz", " ".join(repr(float(v)) for v in xyz))
        o.set("rpy", " ".join(repr(float(v)) for v in rpy))
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


# ----------------------------------------------------------------------------------------------
# Inverse kinematics (position of the ball centre only)
# ----------------------------------------------------------------------------------------------

def _stem_tilt_deg(T, ball, up):
    """Angle (deg) between ``up`` and the stem, the direction from the ball centre to the tip-link
    origin; 0 when the ball hangs straight below the flange. None for a ball at the origin."""
    stem = -(T[:3, :3] @ np.asarray(ball, float))
    norm = np.linalg.norm(stem)
    if norm < 1e-9:
        return None
    return float(np.degrees(np.arccos(np.clip(stem @ up / norm, -1.0, 1.0))))


def _rotation_angle_deg(Ra, Rb):
    c = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def _sample_joints(chain: UrdfChain, rng, n=None):
    """Uniform joint sets within the limits (joints wider than +-pi are sampled in +-pi)."""
    lo = np.maximum(chain.limits[:, 0], np.where(chain.is_revolute, -np.pi, -np.inf))
    hi = np.minimum(chain.limits[:, 1], np.where(chain.is_revolute, np.pi, np.inf))
    return rng.uniform(lo, hi, size=(chain.n,) if n is None else (n, chain.n))


def solve_ik(chain: UrdfChain, target, ball, q0, tol_mm: float = 1e-9):
    """Joint set (rad, mm) within the limits putting ``ball`` (tip frame) at ``target`` (base
    frame), from ``q0``; None if it did not converge to ``tol_mm`` within the limits.

    scipy's least_squares (dogbox, bounded by the limits, loose tolerances) brings it close; a few
    minimum-norm Gauss-Newton steps then polish it to machine precision (least_squares near the
    solution of this underdetermined problem converges only linearly)."""
    target = np.asarray(target, float)
    lo, hi = chain.limits[:, 0], chain.limits[:, 1]
    margin = 1e-6 * (hi - lo)
    q0 = np.clip(q0, lo + margin, hi - margin)

    cache = {}

    def evaluate(q):
        key = q.tobytes()
        if key not in cache:
            cache.clear()
            p, _T, J = chain.point_and_jacobian(q, ball)
            cache[key] = (p - target, J)
        return cache[key]

    def fun(q):
        return evaluate(q)[0]

    def jac(q):
        return evaluate(q)[1]

    sol = least_squares(fun, q0, jac=jac, bounds=(lo, hi), method="dogbox", xtol=1e-2, ftol=1e-2,
                        gtol=1e-2, max_nfev=100)
    q = sol.x
    for _ in range(8):
        p, _T, J = chain.point_and_jacobian(q, ball)
        e = p - target
        if np.linalg.norm(e) < 0.1 * tol_mm:
            break
        try:
            q = q - J.T @ np.linalg.solve(J @ J.T, e)
        except np.linalg.LinAlgError:
            return None
    if not np.linalg.norm(fun(q)) <= tol_mm or np.any(q < lo) or np.any(q > hi):
        return None
    return q


def varied_solutions(chain: UrdfChain, target, ball, rng, count: int, *, min_joint_sep_deg=20.0,
                     min_rotation_deg=10.0, max_tilt_deg=None, up=(0.0, 0.0, 1.0), others=(),
                     max_attempts: int | None = None, give_up_after: int | None = None):
    """Up to ``count`` joint sets (rad, mm) putting ``ball`` at ``target``, each from a random start.

    ``target`` is a point (base frame, mm) or a function returning one, called anew for each
    attempt (a socket plus seating noise, say). Kept solutions are pairwise, and against the joint
    sets ``others``, more than ``min_joint_sep_deg`` apart in joint space (Euclidean norm of the
    difference, deg) and their tip links more than ``min_rotation_deg`` apart in orientation; with
    ``max_tilt_deg`` the stem (ball centre -> tip-link origin) is within that angle of ``up``.
    At most ``max_attempts`` IK solves (12 per wanted solution by default), and none more once
    ``give_up_after`` solves found nothing. Returns (joint sets, their targets), maybe short."""
    up = np.asarray(up, float)
    up = up / np.linalg.norm(up)
    max_attempts = max_attempts or 12 * count
    give_up_after = give_up_after or max_attempts
    kept = [(chain.to_readings(q), chain.fk(q)[:3, :3]) for q in others]
    sols, targets = [], []
    for attempt in range(max_attempts):
        if len(sols) >= count or (not sols and attempt >= give_up_after):
            break
        c = np.asarray(target() if callable(target) else target, dtype=float)
        q = solve_ik(chain, c, ball, _sample_joints(chain, rng))
        if q is None:
            continue
        T = chain.fk(q)
        if max_tilt_deg is not None:
            tilt = _stem_tilt_deg(T, ball, up)
            if tilt is not None and tilt > max_tilt_deg:
                continue
        qd, R = chain.to_readings(q), T[:3, :3]
        if any(np.linalg.norm(qd - qk) <= min_joint_sep_deg or _rotation_angle_deg(R, Rk) <= min_rotation_deg
               for qk, Rk in kept):
            continue
        kept.append((qd, R))
        sols.append(q)
        targets.append(c)
    return sols, targets


# ----------------------------------------------------------------------------------------------
# Datasets
# ----------------------------------------------------------------------------------------------

@dataclass
class ContactTruth:
    """What a generated dataset's robot really was.

    ``q`` are the exact joint sets of the true robot (rad, mm), ``readings`` what ``joints.csv``
    holds (deg, mm: q plus reading noise), ``centres`` the true ball centres there (base frame,
    mm), ``fixtures`` the fixture of each pose (in ``poses`` order)."""
    urdf: str
    chain: dict
    ball: np.ndarray
    poses: np.ndarray
    q: np.ndarray
    readings: np.ndarray
    centres: np.ndarray
    fixtures: list
    sockets: dict = field(default_factory=dict)   # fixture name -> true point (mm, base frame)
    plane: tuple | None = None                    # (unit normal n, offset d): n . x = d on the plane
    seconds: float = 0.0


def _fmt(v) -> str:
    return repr(float(v))


def _write_dataset(out_dir: Path, urdf_path: Path, chain: UrdfChain, ball, radius, noise: dict,
                   fixtures: dict, distances: list, provenance: dict, poses, readings, fixture_of):
    out_dir.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(urdf_path, out_dir / "robot.urdf")
    lines = ["format: fgcal-dataset/1",
             "robot: robot.urdf",
             f"chain: {{base: {chain.base}, tip: {chain.tip}}}",
             "tool:",
             f"  radius: {_fmt(radius)}",
             f"  balls: {{B: [{', '.join(_fmt(v) for v in ball)}]}}",
             "noise: {" + ", ".join(f"{k}: {_fmt(v)}" for k, v in noise.items()) + "}",
             "fixtures:"]
    lines += [f"  {name}: {{type: {kind}}}" for name, kind in fixtures.items()]
    if distances:
        lines += ["constraints:", "  distances:"]
        lines += [f"    - [{a}, {b}, {_fmt(d)}, {_fmt(s)}]" for a, b, d, s in distances]
    lines += ["provenance:"]
    lines += [f"  {k}: {'null' if v is None else v}" for k, v in provenance.items()]
    (out_dir / "dataset.yaml").write_text("\n".join(lines) + "\n")
    header = "pose," + ",".join(f"q{k + 1}" for k in range(chain.n))
    rows = [f"{p}," + ",".join(_fmt(v) for v in r) for p, r in zip(poses, readings)]
    (out_dir / "joints.csv").write_text("\n".join([header] + rows) + "\n")
    rows = [f"{p},B,{f}" for p, f in zip(poses, fixture_of)]
    (out_dir / "contacts.csv").write_text("\n".join(["pose,ball,fixture"] + rows) + "\n")


def _reading_noise(chain, q, rng, joint_sigma_deg, prismatic_sigma_mm=0.0):
    sig = np.where(chain.is_revolute, joint_sigma_deg, prismatic_sigma_mm)
    return chain.to_readings(q) + rng.normal(0.0, 1.0, q.shape) * sig


def _true_robot(urdf_path: Path, chain: dict, rng, true_urdf, perturb_mm, perturb_deg):
    """``(URDF text, UrdfChain)`` of the true robot: ``true_urdf`` if given, else
    :func:`perturbed_urdf` of ``urdf_path``'s chain."""
    base, tip = chain.get("base"), chain.get("tip")
    truth_text = true_urdf if true_urdf is not None else perturbed_urdf(urdf_path.read_text(), rng, base, tip,
                                                                        perturb_mm, perturb_deg)
    return truth_text, UrdfChain(truth_text, base, tip)


def two_socket_dataset(out_dir, urdf_path, chain: dict, rng, n_placements: int = 3,
                       configs_per_socket: int = 15, ball_offset_mm=(0.0, 0.0, 30.0),
                       contact_sigma_mm: float = 0.02, joint_sigma_deg: float = 0.0,
                       distance_mm: float = 50.0, *, distance_sigma_mm: float = 0.005,
                       perturb_mm: float = 0.5, perturb_deg: float = 0.05, true_urdf: str | None = None,
                       min_joint_sep_deg: float = 20.0, min_rotation_deg: float = 10.0,
                       max_tilt_deg: float | None = None, min_radius_mm: float = 150.0,
                       min_height_mm: float = 0.0, seed=None, max_tries: int = 50) -> ContactTruth:
    """Plates with two sockets ``distance_mm`` apart, each socket visited in
    ``configs_per_socket`` varied configurations of the true robot; writes ``out_dir``.

    The true robot is :func:`perturbed_urdf` of ``urdf_path`` (or ``true_urdf`` if given). Each
    plate: socket 0 is the true ball centre at a random joint set, socket 1 ``distance_mm`` away in
    a random horizontal (base x-y) direction; both farther than ``min_radius_mm`` from the base z
    axis and higher than ``min_height_mm``, and both must be reached in ``configs_per_socket``
    configurations (see :func:`varied_solutions`), else the plate is drawn again (up to
    ``max_tries`` times). A seating puts the true ball centre at socket + N(0, contact_sigma_mm)
    per axis; ``joints.csv`` records the exact joint set plus N(0, joint_sigma_deg). Fixtures are
    ``p{k}/hole_0``, ``p{k}/hole_1``; each plate's sockets get one distance constraint."""
    t0 = time.perf_counter()
    out_dir, urdf_path = Path(out_dir), Path(urdf_path)
    truth_text, true = _true_robot(urdf_path, chain, rng, true_urdf, perturb_mm, perturb_deg)
    ball = np.asarray(ball_offset_mm, dtype=float)
    opts = dict(min_joint_sep_deg=min_joint_sep_deg, min_rotation_deg=min_rotation_deg,
                max_tilt_deg=max_tilt_deg)

    def usable(p):
        return np.hypot(p[0], p[1]) > min_radius_mm and p[2] > min_height_mm

    sockets, q_all, centres, fixture_of = {}, [], [], []
    for k in range(n_placements):
        for _ in range(max_tries):
            s0 = true.point(_sample_joints(true, rng), ball)
            a = rng.uniform(0.0, 2.0 * np.pi)
            s1 = s0 + distance_mm * np.array([np.cos(a), np.sin(a), 0.0])
            if not (usable(s0) and usable(s1)):
                continue
            plate = []
            for s in (s0, s1):
                # the seatings: the ball centre at the socket plus seating noise, one IK per target
                sols, seated = varied_solutions(
                    true, lambda s=s: s + rng.normal(0.0, contact_sigma_mm, 3), ball, rng, configs_per_socket,
                    max_attempts=12 * configs_per_socket, give_up_after=3 * configs_per_socket, **opts)
                if len(sols) < configs_per_socket:
                    break
                plate.append((s, sols, seated))
            if len(plate) == 2:
                break
        else:
            raise RuntimeError(f"plate {k}: no two reachable sockets in {max_tries} tries")
        for j, (s, sols, seated) in enumerate(plate):
            name = f"p{k}/hole_{j}"
            sockets[name] = s
            q_all += sols
            centres += seated
            fixture_of += [name] * len(sols)
    q_all = np.array(q_all)
    readings = _reading_noise(true, q_all, rng, joint_sigma_deg)
    poses = np.arange(1, len(q_all) + 1)
    names = list(sockets)
    distances = [(names[2 * k], names[2 * k + 1], distance_mm, distance_sigma_mm) for k in range(n_placements)]
    noise = {"cmm_sigma": 0.01, "joint_resolution": 0.0, "repeatability": joint_sigma_deg,
             "contact_sigma": contact_sigma_mm}
    prov = {"generator": "tests/contact_sim.py", "kind": "two_socket", "seed": seed,
            "perturbation": f"{{mm: {perturb_mm}, deg: {perturb_deg}}}"}
    _write_dataset(out_dir, urdf_path, true, ball, 0.0, noise, {n: "point" for n in names}, distances,
                   prov, poses, readings, fixture_of)
    return ContactTruth(truth_text, {"base": true.base, "tip": true.tip}, ball, poses, q_all, readings,
                        np.array(centres), fixture_of, sockets=sockets, seconds=time.perf_counter() - t0)


def _orthonormal(n):
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(n, a)
    u /= np.linalg.norm(u)
    return u, np.cross(n, u)


def plane_dataset(out_dir, urdf_path, chain: dict, rng, n_contacts: int = 40,
                  ball_radius_mm: float = 5.0, ball_offset_mm=(0.0, 0.0, 30.0),
                  contact_sigma_mm: float = 0.02, joint_sigma_deg: float = 0.0, *,
                  plane_tilt_deg: float = 10.0, patch_radius_mm: float = 300.0,
                  perturb_mm: float = 0.5, perturb_deg: float = 0.05, true_urdf: str | None = None,
                  min_joint_sep_deg: float = 5.0, min_rotation_deg: float = 0.0,
                  max_tilt_deg: float | None = 80.0, min_radius_mm: float = 150.0,
                  min_height_mm: float = 0.0, seed=None, max_tries: int = 50) -> ContactTruth:
    """The tool ball (radius ``ball_radius_mm``) touching an unknown plane (a table) at
    ``n_contacts`` places; writes ``out_dir`` (fixture ``table``, type plane).

    The plane passes below the true ball centre at a random joint set, its normal tilted from the
    base z axis by up to ``plane_tilt_deg`` in a random direction. Contact points are uniform in a
    disc of ``patch_radius_mm`` around that point; at each the true ball centre lies
    ``ball_radius_mm`` + N(0, contact_sigma_mm) from the plane on its normal's side, reached from a
    random start (unreachable points are drawn again). With ``max_tilt_deg`` the stem (ball centre
    -> tip-link origin) is within that angle of the normal, so the tool stands above the table.
    Successive joint sets are more than ``min_joint_sep_deg`` apart."""
    t0 = time.perf_counter()
    out_dir, urdf_path = Path(out_dir), Path(urdf_path)
    truth_text, true = _true_robot(urdf_path, chain, rng, true_urdf, perturb_mm, perturb_deg)
    ball = np.asarray(ball_offset_mm, dtype=float)
    r = float(ball_radius_mm)
    opts = dict(min_joint_sep_deg=min_joint_sep_deg, min_rotation_deg=min_rotation_deg)
    for _ in range(max_tries):
        c0 = true.point(_sample_joints(true, rng), ball)
        if np.hypot(c0[0], c0[1]) > min_radius_mm + patch_radius_mm / 2 and c0[2] > min_height_mm + r:
            break
    else:
        raise RuntimeError("no usable plane centre")
    tilt, az = np.radians(rng.uniform(0.0, plane_tilt_deg)), rng.uniform(0.0, 2.0 * np.pi)
    n = np.array([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)])
    x0 = c0 - r * n  # the plane touches the ball there
    d = float(n @ x0)
    u, v = _orthonormal(n)
    q_all, centres = [], []
    for _attempt in range(20 * n_contacts):
        if len(q_all) == n_contacts:
            break
        rho, phi = patch_radius_mm * np.sqrt(rng.uniform()), rng.uniform(0.0, 2.0 * np.pi)
        x = x0 + rho * (np.cos(phi) * u + np.sin(phi) * v)
        if np.hypot(x[0], x[1]) < min_radius_mm:
            continue
        c = x + (r + rng.normal(0.0, contact_sigma_mm)) * n
        found, _ = varied_solutions(true, c, ball, rng, 1, max_attempts=10, max_tilt_deg=max_tilt_deg, up=n,
                                    others=q_all, **opts)
        if found:
            q_all.append(found[0])
            centres.append(c)
    if len(q_all) < n_contacts:
        raise RuntimeError(f"only {len(q_all)} of {n_contacts} plane contacts reached")
    q_all = np.array(q_all)
    readings = _reading_noise(true, q_all, rng, joint_sigma_deg)
    poses = np.arange(1, len(q_all) + 1)
    noise = {"cmm_sigma": 0.01, "joint_resolution": 0.0, "repeatability": joint_sigma_deg,
             "contact_sigma": contact_sigma_mm}
    prov = {"generator": "tests/contact_sim.py", "kind": "plane", "seed": seed,
            "perturbation": f"{{mm: {perturb_mm}, deg: {perturb_deg}}}"}
    _write_dataset(out_dir, urdf_path, true, ball, r, noise, {"table": "plane"}, [], prov, poses, readings,
                   ["table"] * len(q_all))
    return ContactTruth(truth_text, {"base": true.base, "tip": true.tip}, ball, poses, q_all, readings,
                        np.array(centres), ["table"] * len(q_all), plane=(n, d),
                        seconds=time.perf_counter() - t0)


@dataclass
class NewPoses:
    q: np.ndarray         # exact joint sets (rad, mm)
    readings: np.ndarray  # the same in deg, mm (no noise)
    points: np.ndarray    # true ball centres (mm, base frame)


def new_poses(urdf_true_text: str, chain: dict, ball_offset, rng, n: int) -> NewPoses:
    """``n`` random joint sets within the limits and the TRUE ball centres there (base frame, mm)."""
    true = UrdfChain(urdf_true_text, chain.get("base"), chain.get("tip"))
    q = _sample_joints(true, rng, n)
    return NewPoses(q, true.to_readings(q), true.point(q, np.asarray(ball_offset, float)))


# ----------------------------------------------------------------------------------------------
# Free world frame
# ----------------------------------------------------------------------------------------------

def rigid_align(pred, true):
    """R, t minimising sum |R pred_i + t - true_i|^2 (Kabsch; a proper rotation)."""
    P, Q = np.asarray(pred, float), np.asarray(true, float)
    pc, qc = P.mean(axis=0), Q.mean(axis=0)
    H = (P - pc).T @ (Q - qc)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, qc - R @ pc


def aligned_rms(pred, true) -> float:
    """RMS distance (mm) between predicted and true points (N, 3) after the best rigid alignment."""
    R, t = rigid_align(pred, true)
    e = np.asarray(pred, float) @ R.T + t - np.asarray(true, float)
    return float(np.sqrt(np.mean(np.sum(e * e, axis=1))))
