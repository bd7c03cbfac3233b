"""Each pose's theta columns, for the elimination's products on the columns a pose touches.

Set-up unknowns (socket points, planes, station frames) are columns of theta that only the poses
measuring that fixture touch: a contact row depends on the kinematic parameters and on the 3
coordinates of one socket. With 66 sockets the dense per-pose products of
:class:`fgcal.estimation.elimination.ArrowElimination` cost ``N * P**2`` with P = 219 where a pose's
rows reach ~24 columns. :class:`PoseColumns` lists each pose's nonzero columns (padded to one width
with a column that is always zero), so the products run batched on (N, c) blocks and their sums are
scattered into the (P, P) matrices. The skipped columns are exact zeros: the sums are the same, to the
rounding of another summation order. No I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

__all__ = ["PoseColumns", "active_columns", "pose_columns", "setup_columns"]

COMMON_SHARE = 0.5  # a column nonzero in at least this share of the poses is taken for every pose
MIN_SAVING = 0.5  # the per-pose width squared must be at most this share of P**2 to leave the dense products


def active_columns(J_theta: np.ndarray) -> np.ndarray:
    """Which theta columns (N, P) of ``J_theta`` (N, m_theta, P) each pose's rows touch."""
    return np.any(J_theta != 0.0, axis=1)


@dataclass(frozen=True)
class PoseColumns:
    """The theta columns each pose's rows touch.

    Attributes
    ----------
    cols : ndarray of int, shape (N, c)
        The ``k`` common columns first (the same for every pose), then the pose's own ones,
        padded with ``P`` (a column outside theta, zero in every product).
    P : int
        Theta's size.
    k : int
        How many leading columns are common to all poses (the kinematic ones).
    """

    cols: np.ndarray
    P: int
    k: int

    def take(self, c: slice) -> PoseColumns:
        """The columns of the poses ``c`` (this object when ``c`` takes them all: its index tables are kept)."""
        start, stop, step = c.indices(len(self.cols))
        if start == 0 and stop == len(self.cols) and step == 1:
            return self
        # kept, so that a chunk's index tables are made once too (more poses than a chunk)
        chunks = self.__dict__.setdefault("_chunks", {})
        if (start, stop, step) not in chunks:
            chunks[(start, stop, step)] = PoseColumns(cols=self.cols[c], P=self.P, k=self.k)
        return chunks[(start, stop, step)]

    @cached_property
    def _own_onehot(self):
        """The (P + 1, N s) one-hot matrix of the poses' own entries (sparse): it sums them onto their columns."""
        from scipy import sparse  # only on this path: the default calibration imports no scipy

        flat = self.cols[:, self.k:].reshape(-1)
        return sparse.csr_matrix((np.ones(flat.size), (flat, np.arange(flat.size))), shape=(self.P + 1, flat.size))

    @cached_property
    def _own_pairs(self) -> np.ndarray:
        """Flat index (N s s,) in the padded (P + 1, P + 1) matrix of each pose's own-by-own entries."""
        own = self.cols[:, self.k:]
        return (own[:, :, None] * (self.P + 1) + own[:, None, :]).reshape(-1)

    @cached_property
    def _hat_index(self) -> tuple[np.ndarray, np.ndarray]:
        """Flat indices in the padded (P + 1, P + 1) matrix of each pose's own-by-common (N, s, k) and
        columns-by-own (N, c, s) entries (:meth:`hat`)."""
        n1, k = self.P + 1, self.k
        own = self.cols[:, k:]
        common = self.cols[0, :k] if len(self.cols) else np.zeros(0, dtype=int)
        return own[:, :, None] * n1 + common[None, None, :], self.cols[:, :, None] * n1 + own[:, None, :]

    def _flat_index(self, m: int) -> tuple[np.ndarray, np.ndarray]:
        """Flat indices (N, m, c) into a C-ordered (N, m, P) array of each pose's columns, and the padding's mask."""
        key = ("flat", m)
        cache = self.__dict__.setdefault("_tables", {})
        if key not in cache:
            n, c = self.cols.shape
            col = np.minimum(self.cols, self.P - 1)[:, None, :]
            base = (np.arange(n)[:, None, None] * m + np.arange(m)[None, :, None]) * self.P
            cache[key] = ((base + col).astype(np.intp), np.broadcast_to((self.cols < self.P)[:, None, :], (n, m, c)))
        return cache[key]

    def _sum_by_own(self, Z: np.ndarray) -> np.ndarray:
        """The (P + 1, k) sums of ``Z`` (N, s, k) over the poses, each row onto its pose's own column."""
        return np.asarray(self._own_onehot @ Z.reshape(-1, Z.shape[2]))

    def gather(self, J: np.ndarray) -> np.ndarray:
        """``J`` (N, m, P) on each pose's columns: (N, m, c)."""
        idx, mask = self._flat_index(J.shape[1])
        out = np.take(np.ascontiguousarray(J).reshape(-1), idx)
        out *= mask  # the padding: zero
        return out

    def gather_rows(self, B: np.ndarray) -> np.ndarray:
        """``B`` (N, P, k) on each pose's columns: (N, c, k)."""
        out = np.take_along_axis(B, np.minimum(self.cols, self.P - 1)[:, :, None], axis=1)
        out *= (self.cols < self.P)[:, :, None]
        return out

    def place_rows(self, Bc: np.ndarray) -> np.ndarray:
        """(N, P, k) zeros but ``Bc`` (N, c, k) on each pose's columns: the inverse of :meth:`gather_rows`."""
        out = np.zeros((len(Bc), self.P + 1, Bc.shape[2]))
        np.put_along_axis(out, self.cols[:, :, None], Bc, axis=1)
        return out[:, :self.P]

    def gather_matrix(self, M: np.ndarray) -> np.ndarray:
        """The (P, P) ``M`` on each pose's columns: (N, c, c)."""
        padded = np.zeros((self.P + 1, self.P + 1))
        padded[:self.P, :self.P] = M
        return padded[self.cols[:, :, None], self.cols[:, None, :]]

    def hat(self, J: np.ndarray, M: np.ndarray) -> np.ndarray:
        """The diagonal (N, m) of ``J_n M J_n^T`` for ``J`` (N, m, c) on each pose's columns and the
        (P, P) ``M``: the common block as one dense product, the poses' own blocks gathered (N k s
        and N s s entries, not the N c c of :meth:`gather_matrix`)."""
        k = self.k
        common, own = self.cols[0, :k] if len(self.cols) else np.zeros(0, dtype=int), self.cols[:, k:]
        padded = np.zeros((self.P + 1, self.P + 1))  # the padding column: zero
        padded[:self.P, :self.P] = M
        Jc, Jo = J[:, :, :k], J[:, :, k:]
        n, m = J.shape[:2]
        JM = (Jc.reshape(-1, k) @ M[np.ix_(common, common)]).reshape(n, m, k)
        if own.shape[1]:  # [Jc Jo] [[Mcc Mco] [Moc Moo]] [Jc Jo]^T: the pose's own rows and columns of M
            own_common, cols_own = self._hat_index
            flat = padded.reshape(-1)
            JM = np.concatenate([JM + np.matmul(Jo, flat.take(own_common)), np.matmul(J, flat.take(cols_own))], axis=2)
        return np.einsum("nmc,nmc->nm", JM, J)

    def scatter(self, X: np.ndarray) -> np.ndarray:
        """The (P, P) sum over poses of ``X`` (N, c, c) placed on each pose's columns."""
        n, k = self.P + 1, self.k
        own = self.cols[:, k:]
        s = own.shape[1]
        common = self.cols[0, :k] if len(self.cols) else np.zeros(0, dtype=int)
        out = np.zeros((n, n))
        out[np.ix_(common, common)] = X[:, :k, :k].sum(axis=0)  # the common block: one sum over poses
        if s:
            from scipy import sparse  # only on this path: the default calibration imports no scipy

            # The common-by-own blocks: (k, N s) times a one-hot (N s, P + 1) of the own columns.
            onehot = sparse.csr_matrix((np.ones(own.size), (np.arange(own.size), own.reshape(-1))),
                                       shape=(own.size, n))
            cross = np.asarray(onehot.T @ X[:, :k, k:].transpose(0, 2, 1).reshape(-1, k))  # (P + 1, k)
            out[:, common] += cross
            out[common, :] += cross.T
            flat = (own[:, :, None] * n + own[:, None, :]).reshape(-1)
            out += np.bincount(flat, weights=X[:, k:, k:].reshape(-1), minlength=n * n).reshape(n, n)
        return out[:self.P, :self.P]

    def inner(self, X: np.ndarray, Y: np.ndarray) -> np.ndarray:
        """The (P, P) sum over poses of ``X_n^T Y_n``, both (N, m, c) on each pose's columns.

        The common columns as one dense (N m, k) product (BLAS); a pose's own columns by small
        per-pose products summed onto their columns (a sort made once per pattern).
        """
        n, k = self.P + 1, self.k
        common = self.cols[0, :k] if len(self.cols) else np.zeros(0, dtype=int)
        Xc, Yc = X[:, :, :k], Y[:, :, :k]
        out = np.zeros((n, n))
        out[np.ix_(common, common)] = Xc.reshape(-1, k).T @ Yc.reshape(-1, k)
        if self.cols.shape[1] > k:
            XoT, YoT = X[:, :, k:].transpose(0, 2, 1), Y[:, :, k:].transpose(0, 2, 1)  # (N, s, m)
            cross = self._sum_by_own(np.matmul(XoT, Yc))
            out[:, common] += cross
            # X^T X (the normal equations): the other cross block is this one's transpose
            out[common, :] += cross.T if X is Y else self._sum_by_own(np.matmul(YoT, Xc)).T
            out += np.bincount(self._own_pairs, weights=np.matmul(XoT, Y[:, :, k:]).reshape(-1),
                               minlength=n * n).reshape(n, n)
        return out[:self.P, :self.P]

    def place(self, J: np.ndarray) -> np.ndarray:
        """``J`` (N, m, c) on each pose's columns placed in a dense (N, m, P): the inverse of :meth:`gather`."""
        n, m, c = J.shape
        out = np.zeros((n, m, self.P + 1))
        np.put_along_axis(out, np.broadcast_to(self.cols[:, None, :], (n, m, c)), J, axis=2)
        return out[:, :, :self.P]

    def transpose_times(self, J: np.ndarray, r: np.ndarray) -> np.ndarray:
        """The (P,) sum over poses of ``J_n^T r_n`` for ``J`` (N, m, c) on each pose's columns and ``r`` (N, m)."""
        k = self.k
        out = np.zeros(self.P + 1)
        out[self.cols[0, :k] if len(self.cols) else np.zeros(0, dtype=int)] = J[:, :, :k].reshape(-1, k).T @ r.reshape(-1)
        if self.cols.shape[1] > k:
            own = np.einsum("nms,nm->ns", J[:, :, k:], r)
            out += np.bincount(self.cols[:, k:].reshape(-1), weights=own.reshape(-1), minlength=self.P + 1)
        return out[:self.P]

    def slots(self, pose: np.ndarray, where: np.ndarray) -> np.ndarray:
        """The position in each pose's columns (M, k) of the theta columns ``where`` (M, k) of rows
        of poses ``pose`` (M,); every one must be among its pose's columns."""
        cache = self.__dict__.setdefault("_tables", {})
        key = ("slots", np.asarray(pose).tobytes(), np.asarray(where).tobytes())  # the graph's structure: asked again every linearisation
        if key not in cache:
            cols = self.cols[pose]  # (M, c)
            hit = cols[:, None, :] == where[:, :, None]  # (M, k, c): one True each (the columns are distinct)
            cache[key] = np.argmax(hit, axis=2)
        return cache[key]

    def scatter_vector(self, v: np.ndarray) -> np.ndarray:
        """The (P,) sum over poses of ``v`` (N, c) placed on each pose's columns."""
        return np.bincount(self.cols.reshape(-1), weights=v.reshape(-1), minlength=self.P + 1)[:self.P]


def setup_columns(n: int, k: int, P: int, pose: np.ndarray, where: np.ndarray) -> PoseColumns | None:
    """The columns of a graph whose first ``k`` theta columns (the robot's) are every pose's and whose
    others (set-up unknowns) a pose touches where one of its rows does: ``(pose, where)`` pairs (M,)
    of a pose and a theta column its rows touch (from the graph's structure, not from the values: a
    zero Jacobian entry keeps its column). None where the products on them would not save enough."""
    active = np.zeros((n, P), dtype=bool)
    active[:, :k] = True
    active[np.asarray(pose, dtype=int), np.asarray(where, dtype=int)] = True
    pc = pose_columns(active)
    if pc is None or pc.k != k or not np.array_equal(pc.cols[0, :k], np.arange(k)):
        return None  # a set-up column every pose touches: the dense layout (it keeps the robot's k first)
    return pc


def pose_columns(active: np.ndarray) -> PoseColumns | None:
    """Each pose's columns from ``active`` (N, P) (:func:`active_columns`); None when the products on
    them would not save enough over the dense ones (the caller then keeps its dense products)."""
    n, P = active.shape
    if n == 0 or P == 0:
        return None
    common = active.mean(axis=0) >= COMMON_SHARE
    own = active & ~common
    width = int(common.sum()) + int(own.sum(axis=1).max())
    if width**2 > MIN_SAVING * P**2:
        return None
    # Each pose's own columns (ascending: nonzero's row-major order), then the padding P.
    n_own = width - int(common.sum())
    counts = own.sum(axis=1)
    r, c = np.nonzero(own)
    own_cols = np.full((n, n_own), P)
    own_cols[r, np.arange(len(r)) - np.repeat(np.cumsum(counts) - counts, counts)] = c
    cols = np.concatenate([np.broadcast_to(np.flatnonzero(common), (n, int(common.sum()))), own_cols], axis=1)
    return PoseColumns(cols=cols, P=P, k=int(common.sum()))
