"""Where the simulated instrument can measure, and the pose plans of the paper's studies.

:func:`ball_access` says which tool balls a CMM probing from above can reach at given tool
poses (inside its measuring volume, stems not pointing away); :func:`random_plan` draws random
joint sets whose balls it can reach; :func:`paper_plan` is the paper's experiment, 12 points of
a parallelepiped each reached in four arm configurations. Units: mm and rad. No I/O here.
"""
from __future__ import annotations

import numpy as np

from fgcal.errors import FgcalError
from fgcal.robots.ik import BRANCHES, solve_puma_batch
from fgcal.robots.kinematics import forward, tool_points
from fgcal.robots.model import RobotModel, Tooling
from fgcal.robots.transforms import quaternion_to_matrix

__all__ = ["PLAN_MARGIN_DEG", "PLAN_MARGIN_MM", "UP", "ball_access", "paper_plan", "paper_points", "random_plan"]

UP = np.array([0.0, 0.0, 1.0])  # the CMM's probe comes down from +z of the world
MAX_APPROACH_ANGLE_DEG = 110.0  # a ball whose stem points up more steeply than this is hidden
# The actual base may sit several mm and ~0.5 deg off nominal; with ~1 m lever arms that moves
# the tool by up to ~25 mm, so nominal plans keep this far from the edges.
PLAN_MARGIN_MM = 30.0
PLAN_MARGIN_DEG = 5.0




def ball_access(T, tooling: Tooling, volume=None, margin_mm: float = 0.0, margin_deg: float = 0.0):
    """Which balls the CMM can probe at tool poses ``T`` (N, 4, 4).

    A ball is reachable when the whole ball is inside the measuring ``volume`` (2, 3) and its
    free side faces the probe: the direction from the tool axis out to the ball (its stem
    holds it from the other side) is within ``MAX_APPROACH_ANGLE_DEG`` of the world's +z.
    A planner that knows only the nominal robot asks for margins (``margin_mm`` inside the
    volume, ``margin_deg`` inside the angle) so that the actual robot still reaches the balls.

    Returns
    -------
    ok : ndarray of bool, shape (N, B)
    upness : ndarray, shape (N, B)
        Cosine between the ball's free side and +z (larger is easier to probe).
    centres : ndarray, shape (N, B, 3)
        Ball centres in the world (mm).
    """
    offsets = tooling.offsets()
    centres = tool_points(T, offsets)
    norms = np.linalg.norm(offsets, axis=1, keepdims=True)
    # A ball on the tool axis (a reflector at the flange) faces along the tool's z axis.
    outward = np.where(norms > 1e-9, offsets / np.maximum(norms, 1e-300), np.array([0.0, 0.0, 1.0]))
    outward_w = np.einsum("nij,bj->nbi", T[:, :3, :3], outward)
    upness = outward_w @ UP
    if tooling.radius > 0:
        ok = upness >= np.cos(np.radians(MAX_APPROACH_ANGLE_DEG - margin_deg))
    else:  # a tracker reflector: seen wherever it is inside the tracker's volume
        ok = np.ones(upness.shape, dtype=bool)
    if volume is not None:
        r = tooling.radius + margin_mm
        ok &= np.all((centres - r >= volume[0]) & (centres + r <= volume[1]), axis=2)
    return ok, upness, centres


def random_plan(model: RobotModel, slots, n_poses: int, rng: np.random.Generator, tooling: Tooling,
                volume=None, n_balls: int = 3, max_tries: int = 200_000) -> np.ndarray:
    """``n_poses`` random joint sets (N, n) within the limits with ``n_balls`` reachable balls.

    Revolute joints with limits wider than a turn are drawn within one turn (+-180 deg).
    """
    lo, hi = model.joint_limits[:, 0], model.joint_limits[:, 1]
    wide = model.joint_is_angle & (hi - lo > 2 * np.pi)
    lo, hi = np.where(wide, np.maximum(lo, -np.pi), lo), np.where(wide, np.minimum(hi, np.pi), hi)
    accepted: list[np.ndarray] = []
    tries = 0
    while len(accepted) < n_poses:
        batch = max(256, 4 * (n_poses - len(accepted)))
        q = rng.uniform(lo, hi, size=(batch, model.n_joints))
        tries += batch
        ok, _, _ = ball_access(model.forward(slots, q), tooling, volume)
        good = q[ok.sum(axis=1) >= n_balls]
        accepted.extend(good[: n_poses - len(accepted)])
        if tries >= max_tries and len(accepted) < n_poses:
            raise FgcalError(f"only {len(accepted)} of {n_poses} random poses in {tries} tries have {n_balls} balls "
                             "inside the measuring volume; enlarge the volume or ask for fewer balls")
    return np.array(accepted)


def _random_rotations(rng, n) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return quaternion_to_matrix(q)


def paper_points(box) -> np.ndarray:
    """The 12 experiment points on a parallelepiped ``box`` (2, 3): 8 corners, 4 side-face centres."""
    lo, hi = np.asarray(box, dtype=float)
    mid = (lo + hi) / 2
    corners = np.array([[x, y, z] for z in (lo[2], hi[2]) for y in (lo[1], hi[1]) for x in (lo[0], hi[0])])
    faces = np.array([[lo[0], mid[1], mid[2]], [hi[0], mid[1], mid[2]], [mid[0], lo[1], mid[2]], [mid[0], hi[1], mid[2]]])
    return np.vstack([corners, faces])


def paper_plan(model: RobotModel, rng: np.random.Generator, tooling: Tooling, volume=None, box=None,
               n_balls: int = 3, n_orientations: int = 3000):
    """The paper's experiment: 12 points x (lefty, righty) x (elbow up, down) = 48 poses.

    At each point and arm configuration, the tool orientation is chosen among ``n_orientations``
    random ones so that the wrist joints go as far towards their limits as the joint limits
    and the CMM's access to ``n_balls`` balls allow (as the paper did), preferring wrist
    settings unlike those already used. Planning uses the nominal model (the operator's).

    Returns
    -------
    q : ndarray, shape (M, 6)
        Joint sets (rad), M = 48 when every point is reachable in every configuration.
    labels : list of str
        ``"point k righty/up/noflip"`` for each joint set.
    skipped : list of str
        The point and configuration pairs with no feasible orientation, and why.
    """
    box = model.paper_box if box is None else np.asarray(box, dtype=float)
    if box is None:
        raise FgcalError(f"robot model {model.name} has no paper_box: the paper plan needs one")
    points = paper_points(box)
    lo, hi = model.joint_limits[:, 0], model.joint_limits[:, 1]
    half_range = np.maximum(np.abs(lo), np.abs(hi))[3:]
    rotations = _random_rotations(rng, n_orientations)
    chosen: list = []
    labels: list[str] = []
    skipped: list = []
    for k, p in enumerate(points):
        targets = np.zeros((n_orientations, 4, 4))
        targets[:, :3, :3] = rotations
        targets[:, :3, 3] = p
        targets[:, 3, 3] = 1.0
        for righty in (True, False):
            for elbow_up in (True, False):
                cands, names = [], []
                for branch in BRANCHES:
                    if branch.righty != righty or branch.elbow_up != elbow_up:
                        continue
                    q, reachable = solve_puma_batch(model, targets, branch)
                    good = reachable & model.in_limits(np.nan_to_num(q, nan=1e9))
                    if good.any():
                        ok, _, _ = ball_access(forward(model.nominal, q[good]), tooling, volume,
                                               PLAN_MARGIN_MM, PLAN_MARGIN_DEG)
                        feasible = q[good][ok.sum(axis=1) >= n_balls]
                        # Joint 6 may turn past +-180 deg: the same pose, more wrist travel.
                        for turn in (-2 * np.pi, 2 * np.pi):
                            alt = feasible.copy()
                            alt[:, 5] += turn
                            feasible = np.vstack([feasible, alt[model.in_limits(alt)]])
                        cands.append(feasible)
                        names += [str(branch)] * len(feasible)
                config = f"{'righty' if righty else 'lefty'}/{'up' if elbow_up else 'down'}"
                candidates = np.vstack(cands) if cands else np.zeros((0, 6))
                if not len(candidates):
                    skipped.append(f"point {k} {config}: no tool orientation within the joint limits "
                                   f"with {n_balls} balls inside the measuring volume")
                    continue
                wrist = candidates[:, 3:] / half_range
                excursion = np.abs(wrist).mean(axis=1)
                if chosen:
                    used = np.array([c[3:] for c in chosen]) / half_range
                    spread = np.min(np.linalg.norm(wrist[:, None, :] - used[None], axis=2), axis=1)
                else:
                    spread = np.zeros(len(candidates))
                best = int(np.argmax(excursion + 0.5 * spread))
                chosen.append(candidates[best])
                labels.append(f"point {k} {names[best]}")
    return np.array(chosen).reshape(-1, 6), labels, skipped
