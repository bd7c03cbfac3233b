"""The joint-error block's columns of the factor graph (:mod:`fgcal.estimation.joint_errors`), and the
set-up blocks' (written at their own columns, :meth:`JointErrorColumns._setup_into`).

Each block parameter corrects one joint, so its design ``G`` (N, n, K) has one nonzero row per
column: the graph keeps the compact form ``g`` (N, K) and the joint of each column (on 8,000
poses with a 30-harmonic map of six joints: 24 MB against 146 MB), and writes the block's
Jacobian columns ``J_q G`` one joint at a time into the rows it fills. A mixin of
:class:`fgcal.estimation.graph.Graph`, which supplies ``readings``, ``n_geo``, ``K``, ``S``,
``joint_vars``, ``g``, ``g_joint`` and ``_setup_col``. No I/O here.
"""
from __future__ import annotations

from functools import cached_property

import numpy as np

__all__ = ["JointErrorColumns", "compact_design"]


def compact_design(joint_errors, n: int, n_joints: int) -> tuple[np.ndarray, np.ndarray]:
    """``(g (N, K), joints (K,))`` of a joint-error design given dense (N, n, K) or compact."""
    if joint_errors is None:
        return np.zeros((n, 0)), np.zeros(0, dtype=int)
    if isinstance(joint_errors, tuple):
        g, joint = joint_errors
        return np.asarray(g, dtype=float).reshape(n, -1), np.asarray(joint, dtype=int)
    G = np.asarray(joint_errors, dtype=float).reshape(n, n_joints, -1)
    used = np.abs(G).max(axis=0) > 0  # (n, K)
    if np.any(used.sum(axis=0) > 1):
        raise ValueError("each joint-error parameter must correct one joint (a column of G with one nonzero row)")
    joint = np.argmax(used, axis=0)
    return G[:, joint, np.arange(G.shape[2])], joint


class JointErrorColumns:
    """The block's correction of the joints and its Jacobian columns; the set-up blocks' columns."""

    # The layout, supplied by Graph (declared here for the type checker).
    readings: np.ndarray
    n_geo: int
    K: int
    S: int
    joint_vars: bool
    g: np.ndarray
    g_joint: np.ndarray
    _setup_col: np.ndarray | None

    def block_correction(self, theta) -> np.ndarray:
        """(N, n) the joint-error block's correction of the readings at ``theta``."""
        phi = np.asarray(theta)[self.n_geo:self.n_geo + self.K]
        out = np.zeros_like(self.readings)
        for j in np.unique(self.g_joint):
            cols = self.g_joint == j
            out[:, j] = self.g[:, cols] @ phi[cols]
        return out

    def _block_columns(self, pose, J_q) -> np.ndarray:
        """(M, w, K) the block's Jacobian columns of rows with joint Jacobian ``J_q`` (M, w, n): ``J_q G``."""
        return J_q[:, :, self.g_joint] * self.g[pose][:, None, :]

    def _block_columns_into(self, out, pose, J_q) -> None:
        """:meth:`_block_columns` written into ``out`` (M, w, K), one joint's columns at a time."""
        for j, cols in self._joint_columns:
            if isinstance(cols, slice):
                np.multiply(J_q[:, :, j, None], self.g[pose, None, cols], out=out[:, :, cols])
            else:  # an index array's selection is a copy: assigned instead
                out[:, :, cols] = J_q[:, :, j, None] * self.g[pose][:, None, cols]

    @cached_property
    def _joint_columns(self) -> list:
        """``(joint, its block columns)``: a slice where they are contiguous (they are as built)."""
        out = []
        for j in np.unique(self.g_joint):
            cols = np.nonzero(self.g_joint == j)[0]
            whole = cols[-1] - cols[0] + 1 == len(cols)
            out.append((int(j), slice(int(cols[0]), int(cols[-1]) + 1) if whole else cols))
        return out

    def _with_block(self, pose, J_t, J_q):
        """Geometric Jacobian columns extended by the block's (exact readings: J_q G; else 0); the
        set-up columns are written at their own columns by :meth:`_setup_into`."""
        if not self.K:
            return J_t
        block = np.zeros(J_t.shape[:2] + (self.K,)) if self.joint_vars else self._block_columns(pose, J_q)
        return np.concatenate([J_t, block], axis=2)

    def _setup_touched(self, pose, cols) -> tuple[np.ndarray, np.ndarray]:
        """``(pose, theta column)`` pairs (flat) of the free set-up entries ``cols`` (M, k) of rows of
        poses ``pose`` (M,)."""
        assert self._setup_col is not None  # a graph with set-up blocks
        where = self._setup_col[cols]
        free = where >= self.n_geo + self.K
        return np.broadcast_to(np.asarray(pose)[:, None], where.shape)[free], where[free]

    def _setup_into(self, Jt, pose, rows_, J_s, cols, sw, columns=None):
        """Write a set-up Jacobian ``J_s`` (M, w, k) at set-up entries ``cols`` (M, k), whitened by
        ``sw`` (M, w), into the rows ``rows_`` (M, w) of poses ``pose`` (M,) of ``Jt`` (N, m_theta, P),
        or, on pose ``columns`` (:class:`~fgcal.estimation.column_groups.PoseColumns`), of ``Jt``
        (N, m_theta, c) at each entry's place among its pose's columns: no (M, w, P) array of the
        factors' mostly zero set-up columns."""
        assert self._setup_col is not None  # a graph with set-up blocks
        where = self._setup_col[cols]  # (M, k) columns of theta; fixed entries map below n_geo + K
        free = where >= self.n_geo + self.K
        if columns is not None:  # each free entry's place among its pose's columns (a fixed one's, unused: column 0's)
            where = columns.slots(np.asarray(pose), np.where(free, where, 0))
        if free.all():  # unknown blocks: every entry has its column
            Jt[pose[:, None, None], rows_[:, :, None], where[:, None, :]] = J_s * sw[:, :, None]
            return
        m, w, k = J_s.shape
        sel = np.broadcast_to(free[:, None, :], (m, w, k))
        at = (np.broadcast_to(pose[:, None, None], (m, w, k))[sel], np.broadcast_to(rows_[:, :, None], (m, w, k))[sel],
              np.broadcast_to(where[:, None, :], (m, w, k))[sel])
        Jt[at] = (J_s * sw[:, :, None])[sel]
