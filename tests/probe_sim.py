"""An independent simulator of CMM probing of a 5-link DH arm (the PUMA 560 set-up), for scoring plans.

Nothing here uses fgcal's kinematics: the forward kinematics is :mod:`plain_dh` (plain 4x4
matrices), the robot is read from its model file with PyYAML, the instrument's access rule (the
whole ball inside the measuring volume, its free side within 110 deg of +z, the most upward balls
first) and the probe pattern (the cap's pole and a ring 45-75 deg from it) are written out here,
and the dataset is written as plain text in fgcal's dataset format (``fgcal-dataset/1``).

Joint readings are rounded afresh for each simulated robot: the arm stops within half a
resolution step of the commanded joints (uniformly), the controller reports the rounded value,
so a plan's rounding errors are a new draw for every truth (a plan's commanded joints would
otherwise carry one fixed draw of them).

Units: mm and degrees throughout.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import yaml
from plain_dh import fk_from_truth

BLOCKS = ("base", "j1", "j2", "j3", "j4", "j5", "tool")
LINK_FIELDS = ("theta", "d", "a", "alpha", "beta")
FRAME_FIELDS = ("phi", "theta", "psi", "px", "py", "pz")
MAX_APPROACH_DEG = 110.0


def read_robot(path) -> dict:
    """The model file (``fgcal-robot/1``) as a dict: ``nominal`` {slot name: mm/deg}, ``balls``
    {name: (3,) mm}, ``radius``, ``volume`` (2, 3) mm, ``limits`` (6, 2) deg."""
    data = yaml.safe_load(Path(path).read_text())
    nominal = {f"base.{f}": float(data["base"].get(f, 0.0)) for f in FRAME_FIELDS}
    nominal.update({f"tool.{f}": float(data["tool"].get(f, 0.0)) for f in FRAME_FIELDS})
    for n, row in enumerate(data["links"], start=1):
        nominal.update({f"j{n}.{f}": float(row.get(f, 0.0)) for f in LINK_FIELDS})
    vol = data["volume"]
    return {"nominal": nominal, "balls": {k: np.array(v, dtype=float) for k, v in data["tooling"]["balls"].items()},
            "radius": float(data["tooling"]["radius"]), "volume": np.array([vol["min"], vol["max"]], dtype=float),
            "limits": np.array(data["joint_limits"], dtype=float), "name": data["name"]}


def perturbed(robot: dict, names, rng: np.random.Generator, length=0.5, angle=0.05, base_length=5.0,
              base_angle=0.5) -> dict:
    """A true robot: the nominal with Gaussian deviations of the slots ``names`` (mm, deg)."""
    truth = dict(robot["nominal"])
    for name in names:
        block, f = name.split(".")
        is_angle = f in ("phi", "theta", "psi", "alpha", "beta")
        sd = (base_angle if is_angle else base_length) if block == "base" else (angle if is_angle else length)
        truth[name] += rng.normal() * sd
    return truth


def _access(robot: dict, T: np.ndarray, margin_mm: float = 0.0):
    """Per ball: reachable (bool), upness (cosine of its free side with +z) and centre (mm)."""
    ok, up, centres = {}, {}, {}
    lo, hi = robot["volume"]
    r = robot["radius"] + margin_mm
    for name, off in robot["balls"].items():
        c = T[:3, :3] @ off + T[:3, 3]
        out = T[:3, :3] @ (off / np.linalg.norm(off))
        up[name] = float(out[2])
        centres[name] = c
        ok[name] = bool(up[name] >= math.cos(math.radians(MAX_APPROACH_DEG)) and np.all(c - r >= lo)
                        and np.all(c + r <= hi))
    return ok, up, centres


def measured_balls(robot: dict, T: np.ndarray, n_balls: int = 3):
    """The ``n_balls`` most upward reachable balls at tool pose ``T`` (4, 4) and their centres, or
    None when fewer are reachable."""
    ok, up, centres = _access(robot, T)
    names = sorted((b for b in ok if ok[b]), key=lambda b: -up[b])
    if len(names) < n_balls:
        return None
    return {b: centres[b] for b in sorted(names[:n_balls])}


def random_poses(robot: dict, truth: dict, n: int, rng: np.random.Generator, n_balls: int = 3) -> np.ndarray:
    """``n`` uniform joint sets (deg) within the limits at which the true robot shows ``n_balls`` balls."""
    lo, hi = robot["limits"][:, 0], robot["limits"][:, 1]
    lo, hi = np.maximum(lo, -180.0), np.minimum(hi, 180.0)  # joints wider than a turn: one turn
    out = []
    while len(out) < n:
        q = rng.uniform(lo, hi)
        if measured_balls(robot, fk_from_truth(truth, q), n_balls) is not None:
            out.append(q)
    return np.array(out)


def _cap(axis, rng, n_points=4):
    axis = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    start = rng.uniform(0, 2 * math.pi)
    dirs = [axis]
    for i in range(n_points - 1):
        polar = math.radians(rng.uniform(45.0, 75.0))
        az = start + 2 * math.pi * i / (n_points - 1) + rng.uniform(-0.2, 0.2)
        dirs.append(math.cos(polar) * axis + math.sin(polar) * (math.cos(az) * e1 + math.sin(az) * e2))
    return np.array(dirs)


def _write_dataset(out_dir, robot: dict, robot_file, cmm_sigma, joint_resolution, joints, level, rows) -> None:
    """``dataset.yaml`` (the robot file, its tooling, the noise), ``joints.csv`` and ``LEVEL.csv``
    (``rows``: the CSV lines, header first) in ``out_dir``."""
    balls = "\n".join(f"    {b}: [{', '.join(repr(float(v)) for v in off)}]" for b, off in robot["balls"].items())
    (out_dir / "dataset.yaml").write_text(
        f"format: fgcal-dataset/1\nrobot: {robot_file}\ntool:\n  radius: {robot['radius']}\n  balls:\n{balls}\n"
        f"noise: {{cmm_sigma: {cmm_sigma}, joint_resolution: {joint_resolution}, repeatability: 0.0}}\n"
        "provenance: {generator: tests/probe_sim.py}\n")
    (out_dir / "joints.csv").write_text("\n".join(joints) + "\n")
    (out_dir / f"{level}.csv").write_text("\n".join(rows) + "\n")


def probe_dataset(out_dir, robot: dict, robot_file, truth: dict, q_commanded_deg, rng: np.random.Generator,
                  cmm_sigma=0.01, joint_resolution=0.01, n_balls=3, probes_per_ball=4) -> int:
    """Probe the true robot at the commanded joints (N, 6) deg and write the dataset to ``out_dir``.

    Returns the number of poses written (a pose whose balls the true robot does not show is
    left out, as an operator would skip it)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    joints, probes = ["pose," + ",".join(f"q{k}" for k in range(1, 7))], ["pose,ball,x,y,z"]
    n = 0
    for i, qc in enumerate(np.atleast_2d(q_commanded_deg), start=1):
        step = joint_resolution
        actual = qc + (rng.uniform(-0.5, 0.5, size=qc.shape) * step if step > 0 else 0.0)
        reading = np.round(actual / step) * step if step > 0 else actual
        T = fk_from_truth(truth, actual)
        balls = measured_balls(robot, T, n_balls)
        if balls is None:
            continue
        n += 1
        joints.append(f"{i}," + ",".join(repr(float(v)) for v in reading))
        for name, c in balls.items():
            outward = T[:3, :3] @ (robot["balls"][name] / np.linalg.norm(robot["balls"][name]))
            dirs = _cap(outward + np.array([0.0, 0.0, 1.0]), rng, probes_per_ball)
            pts = c + robot["radius"] * dirs + rng.normal(size=dirs.shape) * cmm_sigma
            probes += [f"{i},{name}," + ",".join(repr(float(v)) for v in p) for p in pts]
    _write_dataset(out_dir, robot, robot_file, cmm_sigma, joint_resolution, joints, "probes", probes)
    return n


def position_rms(truth: dict, estimate: dict, q_deg) -> float:
    """RMS (mm) over joint sets ``q_deg`` (N, 6) of the distance between the tool points of two robots."""
    d = [fk_from_truth(truth, q)[:3, 3] - fk_from_truth(estimate, q)[:3, 3] for q in np.atleast_2d(q_deg)]
    return float(np.sqrt(np.mean(np.sum(np.square(d), axis=1))))


def droop_deg(q_deg, gain_deg=0.02):
    """A non-geometric joint error (deg) no DH model has: the shoulder and elbow sag under the arm's
    weight (a torque of cos q2 and cos(q2 + q3)), the wrist wobbles once a turn; ``gain_deg`` its size."""
    q = np.radians(np.atleast_2d(q_deg))
    out = np.zeros_like(q)
    out[:, 1] = gain_deg * (np.cos(q[:, 1]) + 0.5 * np.cos(q[:, 1] + q[:, 2]))
    out[:, 2] = 0.5 * gain_deg * np.cos(q[:, 1] + q[:, 2])
    out[:, 3] = 0.5 * gain_deg * np.sin(3 * q[:, 3])
    return out


def centre_dataset(out_dir, robot: dict, robot_file, truth: dict, q_commanded_deg, rng: np.random.Generator,
                   cmm_sigma=0.01, joint_resolution=0.01, n_balls=3, unmodelled=None, pose_ids=None) -> list[int]:
    """Measure the ball centres of the true robot at the commanded joints (N, 6) deg (fresh rounding
    as :func:`probe_dataset`); ``unmodelled(q_deg) -> dq_deg`` moves the arm away from its readings
    (an error of the robot no geometric model has). Writes ``centres.csv``; returns the pose ids
    written (a pose whose balls the true robot does not show is left out)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    q_c = np.atleast_2d(q_commanded_deg)
    ids = np.arange(1, len(q_c) + 1) if pose_ids is None else np.asarray(pose_ids, dtype=int)
    joints, centres, kept = ["pose," + ",".join(f"q{k}" for k in range(1, 7))], ["pose,ball,x,y,z"], []
    step = joint_resolution
    for pid, qc in zip(ids, q_c, strict=True):
        actual = qc + (rng.uniform(-0.5, 0.5, size=qc.shape) * step if step > 0 else 0.0)
        reading = np.round(actual / step) * step if step > 0 else actual
        arm = actual + (unmodelled(actual)[0] if unmodelled is not None else 0.0)
        balls = measured_balls(robot, fk_from_truth(truth, arm), n_balls)
        if balls is None:
            continue
        kept.append(int(pid))
        joints.append(f"{pid}," + ",".join(repr(float(v)) for v in reading))
        centres += [f"{pid},{b}," + ",".join(repr(float(v)) for v in c + rng.normal(size=3) * cmm_sigma)
                    for b, c in balls.items()]
    _write_dataset(out_dir, robot, robot_file, cmm_sigma, joint_resolution, joints, "centres", centres)
    return kept
