"""The calibration problem as a factor graph over parameters, joints and ball centres.

Variables: the parameter vector ``theta`` (P), each pose's joints ``q_i`` (n, rad or mm; only when
the readings carry noise) and each probed ball's centre ``c_ib`` (3, mm). Factors (see the
``factors`` package): probe points on spheres around ``c_ib``; ``c_ib`` at the forward
kinematics (a tight "kinematic" factor whose sigma is the unmodelled error); measured centres
and poses against the forward kinematics; joint readings as priors on ``q_i``; an optional prior
on ``theta``.

Every pose's variables touch only that pose's factors and ``theta``: the graph is an arrow.
:class:`Graph` evaluates all factors at once with the batched error functions and stores the
whitened Jacobian in per-pose blocks (padded to equal size), so a Gauss-Newton step eliminates
the per-pose variables in one batched Schur complement. :func:`fgcal.estimation.gtsam_graph.to_gtsam` turns the same
linearisation (or the nonlinear factors) into GTSAM graphs. No I/O here.
"""
from __future__ import annotations

from functools import cached_property
from typing import Literal

import numpy as np

import factors.errors as fx
from fgcal.estimation.column_groups import PoseColumns, setup_columns
from fgcal.estimation.elimination import POSE_CHUNK, ArrowElimination
from fgcal.estimation.graph_block import JointErrorColumns, compact_design
from fgcal.estimation.graph_types import Linearisation, Sigmas, State, _robust
from fgcal.measurements.types import BY_LEVEL, kinematic_levels
from fgcal.robots.kinematics import jacobians
from fgcal.robots.model import ParameterSet

__all__ = ["LEVELS", "Graph", "Sigmas", "State"]

LEVELS = ("probes", "kinematic", *BY_LEVEL, "joints", "prior")


class Graph(ArrowElimination, JointErrorColumns):
    """The factor graph of one dataset, laid out for batched evaluation.

    Parameters
    ----------
    params : ParameterSet
        Estimated parameters; the other slots are held at ``held``.
    held : ndarray, shape (37,)
    readings : ndarray, shape (N, n)
        Joint readings (rad).
    sigmas : Sigmas
    probes : tuple (pose_index (Mp,), ball_var (Mp,), xyz (Mp, 3)) or None
        ``ball_var`` indexes ``ball_pose``/``ball_offset``.
    ball_pose, ball_offset : ndarray, shapes (Nb,), (Nb, 3)
        The ball-centre variables: their pose index and tool-frame offset.
    radius : float
    measurements : dict of level to Terms, optional
        The kinematic measurements (ball centres, poses, ballbar lengths, ...), each a
        :class:`fgcal.measurements.base.Terms` of its type in :mod:`fgcal.measurements.types`.
    prior : tuple (mean (P,), sigma (P,)) or None
    robust : {None, "huber", "cauchy"}, robust_k : float
    joint_errors : ndarray, shape (N, n, K), or tuple (g (N, K), joints (K,)), optional
        ``G`` of a joint-error block (:mod:`fgcal.estimation.joint_errors`) whose K parameters follow the
        geometric ones in ``theta``: the joints are ``reading + G @ theta[n_geo:n_geo + K]``. Each
        parameter corrects one joint: the compact form gives that joint and ``G``'s entry there
        (:meth:`~fgcal.estimation.joint_errors.JointErrorBlock.design_columns`), which is all the
        graph keeps.
    setup : fgcal.measurements.setup.SetupLayout, optional
        The set-up unknowns (fixtures, planes); their free entries close ``theta`` (after the
        joint-error block). Measurement types with ``uses_setup`` see them; the known distances
        between fixture points are global rows beside the prior's.
    """

    def __init__(self, params: ParameterSet, held, readings, sigmas: Sigmas, *, probes=None, ball_pose=None,
                 ball_offset=None, radius=0.0, measurements=None, prior=None, robust=None,
                 robust_k=None, joint_errors=None, setup=None):
        self.params = params
        self.index = params.index
        self.held = np.asarray(held, dtype=float)
        self.chain = params.model.chain
        self.n_joints = nj = params.model.n_joints
        self.readings = np.asarray(readings, dtype=float).reshape(-1, nj)
        self.sigmas = sigmas
        self.radius = float(radius)
        self.robust = robust
        self.robust_k = robust_k if robust_k is not None else {"huber": 1.345, "cauchy": 2.385, None: 0.0}[robust]
        self.prior = prior
        self.excluded = {}  # level -> bool mask over its factors (set by the outlier handling)
        self._last: tuple | None = None  # the remembered linearisation (see linearise)
        self.joint_vars = bool(np.all(np.asarray(sigmas.joint) > 0))
        # --- joint-error block (fgcal.estimation.joint_errors): theta = [geometry (n_geo), phi (K)]
        self.n_geo = len(self.index)
        self.g, self.g_joint = compact_design(joint_errors, len(self.readings), nj)
        self.K = self.g.shape[1]
        self.setup = setup
        self.S = 0 if setup is None else setup.n_free
        self._setup_col = None if setup is None else self.n_geo + self.K + setup.column()  # < n_geo+K: fixed
        # The pose columns the theta Jacobian is formed on (set-up unknowns): False until the first
        # linearisation has shown which set-up columns each pose's rows touch, then None (dense) or them.
        self._pose_columns: PoseColumns | Literal[False] | None = False if self.S else None
        n = len(self.readings)
        self.n_poses = n
        nb = 0 if ball_pose is None else len(ball_pose)
        self.ball_pose = np.zeros(0, dtype=int) if ball_pose is None else np.asarray(ball_pose, dtype=int)
        self.ball_offset = np.zeros((0, 3)) if ball_offset is None else np.asarray(ball_offset, dtype=float)
        self.probes = probes
        measurements = measurements or {}
        unknown = set(measurements) - set(BY_LEVEL)
        if unknown:
            raise ValueError(f"unknown measurement level(s) {', '.join(sorted(unknown))}")
        # In registry order: the row layout does not depend on the caller's dict order.
        self.measurements = {t.level: measurements[t.level] for t in kinematic_levels(measurements)}

        # Local variable columns: [q (n, if variables)] then 3 per ball variable of the pose.
        qdim = nj if self.joint_vars else 0
        balls_per_pose = np.bincount(self.ball_pose, minlength=n) if nb else np.zeros(n, dtype=int)
        order = np.argsort(self.ball_pose, kind="stable")
        self._balls_by_pose = order
        self.ball_slot = np.empty(nb, dtype=int)
        self.ball_slot[order] = np.arange(nb) - np.searchsorted(self.ball_pose[order], self.ball_pose[order])
        # Each pose's ball offsets, padded: the kinematics of a pose's balls is one evaluation.
        self.pose_offsets = np.zeros((n, int(balls_per_pose.max()) if nb else 0, 3))
        self.pose_offsets[self.ball_pose, self.ball_slot] = self.ball_offset
        self.ball_col = qdim + 3 * self.ball_slot
        self.nz = qdim + 3 * (int(balls_per_pose.max()) if nb else 0)
        self.local_used = np.zeros((n, self.nz), dtype=bool)
        self.local_used[:, :qdim] = True
        self.local_used[self.ball_pose[:, None], self.ball_col[:, None] + np.arange(3)] = True

        # Rows per pose, in this order: kinematic, centres, poses (the rows that depend on theta,
        # so that J_theta holds only the first ``m_theta`` rows of each pose), probes, joints.
        rows = np.zeros(n, dtype=int)

        def take(pose_index, width):
            pose_index = np.asarray(pose_index, dtype=int)
            # Rows already taken by earlier measurements of the same pose, in input order.
            order = np.argsort(pose_index, kind="stable")
            sorted_p = pose_index[order]
            first = np.searchsorted(sorted_p, sorted_p)
            start = np.empty(len(pose_index), dtype=int)
            start[order] = rows[sorted_p] + width * (np.arange(len(sorted_p)) - first)
            rows[:] += width * np.bincount(pose_index, minlength=n)
            return start

        self.row = {}
        self.level_rows: dict[str, np.ndarray] = {}
        if nb:
            self.row["kinematic"] = take(self.ball_pose, 3)
        for level, terms in self.measurements.items():
            self.row[level] = take(terms.pose, BY_LEVEL[level].width)
        if self.joint_vars and self.K:  # the joint-error block enters the joint rows
            self.row["joints"] = take(np.arange(n), nj)
        self.m_theta = int(rows.max()) if n else 0
        if probes is not None:
            self.row["probes"] = take(probes[0], 1)
        if self.joint_vars and not self.K:
            self.row["joints"] = take(np.arange(n), nj)
        self.m = int(rows.max()) if n else 0
        self.rows_per_pose = rows

    @cached_property
    def ball_rows(self) -> list:
        """Per pose, each ball's ``(ball variable, its probe and kinematic rows)`` (for GTSAM factors)."""
        n, nb, probes = self.n_poses, len(self.ball_pose), self.probes
        ball_rows: list[list[tuple[int, np.ndarray]]] = [[] for _ in range(n)]
        per_ball: dict[int, list[int]] = {j: [] for j in range(nb)}
        if probes is not None:
            for j, start in zip(probes[1], self.row["probes"]):
                per_ball[int(j)].append(int(start))
        if nb:
            for j, start in enumerate(self.row["kinematic"]):
                per_ball[j] += [int(start), int(start) + 1, int(start) + 2]
        for j, rws in per_ball.items():
            ball_rows[self.ball_pose[j]].append((j, np.array(sorted(rws), dtype=int)))
        return ball_rows

    @cached_property
    def pose_rows(self) -> list:
        """Per pose, the rows that touch only theta and q (kinematic measurements, joints)."""
        pose_rows: list[list] = [[] for _ in range(self.n_poses)]
        for level in [*self.measurements, "joints"]:
            if level in self.row:
                pose, rows_ = self.factor_rows(level)
                for p, r in zip(pose.tolist(), rows_):
                    pose_rows[p] += r.tolist()
        return [np.array(r, dtype=int) for r in pose_rows]

    # ------------------------------------------------------------------ evaluation
    def initial_state(self, theta, centres_guess=None) -> State:
        c = np.zeros((len(self.ball_pose), 3)) if centres_guess is None else np.asarray(centres_guess, dtype=float)
        return State(np.asarray(theta, dtype=float).copy(), self.readings.copy(), c.copy())

    def joints(self, state: State) -> np.ndarray:
        if self.joint_vars:
            return state.q
        return self.readings if not self.K else self.readings + self.block_correction(state.theta)

    def setup_values(self, theta) -> np.ndarray:
        """The whole set-up vector (fixed entries included) at ``theta``."""
        return self.setup.full(np.asarray(theta)[self.n_geo + self.K:])

    def constraint_rows(self, theta):
        """Whitened rows of the known distances between fixture points: ``(r (k,), J (k, P), e (k,))``."""
        P = len(theta)
        if self.setup is None or not self.setup.spec.distances:
            return np.zeros(0), np.zeros((0, P)), np.zeros(0)
        e, J_s, sd = self.setup.distance_errors(self.setup_values(theta))
        J = np.zeros((len(e), P))
        free = self._setup_col >= self.n_geo + self.K  # fixed entries have no column
        J[:, self._setup_col[free]] = J_s[:, free] / sd[:, None]
        return e / sd, J, e

    def linearise(self, state: State, remember: bool = True) -> Linearisation:
        """Whitened residuals and Jacobians at ``state``; robust weights from the state itself.

        The last linearisation is remembered: asking again at the same state (and held values,
        noise and excluded measurements) returns it, with the normal equations already formed on it.
        ``remember=False``: a new one is not remembered (the remembered one is still returned).
        """
        lin = self._remembered(state)
        if lin is not None:
            return lin
        lin = self._linearise(state)
        if remember:
            key = (state.theta, state.q, state.c, self.held)
            self._last = (tuple(np.array(k, copy=True) for k in key), lin, self._weights_key(), self.sigmas)
        return lin

    def forget(self, lin: Linearisation | None = None) -> None:
        """Stop remembering ``lin`` (if it is the remembered linearisation; any when None)."""
        if self._last is not None and (lin is None or self._last[1] is lin):
            self._last = None

    def raw_errors(self, state: State) -> dict:
        """``{level: (e, s, w)}`` at ``state``: the remembered linearisation's, else evaluated without
        the Jacobians' (N, m, P) array."""
        lin = self._remembered(state)
        return (lin if lin is not None else self._linearise(state, residuals_only=True)).raw

    def _weights_key(self) -> tuple:
        return tuple((lv, m.tobytes()) for lv, m in sorted(self.excluded.items()))

    def _remembered(self, state: State) -> Linearisation | None:
        # Sigmas are immutable (replaced, never changed): the same object means the same noise.
        key = (state.theta, state.q, state.c, self.held)
        last = self._last
        if (last is not None and last[3] is self.sigmas and last[2] == self._weights_key()
                and all(np.array_equal(u, v) for u, v in zip(last[0], key))):
            return last[1]
        return None

    def _linearise(self, state: State, residuals_only: bool = False) -> Linearisation:
        """The linearisation at ``state``; ``residuals_only``: its ``J_theta`` has no columns (the
        residuals, costs and raw errors alone, without the (N, m, P) array)."""
        n, m, mt, P, nz = self.n_poses, self.m, self.m_theta, self.n_geo + self.K + self.S, self.nz
        theta = state.theta[:self.n_geo]
        r = np.zeros((n, m))
        q = self.joints(state)
        # The set-up levels' rows first: their entries say which columns each pose's rows touch (the
        # graph's structure, known from its first linearisation on), before the Jacobian is allocated.
        s_values = self.setup_values(state.theta) if self.setup is not None else None
        setup_rows = {level: BY_LEVEL[level].setup_error(theta, q[terms.pose], terms.data, s_values, self.index,
                                                         self.held, self.chain)
                      for level, terms in self.measurements.items() if getattr(BY_LEVEL[level], "uses_setup", False)}
        if self._pose_columns is False and not residuals_only:
            touched = [self._setup_touched(self.measurements[lv].pose, rows[4]) for lv, rows in setup_rows.items()]
            self._pose_columns = setup_columns(n, self.n_geo + self.K, P, *map(np.concatenate, zip(*touched))) \
                if touched else None
        known = self._pose_columns
        on_columns = None if residuals_only or known is False else known
        Jt = np.zeros((n, mt, 0 if residuals_only else P if on_columns is None else on_columns.cols.shape[1]))
        Jz = np.zeros((n, m, nz))
        cost = 0.0
        raw = {}
        excluded_rows: list = []

        def put(level, pose, start, e, J_t=None, J_q=None, J_c=None, c_col=None, sigma=1.0, block=False, setup=None):
            """Whitened rows of one level; ``block``: ``J_t`` holds the geometric columns only and
            the joint-error block's (``J_q G``) are formed here, a chunk of factors at a time
            (no temporary of the whole level's P columns); ``setup``: ``(J_s, cols)`` of a level on
            set-up blocks, written at their columns."""
            nonlocal cost
            width = e.shape[1]
            ew = e / sigma
            s = np.linalg.norm(ew, axis=1)
            w, rho = _robust(s, self.robust if level == "probes" or level in BY_LEVEL else None, self.robust_k)
            out = self.excluded.get(level)
            out = out if out is not None and out.any() else None
            if out is not None:  # excluded measurements: zero weight, no cost (their rows zeroed below)
                rho = np.where(out, 0.0, rho)
            raw[level] = (e, s, w if out is None else np.where(out, 0.0, w))
            cost += float(rho.sum())
            sw = np.sqrt(w)[:, None] / sigma
            rows_ = start[:, None] + np.arange(width)
            r[pose[:, None], rows_] = e * sw
            if J_t is not None and not residuals_only:
                wide = J_t.shape[2]
                with_block = block and self.K and not self.joint_vars  # else the block's columns are zero
                # One factor per pose at the same rows (a pose measurement): Jt's rows are a view.
                direct = len(pose) == n and np.array_equal(pose, np.arange(n)) and np.all(start == start[0])
                for lo in range(0, len(pose), POSE_CHUNK):
                    c = slice(lo, lo + POSE_CHUNK)
                    s_ = sw[c][:, :, None]
                    if direct:
                        view = Jt[c, int(start[0]):int(start[0]) + width]
                        np.multiply(J_t[c], s_, out=view[:, :, :wide])
                        if with_block:
                            self._block_columns_into(view[:, :, self.n_geo:self.n_geo + self.K], c, J_q[c] * s_)
                        continue
                    at = (pose[c, None], rows_[c])
                    Jt[at + (slice(0, wide),)] = J_t[c] * s_
                    if with_block:
                        Jt[at + (slice(self.n_geo, self.n_geo + self.K),)] = self._block_columns(pose[c], J_q[c] * s_)
                if setup is not None:
                    self._setup_into(Jt, pose, rows_, *setup, sw, on_columns)
            if J_q is not None and self.joint_vars:
                Jz[pose[:, None], rows_, :self.n_joints] = J_q * sw[:, :, None]
            if J_c is not None:
                cols = c_col[:, None] + np.arange(3)
                Jz[pose[:, None, None], rows_[:, :, None], cols[:, None, :]] = J_c * sw[:, :, None]
            if out is not None:  # kept as they would be included (included_leverage), then zeroed
                at_ex = (pose[out, None], rows_[out])
                with_t = J_t is not None and not residuals_only
                excluded_rows.append((*at_ex, r[at_ex].copy(), Jz[at_ex].copy(), Jt[at_ex].copy() if with_t else None))
                r[at_ex], Jz[at_ex] = 0.0, 0.0
                if with_t:
                    Jt[at_ex] = 0.0

        if self.probes is not None:
            pose_i, ball_var, xyz = self.probes
            e, Jc = fx.probe_error(state.c[ball_var], xyz, self.radius)
            put("probes", pose_i, self.row["probes"], e, J_c=Jc, c_col=self.ball_col[ball_var],
                sigma=self.sigmas.probe)
        if len(self.ball_pose):
            # One kinematics evaluation per pose for all of its balls, in chunks of poses (the
            # chain's intermediate arrays are ~20 times the Jacobians' size).
            x = fx.slots_of(theta, self.index, self.held)
            nb = len(self.ball_pose)
            pts, J_t, J_q = np.empty((nb, 3)), np.empty((nb, 3, self.n_geo)), np.empty((nb, 3, q.shape[1]))
            order = self._balls_by_pose
            for lo in range(0, n, POSE_CHUNK):
                a, z = np.searchsorted(self.ball_pose[order], [lo, lo + POSE_CHUNK])
                sel = order[a:z]
                jac = jacobians(x, q[lo:lo + POSE_CHUNK], offsets=self.pose_offsets[lo:lo + POSE_CHUNK],
                                chain=self.chain)
                b, k = self.ball_pose[sel] - lo, self.ball_slot[sel]
                assert jac.points is not None and jac.point_slots is not None and jac.point_joints is not None
                pts[sel] = jac.points[b, k]
                J_t[sel] = jac.point_slots[b, k][:, :, self.index]
                J_q[sel] = jac.point_joints[b, k]
                del jac
            J_c = np.broadcast_to(-np.eye(3), (nb, 3, 3))
            put("kinematic", self.ball_pose, self.row["kinematic"], pts - state.c, J_t, J_q, J_c, self.ball_col,
                sigma=self.sigmas.kinematic, block=True)
        for level, terms in self.measurements.items():
            kind = BY_LEVEL[level]
            if getattr(kind, "uses_setup", False):
                e, J_t, J_q, J_s, cols = setup_rows.pop(level)
                put(level, terms.pose, self.row[level], e, self._with_block(terms.pose, J_t, J_q), J_q,
                    sigma=kind.sigma(self.sigmas), setup=(J_s, cols))
            else:
                # In chunks of measurements: the kinematics' temporaries are many times the Jacobians'.
                chunks = [terms.take(slice(lo, lo + POSE_CHUNK)) for lo in range(0, len(terms), POSE_CHUNK)] \
                    if len(terms) > POSE_CHUNK else [terms]
                parts = [kind.error(theta, q[t.pose], t.data, self.index, self.held, self.chain) for t in chunks]
                e, J_t, J_q = (np.concatenate(x) if len(parts) > 1 else x[0] for x in zip(*parts))
                put(level, terms.pose, self.row[level], e, J_t, J_q, sigma=kind.sigma(self.sigmas), block=True)
        if self.joint_vars:
            nj = self.n_joints
            J_joints = None
            if self.K:  # the joint variable is the reading plus the block's correction
                e = fx.joint_error(state.q, self.readings + self.block_correction(state.theta))
                J_joints = np.zeros((n, nj, 0 if residuals_only else self.n_geo + self.K))  # nothing beyond the block
                if not residuals_only:
                    J_joints[:, self.g_joint, self.n_geo + np.arange(self.K)] = -self.g
            else:
                e = fx.joint_error(state.q, self.readings)
            put("joints", np.arange(n), self.row["joints"], e, J_t=J_joints, J_q=np.broadcast_to(np.eye(nj), (n, nj, nj)),
                sigma=self.sigmas.joint)
        prior_r = np.zeros(0)
        prior_J = np.zeros((0, P))
        if self.prior is not None:
            mean, sig = self.prior
            prior_r = (state.theta - mean) / sig
            prior_J = np.diag(1.0 / sig)
            raw["prior"] = (state.theta - mean, np.abs(prior_r), np.ones(P))
            cost += 0.5 * float(prior_r @ prior_r)
        if self.setup is not None and self.setup.spec.distances:
            c_r, c_J, c_e = self.constraint_rows(state.theta)
            prior_r, prior_J = np.concatenate([prior_r, c_r]), np.vstack([prior_J, c_J])
            raw["constraints"] = (c_e[:, None], np.abs(c_r), np.ones(len(c_r)))
            cost += 0.5 * float(c_r @ c_r)
        return Linearisation(r, Jt, Jz, prior_r, prior_J, cost, raw, excluded_rows=excluded_rows, columns=on_columns)

    def cost(self, state: State) -> float:
        return self.linearise(state).cost

    def factor_rows(self, level: str):
        """Pose index (K,) and row numbers (K, width) of each factor of ``level``."""
        if level in self.measurements:
            width, pose = BY_LEVEL[level].width, self.measurements[level].pose
        else:
            width = {"probes": 1, "kinematic": 3, "joints": self.n_joints}[level]
            pose = {"probes": lambda: self.probes[0], "kinematic": lambda: self.ball_pose,
                    "joints": lambda: np.arange(self.n_poses)}[level]()
        return np.asarray(pose, dtype=int), self.row[level][:, None] + np.arange(width)
