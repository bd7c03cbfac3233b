"""Which poses to measure: observability indices and optimal experiment design.

The information a pose brings about the parameters uses the estimator's own noise model: each
of its measured balls is a centre fitted to 4 probe points on its accessible cap (covariance
from that geometry and the CMM noise), and the joint readings' noise moves all of a pose's balls
together (``J_q Sigma_q J_q^T``), which is what makes some poses far less informative than their
Jacobian alone suggests. Indices on the information scaled by the expected parameter errors:

* O1 (Borm & Menq): ``(s_1 ... s_L)^(1/L) / sqrt(m)``; O2: ``s_min / s_max``; O3: ``s_min``;
  O4 (noise amplification): ``s_min^2 / s_max``; O5: ``1 / sum(1 / s_i)``;
* ``pred``: the predicted position error RMS (mm) at verification poses drawn like the
  candidates, ``sqrt(trace(W Sigma))``: the accuracy the calibration is for.

Plans are chosen from a candidate pool by a greedy start and the DETMAX exchange (Mitchell
1974: add the best candidate, remove the worst design point, until nothing improves). No I/O.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .dataset import Noise
from .errors import FgcalError
from .kinematics import forward, jacobians
from .model import ParameterSet, RobotModel
from .simulate import PLAN_MARGIN_DEG, PLAN_MARGIN_MM, UP, Deviations, ball_access

__all__ = ["INDICES", "pose_information", "indices", "predicted_rms", "Design", "design_plan", "candidate_pool",
           "verification_weight", "Candidates", "random_design_values"]

INDICES = ("O1", "O2", "O3", "O4", "O5", "pred")


def _cap_information(n_points: int = 4, polar_deg: float = 60.0) -> np.ndarray:
    """Information (3, 3) about a centre from unit-sigma points on a cap around +z (pole + ring)."""
    dirs = [np.array([0.0, 0.0, 1.0])]
    p = np.radians(polar_deg)
    for k in range(n_points - 1):
        a = 2 * np.pi * k / (n_points - 1)
        dirs.append(np.array([np.sin(p) * np.cos(a), np.sin(p) * np.sin(a), np.cos(p)]))
    D = np.array(dirs)
    return D.T @ D


def _frame_from_axis(axis) -> np.ndarray:
    a = axis / np.linalg.norm(axis)
    h = np.array([1.0, 0, 0]) if abs(a[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = np.cross(a, h)
    e1 /= np.linalg.norm(e1)
    return np.column_stack([e1, np.cross(a, e1), a])


def pose_information(model: RobotModel, q, noise: Noise, params: ParameterSet | None = None, slots=None,
                     n_balls: int = 3, probes_per_ball: int = 4):
    """Per-pose information about the parameters, ``(N, P, P)`` (internal units).

    Also returns ``usable`` (N,) bool: the pose shows ``n_balls`` balls to the CMM.
    """
    params = params or model.parameters()
    x = model.nominal if slots is None else np.asarray(slots, dtype=float)
    q = np.atleast_2d(q)
    tooling = model.tooling
    T = forward(x, q)
    ok, upness, _ = ball_access(T, tooling, model.volume)
    offsets = tooling.offsets()
    jac = jacobians(x, q, offsets=offsets)
    cap = _cap_information(probes_per_ball)
    sigma_cmm = max(noise.cmm_sigma, 1e-6)
    sigma_q = np.radians(noise.joint_sigma_deg)
    idx = params.index
    P = len(idx)
    info = np.zeros((len(q), P, P))
    usable = ok.sum(axis=1) >= n_balls
    outward = offsets / np.linalg.norm(offsets, axis=1, keepdims=True)
    for i in np.nonzero(usable)[0]:
        vis = np.nonzero(ok[i])[0]
        balls = vis[np.argsort(-upness[i, vis], kind="stable")[:n_balls]]
        m = 3 * len(balls)
        R = np.zeros((m, m))
        for k, b in enumerate(balls):
            axis = T[i, :3, :3] @ outward[b] + UP
            F = _frame_from_axis(axis)
            R[3 * k:3 * k + 3, 3 * k:3 * k + 3] = F @ np.linalg.inv(cap) @ F.T * sigma_cmm**2
        Jt = jac.point_slots[i, balls][:, :, idx].reshape(m, P)
        Jq = jac.point_joints[i, balls].reshape(m, 6)
        R += sigma_q**2 * Jq @ Jq.T  # the readings move all balls of the pose together
        info[i] = Jt.T @ np.linalg.solve(R, Jt)
    return info, usable


def verification_weight(model: RobotModel, q_verify, params: ParameterSet | None = None, slots=None) -> np.ndarray:
    """``W`` (P, P) with ``trace(W Sigma)`` the mean squared tool-position error at ``q_verify``."""
    params = params or model.parameters()
    x = model.nominal if slots is None else np.asarray(slots, dtype=float)
    J = jacobians(x, np.atleast_2d(q_verify)).pose_slots[:, :3][:, :, params.index]
    return np.einsum("nrp,nrq->pq", J, J) / len(J)


def predicted_rms(info, W) -> float:
    """Predicted position error RMS (mm) at the verification poses of ``W``, given information."""
    try:
        return float(np.sqrt(max(np.trace(W @ np.linalg.inv(info)), 0.0)))
    except np.linalg.LinAlgError:
        return float("inf")


def indices(info, m: int, scale, W=None) -> dict[str, float]:
    """O1-O5 of ``info`` (P, P) scaled by the expected parameter errors ``scale`` (P,), and ``pred``."""
    s = np.sqrt(np.clip(np.linalg.eigvalsh(info * np.outer(scale, scale)), 0.0, None))[::-1]
    out = {"O1": float(np.exp(np.mean(np.log(np.maximum(s, 1e-300)))) / np.sqrt(m)),
           "O2": float(s[-1] / s[0]) if s[0] > 0 else 0.0, "O3": float(s[-1]),
           "O4": float(s[-1] ** 2 / s[0]) if s[0] > 0 else 0.0,
           "O5": float(1.0 / np.sum(1.0 / np.maximum(s, 1e-300)))}
    if W is not None:
        out["pred"] = predicted_rms(info, W)
    return out


def _scores(infos, scale, index: str, W=None) -> np.ndarray:
    """Criterion (larger is better) for a batch of information matrices (K, P, P)."""
    if index == "pred":
        try:
            cov = np.linalg.inv(infos)
        except np.linalg.LinAlgError:
            return np.array([-predicted_rms(I, W) for I in infos])
        return -np.sqrt(np.clip(np.einsum("pq,kqp->k", W, cov), 0.0, None))
    s = np.sqrt(np.clip(np.linalg.eigvalsh(infos * np.outer(scale, scale)[None]), 1e-300, None))
    if index == "O1":
        return np.mean(np.log(s), axis=1)  # log of det^(1/L): same order, no overflow
    if index == "O2":
        return s[:, 0] / s[:, -1]
    if index == "O3":
        return s[:, 0]
    if index == "O4":
        return s[:, 0] ** 2 / s[:, -1]
    if index == "O5":
        return 1.0 / np.sum(1.0 / s, axis=1)
    raise FgcalError(f"unknown index {index!r} ({', '.join(INDICES)})")


@dataclass
class Design:
    """A chosen plan: joint sets (rad), their indices in the pool, and its index values."""

    q: np.ndarray
    chosen: np.ndarray
    values: dict[str, float]
    index: str
    iterations: int


def candidate_pool(model: RobotModel, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` random joint sets (rad) whose balls the CMM reaches on the nominal robot, with the
    planning margins (the actual robot is a few mm off)."""
    lo, hi = model.joint_limits[:, 0], model.joint_limits[:, 1]
    out = []
    while sum(len(o) for o in out) < n:
        q = rng.uniform(lo, hi, size=(4 * n, 6))
        ok, _, _ = ball_access(forward(model.nominal, q), model.tooling, model.volume, PLAN_MARGIN_MM,
                               PLAN_MARGIN_DEG)
        out.append(q[ok.sum(axis=1) >= 3])
    return np.vstack(out)[:n]


@dataclass
class Candidates:
    """A candidate pool with each pose's information and the verification weight."""

    q: np.ndarray
    info: np.ndarray
    usable: np.ndarray
    W: np.ndarray
    scale: np.ndarray

    @classmethod
    def build(cls, model: RobotModel, candidates, noise: Noise, q_verify=None, deviations: Deviations = Deviations()):
        params = model.parameters()
        info, usable = pose_information(model, candidates, noise, params)
        W = verification_weight(model, candidates if q_verify is None else q_verify, params)
        return cls(np.asarray(candidates, dtype=float), info, usable, W, deviations.sigmas(params.names))

    def values(self, sel) -> dict[str, float]:
        """O1-O5 and ``pred`` of the plan made of candidates ``sel``."""
        return indices(self.info[sel].sum(axis=0), len(sel), self.scale, self.W)


def design_plan(model: RobotModel, n_poses: int, candidates, noise: Noise, index: str = "pred",
                q_verify=None, deviations: Deviations = Deviations(), max_iterations: int = 200,
                ridge: float = 1e-9, prepared: Candidates | None = None) -> Design:
    """Choose ``n_poses`` of ``candidates`` (K, 6) rad maximising ``index`` (greedy, then DETMAX).

    ``q_verify`` (default: the candidates) are the poses whose accuracy ``pred`` predicts;
    ``prepared`` reuses a :class:`Candidates` built once for several designs.
    """
    if index not in INDICES:
        raise FgcalError(f"unknown index {index!r} ({', '.join(INDICES)})")
    prep = prepared or Candidates.build(model, candidates, noise, q_verify, deviations)
    scale, W = prep.scale, prep.W
    pool = np.nonzero(prep.usable)[0]
    if len(pool) < n_poses:
        raise FgcalError(f"only {len(pool)} usable candidates for {n_poses} poses")
    info = prep.info[pool]
    # A vanishing ridge (relative to the parameters' expected spread) makes the first, rank
    # deficient steps of the greedy start well defined; it does not change the final choice.
    base = np.diag(ridge / scale**2)
    chosen: list[int] = []
    total = base.copy()
    for _ in range(n_poses):
        scores = _scores(total[None] + info, scale, index, W)
        scores[chosen] = -np.inf
        j = int(np.argmax(scores))
        chosen.append(j)
        total = total + info[j]

    def score_of(sel):
        return float(_scores((base + info[sel].sum(axis=0))[None], scale, index, W)[0])

    best = score_of(chosen)
    it = 0
    for it in range(1, max_iterations + 1):
        # DETMAX excursion of size one: add the best candidate, then drop the weakest point.
        total = base + info[chosen].sum(axis=0)
        add = _scores(total[None] + info, scale, index, W)
        add[chosen] = -np.inf
        j = int(np.argmax(add))
        grown = chosen + [j]
        drop = _scores((total + info[j])[None] - info[grown], scale, index, W)
        k = int(np.argmax(drop))
        new = [c for i, c in enumerate(grown) if i != k]
        new_score = score_of(new)
        if new_score <= best + 1e-12 * abs(best):
            break
        chosen, best = new, new_score
    sel = pool[np.array(chosen)]
    return Design(prep.q[sel], sel, prep.values(sel), index, it)


def random_design_values(prepared: Candidates, n_poses: int, rng: np.random.Generator):
    """A random ``n_poses`` subset of the usable candidates and its index values (for comparison)."""
    sel = rng.choice(np.nonzero(prepared.usable)[0], size=n_poses, replace=False)
    return sel, prepared.values(sel)
