"""Elimination on the arrow-shaped graph: normal equations in per-pose blocks, the Schur
complement on the parameters, damped Gauss-Newton steps, the covariance (computed here, once) and
the rows' leverage. A mixin of :class:`fgcal.estimation.graph.Graph`, which supplies the layout
(``n_poses``, ``m``, ``nz``, ``local_used``, ``joint_vars``, ``n_joints``, ``ball_pose``,
``ball_col``, ``row``, ``excluded``, ``prior``) and ``linearise``/``factor_rows``. No I/O here.
"""
from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import numpy as np

from fgcal.estimation.column_groups import PoseColumns, active_columns, pose_columns
from fgcal.estimation.setup_schur import SetupSplit
from fgcal.robots.jacobian_rank import ScaledSpectrum

if TYPE_CHECKING:  # annotations only: graph.py imports this module
    from fgcal.estimation.graph_types import Linearisation, State

__all__ = ["POSE_CHUNK", "ArrowElimination", "scaled_inverse"]

POSE_CHUNK = 2000  # poses per block of work (bounds the temporaries)


def _prior_normal(lin: Linearisation) -> np.ndarray:
    """``prior_J^T prior_J`` (P, P) of ``lin``, formed once on its nonzero rows (a parameter without a
    prior has a zero row: with 198 socket coordinates, most of them)."""
    if "prior_normal" not in lin.cache:
        J = lin.prior_J
        J = J[np.any(J != 0.0, axis=1)]
        lin.cache["prior_normal"] = J.T @ J
    return lin.cache["prior_normal"]


def scaled_inverse(S, split: SetupSplit | None = None) -> np.ndarray:
    """Inverse of a symmetric positive (semi)definite ``S`` (P, P), scaled to unit diagonal first; the
    pseudo-inverse where it is singular to the last bit (parameters left free that the data cannot
    see, ``decide_held=False``: the rows' leverage is then the projection on the seen directions).
    ``split``: the inverse by the set-up block's blocks (:class:`~fgcal.estimation.setup_schur.SetupSplit`)."""
    d = np.sqrt(np.maximum(np.diag(S), 1e-300))
    dd = np.outer(d, d)
    scaled = S / dd
    try:
        return (np.linalg.inv(scaled) if split is None else split.inverse(scaled)) / dd
    except np.linalg.LinAlgError:
        return np.linalg.pinv(scaled, hermitian=True) / dd


def _times(X: np.ndarray, M: np.ndarray) -> np.ndarray:
    """``X @ M`` for a stack ``X`` (n, m, P): one (n m, P) product where ``M`` is one (P, P) matrix (a
    stack of n small products is 2-2.5 times slower: a 392-parameter map's leverage on 8,400 poses),
    else the stacked product (``M`` per pose, (n, P, P))."""
    if M.ndim == 2 and X.flags.c_contiguous:
        return (X.reshape(-1, X.shape[-1]) @ M).reshape(*X.shape[:-1], M.shape[1])
    return X @ M


class ArrowElimination:
    """Solving and statistics of a graph whose per-pose variables touch only their pose and theta."""

    # The layout, supplied by Graph (declared here for the type checker).
    n_poses: int
    n_geo: int
    K: int
    S: int
    m: int
    nz: int
    n_joints: int
    local_used: np.ndarray
    joint_vars: bool
    ball_pose: np.ndarray
    ball_col: np.ndarray
    row: dict[str, Any]
    excluded: dict[str, np.ndarray]
    prior: Any

    def linearise(self, state: State) -> Linearisation:
        raise NotImplementedError  # Graph's

    def factor_rows(self, level: str) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError  # Graph's

    def _blocks(self, lin: Linearisation) -> Iterator[tuple[slice, PoseColumns | None]]:
        """Chunks of at most ``POSE_CHUNK`` poses and the theta columns their rows touch.

        The columns None: the dense products over all of theta (no set-up columns, or too few
        skipped to pay: :func:`fgcal.estimation.column_groups.pose_columns`).
        """
        if "columns" not in lin.cache and lin.columns is not None:  # formed on its pose columns
            lin.cache["columns"] = lin.columns
        if "columns" not in lin.cache:
            active = active_columns(lin.J_theta)
            last = getattr(self, "_last_columns", None)
            # The pattern is the graph's structure, the same at every linearisation of a solve: the
            # columns (a sort per pose) are reused while the pattern is exactly the same.
            if last is not None and last[0].shape == active.shape and np.array_equal(last[0], active):
                lin.cache["columns"] = last[1]
            else:
                lin.cache["columns"] = pose_columns(active)
                self._last_columns: tuple[np.ndarray, PoseColumns | None] = (active, lin.cache["columns"])
        pc = lin.cache["columns"]
        for lo in range(0, self.n_poses, POSE_CHUNK):
            c = slice(lo, lo + POSE_CHUNK)
            yield c, None if pc is None else pc.take(c)

    def _on_columns(self, lin: Linearisation) -> np.ndarray:
        """``lin``'s theta Jacobian on its pose columns (N, m_theta, c): as formed, or gathered from
        the dense one once."""
        if lin.columns is not None:
            return lin.J_stored
        if "J_columns" not in lin.cache:
            lin.cache["J_columns"] = lin.cache["columns"].gather(lin.J_theta)
        return lin.cache["J_columns"]

    def normal_equations(self, lin: Linearisation):
        """``A`` (P, P), ``B`` (N, P, nz), ``D`` (N, nz, nz), ``g_t`` (P,), ``g_z`` (N, nz) of ``lin``.

        Formed once per linearisation (kept on ``lin``) by BLAS products over the per-pose blocks.
        """
        if "normal" in lin.cache:
            return lin.cache["normal"]
        mt = lin.J_stored.shape[1]
        blocks = list(self._blocks(lin))
        if blocks[0][1] is None:
            Jt2 = lin.J_theta.reshape(-1, lin.J_theta.shape[2])
            A = Jt2.T @ Jt2 + _prior_normal(lin)
            B = np.matmul(lin.J_theta.transpose(0, 2, 1), lin.J_local[:, :mt])
            g_t = Jt2.T @ lin.r[:, :mt].reshape(-1)
        else:  # each pose's products on its own columns (the others are zero in its rows)
            Jc_all = self._on_columns(lin)  # (N, mt, c)
            g_t = lin.cache["columns"].transpose_times(Jc_all, lin.r[:, :mt])
            A = _prior_normal(lin).copy()
            for c, pc in blocks:
                assert pc is not None  # one choice for all chunks
                Jc = Jc_all[c]
                A = A + pc.inner(Jc, Jc)  # the same object: inner's symmetric shortcut
            # B on each pose's columns (N, c, nz), kept for the Schur complement and the leverage,
            # and placed into the (N, P, nz) the step uses.
            lin.cache["B_own"] = np.matmul(Jc_all.transpose(0, 2, 1), lin.J_local[:, :mt])
            B = lin.cache["columns"].place_rows(lin.cache["B_own"])
        g_t = g_t + lin.prior_J.T @ lin.prior_r
        JzT = lin.J_local.transpose(0, 2, 1)
        D = np.matmul(JzT, lin.J_local)
        g_z = np.matmul(JzT, lin.r[:, :, None])[:, :, 0]
        # Padding columns (poses with fewer balls) get a unit diagonal: they stay at zero.
        pad = ~self.local_used
        D[pad] = 0.0
        D[:, np.arange(self.nz), np.arange(self.nz)] += pad
        lin.cache["normal"] = (A, B, D, g_t, g_z)
        return lin.cache["normal"]

    def reduced(self, A, B, D, g_t=None, g_z=None, damping: float = 0.0, lin: Linearisation | None = None):
        """Schur complement on theta: ``S``, right-hand side, and the per-pose inverses.

        ``lin``: the linearisation ``B`` and ``D`` come from, whose pose columns the products use
        (None: dense products over all columns).
        """
        if damping:
            A = A + damping * np.diag(np.maximum(np.diag(A), 1e-12))
        S = A.copy()
        rhs = None if g_t is None else g_t.copy()
        Dinv = self._inverses(D, damping)
        if not self.nz:  # no per-pose variables: nothing to eliminate
            return S, rhs, Dinv
        blocks = self._blocks(lin) if lin is not None else \
            ((slice(lo, lo + POSE_CHUNK), None) for lo in range(0, len(D), POSE_CHUNK))
        for c, pc in blocks:
            if pc is None:
                BD = np.matmul(B[c], Dinv[c])
                S -= np.tensordot(BD, B[c], axes=([0, 2], [0, 2]))
                if rhs is not None:
                    rhs -= np.tensordot(BD, g_z[c], axes=([0, 2], [0, 1]))
                continue
            # (n, c, nz): B's rows off a pose's columns are zero
            Bc = lin.cache["B_own"][c] if lin is not None and "B_own" in lin.cache else pc.gather_rows(B[c])
            BD = np.matmul(Bc, Dinv[c])
            S -= pc.inner(BD.transpose(0, 2, 1), Bc.transpose(0, 2, 1))
            if rhs is not None:
                rhs -= pc.scatter_vector(np.matmul(BD, g_z[c][:, :, None])[:, :, 0])
        return S, rhs, Dinv

    def _inverses(self, D, damping: float = 0.0) -> np.ndarray:
        """The per-pose inverses (N, nz, nz) of ``D``, its diagonal damped by ``damping``."""
        Dinv = np.empty_like(D)
        idx = np.arange(self.nz)
        for lo in range(0, len(D), POSE_CHUNK):  # in chunks of poses: no temporaries of N blocks
            c = slice(lo, lo + POSE_CHUNK)
            Dc = D[c]
            if damping:
                Dc = Dc.copy()
                Dc[:, idx, idx] += damping * np.maximum(Dc[:, idx, idx], 1e-12)
            Dinv[c] = np.linalg.inv(Dc) if self.nz else Dc
        return Dinv

    def _reduced_at(self, lin: Linearisation):
        """The undamped ``(S, Dinv)`` of ``lin``, formed once."""
        if "reduced" not in lin.cache and not self.nz:  # no per-pose variables: S is the normal matrix
            A = self.normal_equations(lin)[0]
            lin.cache["reduced"] = (A, np.zeros((self.n_poses, 0, 0)))
        if "reduced" not in lin.cache:
            Dinv = self._inverses(self.normal_equations(lin)[2])
            # S itself from a QR elimination of each pose's whitened rows [J_local, J_theta], as
            # GTSAM does: B D^-1 B^T cancels ~1e-4 of A's entries under the 1e-4 mm kinematic sigma.
            mt, P = lin.J_stored.shape[1], lin.prior_J.shape[1]
            S = _prior_normal(lin).copy()
            for c, pc in self._blocks(lin):
                k = len(lin.r[c])
                pad = ~self.local_used[c]
                extra = self.nz if pad.any() else 0  # no padding in the chunk: no unit rows (zero rows change no R)
                width = P if pc is None else pc.cols.shape[1]  # zero columns would give zero rows of R
                M = np.zeros((k, self.m + extra, self.nz + width))
                M[:, :self.m, :self.nz] = lin.J_local[c]
                M[:, :mt, self.nz:] = lin.J_theta[c] if pc is None else self._on_columns(lin)[c]
                if extra:
                    M[:, self.m:, :self.nz] = pad[:, :, None] * np.eye(self.nz)  # unit rows keep padding at zero
                R = np.asarray(np.linalg.qr(M, mode="r"))[:, self.nz:, self.nz:]
                if pc is None:
                    S = S + np.tensordot(R, R, axes=([0, 1], [0, 1]))
                else:
                    S = S + pc.inner(R, R)
            lin.cache["reduced"] = (S, Dinv)
        return lin.cache["reduced"]

    def step(self, state: State, lin: Linearisation, damping: float):
        """A damped Gauss-Newton step: ``(new state, d_theta, predicted cost decrease)``."""
        A, B, D, g_t, g_z = self.normal_equations(lin)
        S, rhs, Dinv = self.reduced(A, B, D, g_t, g_z, damping, lin=lin)
        split = self._setup_split(S)
        d_theta = -(np.linalg.solve(S, rhs) if split is None else split.solve(S, rhs))
        d_z = -np.matmul(Dinv, (g_z + np.matmul(d_theta, B))[:, :, None])[:, :, 0]
        new = state.copy()
        new.theta = state.theta + d_theta
        if self.joint_vars:
            new.q = state.q + d_z[:, :self.n_joints]
        if len(self.ball_pose):
            cols = self.ball_col[:, None] + np.arange(3)
            new.c = state.c + d_z[self.ball_pose[:, None], cols]
        # The Gauss-Newton model's decrease: -g.d - d.H.d / 2 over all variables (H undamped).
        g_dot = g_t @ d_theta + np.einsum("nz,nz->", g_z, d_z)
        Hd_t = A @ d_theta + np.einsum("npz,nz->p", B, d_z)
        Hd_z = np.matmul(d_theta, B) + np.matmul(D, d_z[:, :, None])[:, :, 0]
        dHd = d_theta @ Hd_t + np.einsum("nz,nz->", d_z, Hd_z)
        return new, d_theta, float(-g_dot - 0.5 * dHd)

    def parameter_information(self, state: State, lin: Linearisation | None = None) -> np.ndarray:
        """The (P, P) information of theta with the per-pose variables marginalised out.

        ``lin``: the linearisation at ``state`` when the caller has it already.
        """
        lin = self.linearise(state) if lin is None else lin
        return self._reduced_at(lin)[0]

    def information_inverse(self, state: State, lin: Linearisation | None = None) -> np.ndarray:
        """The (P, P) inverse of :meth:`parameter_information`, scaled to unit diagonal first (a
        pseudo-inverse where singular: :func:`scaled_inverse`), formed once per
        linearisation: the noise rounds' leverage and the level summaries' are then one product."""
        lin = self.linearise(state) if lin is None else lin
        if "information_inverse" not in lin.cache:
            S = self.parameter_information(state, lin)
            lin.cache["information_inverse"] = scaled_inverse(S, self._setup_split(S))
        return lin.cache["information_inverse"]

    def _setup_split(self, S: np.ndarray) -> SetupSplit | None:
        """The :class:`~fgcal.estimation.setup_schur.SetupSplit` of ``S`` (P, P) (None: dense algebra),
        made once per pattern of its set-up block (the graph's structure: the same at every step)."""
        if self.S <= 0:
            return None
        k = self.n_geo + self.K  # theta: the robot's k, then the set-up unknowns
        pattern = S[k:, k:] != 0.0
        last = getattr(self, "_last_split", None)
        if last is None or last[0].shape != pattern.shape or not np.array_equal(last[0], pattern):
            split = SetupSplit.of(S, np.arange(k), np.arange(k, len(S)))
            self._last_split: tuple[np.ndarray, SetupSplit | None] = (pattern, split)
        return self._last_split[1]

    def covariance(self, state: State, lin: Linearisation | None = None) -> np.ndarray:
        """The (P, P) covariance of theta: the inverse of the Schur complement the solve forms
        (:meth:`information_inverse`, which the noise rounds have formed at the solution already),
        symmetrised."""
        lin = self.linearise(state) if lin is None else lin
        if "covariance" not in lin.cache:
            V = self.information_inverse(state, lin)
            lin.cache["covariance"] = 0.5 * (V + V.T)
        return lin.cache["covariance"]

    def parameter_spectrum(self, state: State, lin: Linearisation | None = None) -> ScaledSpectrum:
        """The :class:`~fgcal.robots.jacobian_rank.ScaledSpectrum` of :meth:`parameter_information`,
        formed once per linearisation (the covariance's singularity check and the identifiability at
        the solution share it)."""
        lin = self.linearise(state) if lin is None else lin
        if "spectrum" not in lin.cache:
            lin.cache["spectrum"] = ScaledSpectrum(self.parameter_information(state, lin))
        return lin.cache["spectrum"]

    def row_leverage(self, state: State, covariance, lin: Linearisation | None = None) -> np.ndarray:
        """Diagonal of the hat matrix (N, m) of the whitened rows; ``covariance`` is theta's (P, P).

        One minus it is each row's redundancy number (Foerstner): the share of its noise that
        shows in its residual.
        """
        lin = self.linearise(state) if lin is None else lin
        cached = lin.cache.get("leverage")
        if cached is not None and cached[0] is covariance:  # the same covariance object: the same answer
            return cached[1]
        _, B, _, _, _ = self.normal_equations(lin)
        _, Dinv = self._reduced_at(lin)
        Jz_all = lin.J_local
        Jt_all = lin.J_theta if lin.cache["columns"] is None else self._on_columns(lin)
        mt = Jt_all.shape[1]
        h = np.zeros(lin.r.shape)
        # In chunks of poses: the temporaries are as large as J_theta (on 8,000 poses with a
        # 392-parameter map, 160 MB each).
        for c, pc in self._blocks(lin):
            # A pose's rows are zero off its columns: only that block of Sigma reaches them.
            Jz = Jz_all[c]
            Jt = Jt_all[c]  # (n, mt, P), or on the poses' columns (n, mt, c)
            # Hat diagonal per row: J_i Sigma J_i^T with J = [J_theta, J_local]; only the first mt
            # rows of a pose depend on theta.
            if not self.nz:
                h[c, :mt] = np.einsum("nmp,nmp->nm", _times(Jt, covariance), Jt) if pc is None else pc.hat(Jt, covariance)
                continue
            St = covariance if pc is None else pc.gather_matrix(covariance)  # (P, P) or (n, c, c)
            Bc = B[c] if pc is None else lin.cache["B_own"][c]
            E = -np.matmul(Dinv[c], Bc.transpose(0, 2, 1))  # Sigma_z_theta = -D^-1 B^T S^-1 (before S^-1)
            Szt = _times(E, St)  # (n, nz, P)
            Szz = Dinv[c] + np.matmul(Szt, E.transpose(0, 2, 1))
            h[c] = np.einsum("nmz,nmz->nm", np.matmul(Jz, Szz), Jz)
            h[c, :mt] += np.einsum("nmp,nmp->nm", _times(Jt, St) + 2 * np.matmul(Jz[:, :mt], Szt), Jt)
        lin.cache["leverage"] = (covariance, h)
        return h

    def leverage_by_level(self, state: State, covariance, lin: Linearisation | None = None) -> dict:
        """Redundancy of each factor level: rows (excluded ones not counted) and the sum of their leverage."""
        lin = self.linearise(state) if lin is None else lin
        h = self.row_leverage(state, covariance, lin)
        out = {}
        for level in self.row:
            pose, rows_ = self.factor_rows(level)
            kept = ~self.excluded.get(level, np.zeros(len(pose), dtype=bool))
            out[level] = (int(rows_[kept].size), float(h[pose[kept, None], rows_[kept]].sum()))
        if self.prior is not None:
            hp = np.einsum("kp,kp->k", lin.prior_J @ covariance, lin.prior_J)  # by BLAS: the 3-operand einsum loops (12 ms at P = 219)
            out["prior"] = (len(hp), float(hp.sum()))
        return out
