"""The parameters' information with the set-up unknowns marginalised, block by block. No I/O here.

The set-up block of a graph's information couples a fixture's unknowns only with themselves and with
the fixtures a known distance ties them to: the socket points of a contact dataset are 3x3 blocks,
pairs of them 6x6 where a plate's distance joins them. Its pseudo-inverse is the pseudo-inverse of
each connected block (:func:`marginal_information`), at the cutoff the dense
``numpy.linalg.pinv`` applies (``1e-15`` of the largest singular value of the whole block), so the
Schur complement is the dense one's to rounding, at a cost linear in the number of fixtures instead
of cubic in the block's size (198 socket coordinates: 66 3x3 inverses instead of one 198x198 SVD).
"""
from __future__ import annotations

import numpy as np

__all__ = ["SetupSplit", "blocks_by_width", "connected_blocks", "marginal_information"]

RCOND = 1e-15  # numpy.linalg.pinv's default: singular values up to this share of the largest are zero
DENSE_UP_TO = 36  # set-up unknowns up to which the dense pinv is the cheaper (0.05 ms at 12, blocks 0.3 ms)


def connected_blocks(M: np.ndarray) -> np.ndarray:
    """Labels (n,) of the connected components of the nonzero pattern of the symmetric ``M`` (n, n):
    two indices share a label when a chain of nonzero entries joins them (the smallest index of the
    component is its label)."""
    n = len(M)
    linked = (M != 0.0) | (M.T != 0.0) | np.eye(n, dtype=bool)
    labels = np.arange(n)
    while True:  # each pass takes the smallest label among the neighbours: at most a component's diameter
        new = np.where(linked, labels[None, :], n).min(axis=1)
        if np.array_equal(new, labels):
            return labels
        labels = new


def blocks_by_width(M: np.ndarray) -> list[np.ndarray]:
    """The connected blocks of the symmetric ``M`` (n, n) (:func:`connected_blocks`) grouped by width:
    one (b, w) array of indices (each block's ascending, blocks in the order of their smallest
    index) per width ``w``, widths ascending."""
    _, comp = np.unique(connected_blocks(M), return_inverse=True)
    comp = comp.ravel()
    members = np.split(np.argsort(comp, kind="stable"), np.cumsum(np.bincount(comp))[:-1])
    widths = np.array([len(m) for m in members])
    return [np.array([m for m in members if len(m) == w]) for w in np.unique(widths)]


def marginal_information(info: np.ndarray, g: np.ndarray, s: np.ndarray) -> np.ndarray:
    """``info[g, g] - info[g, s] pinv(info[s, s]) info[s, g]``: the information of the ``g`` indices
    with the ``s`` ones marginalised, the pseudo-inverse taken per connected block of ``info[s, s]``.

    Parameters
    ----------
    info : ndarray, shape (P, P)
        A symmetric information matrix.
    g, s : ndarray of int
        The kept and the marginalised indices.

    Returns
    -------
    ndarray, shape (len(g), len(g))
    """
    A, B, C, Bt = info[np.ix_(g, g)], info[np.ix_(g, s)], info[np.ix_(s, s)], info[np.ix_(s, g)]
    if len(s) <= DENSE_UP_TO:  # a few unknowns (planes, station frames): one dense pinv is cheaper
        return A - B @ np.linalg.pinv(C, rcond=RCOND) @ Bt
    parts = []  # (indices (b, w), U (b, w, w), singular values (b, w), Vt (b, w, w)) per block width
    for idx in blocks_by_width(C):
        U, sv, Vt = np.linalg.svd(C[idx[:, :, None], idx[:, None, :]])
        parts.append((idx, U, sv, Vt))
    cutoff = RCOND * max(float(p[2].max()) for p in parts)
    out = A.copy()
    for idx, U, sv, Vt in parts:
        inv_s = np.where(sv > cutoff, 1.0 / np.where(sv > cutoff, sv, 1.0), 0.0)
        Bb = B[:, idx].transpose(1, 0, 2)  # (b, G, w)
        left = np.matmul(Bb, Vt.transpose(0, 2, 1)) * inv_s[:, None, :]  # B V S^+
        right = np.matmul(U.transpose(0, 2, 1), Bt[idx])  # U^T B^T
        out -= np.einsum("bgw,bwh->gh", left, right)
    return out


MAX_BLOCK = 12  # widest set-up block the split takes (a plate's two sockets: 6; a station frame: 6)


class SetupSplit:
    """Solves and inverses of a symmetric positive definite ``S`` (P, P) whose set-up block is block
    diagonal: the robot's ``g`` indices dense, the set-up ``s`` ones in small connected blocks.

    With ``W = S_ss^-1 S_sg`` (per block) and ``K = S_gg - S_gs W`` (the robot's Schur complement), a
    solve is one (g, g) solve and per-block ones, and the inverse is ``[[K^-1, -K^-1 W^T], [-W K^-1,
    S_ss^-1 + W K^-1 W^T]]``: the same matrix as the dense one's (to rounding), at a cost of
    ``s g^2`` instead of ``P^3`` (0.26 against 0.92 ms for the inverse at 198 socket coordinates beside
    21 parameters; the step's solve 0.12 against 0.38 ms).

    Parameters
    ----------
    g, s : ndarray of int
        The dense and the set-up indices (together all P).
    blocks : list of ndarray of int, each (b, w)
        The set-up block's connected blocks of one width ``w``, as rows of indices into ``s``.
    """

    def __init__(self, g: np.ndarray, s: np.ndarray, blocks: list[np.ndarray]) -> None:
        self.g, self.s, self.blocks = g, s, blocks
        self.order = np.concatenate([b.reshape(-1) for b in blocks])  # the set-up entries block by block
        self.s_rows = s[self.order]  # their indices in S
        self._in_s = [s[idx] for idx in blocks]  # each width's blocks as indices in S

    @classmethod
    def of(cls, S: np.ndarray, g: np.ndarray, s: np.ndarray) -> SetupSplit | None:
        """The split of ``S``'s pattern, or None where the dense algebra is as cheap (few set-up
        unknowns) or the blocks are wide."""
        if len(s) <= DENSE_UP_TO:
            return None
        blocks = blocks_by_width(S[np.ix_(s, s)])
        return None if blocks[-1].shape[1] > MAX_BLOCK else cls(g, s, blocks)

    def _parts(self, S: np.ndarray):
        """``(S_gg, S_sg in block order (s, g), [per-width block inverses (b, w, w)], W (s, g))``."""
        Sgg, Ssg = S[np.ix_(self.g, self.g)], S[np.ix_(self.s_rows, self.g)]
        inverses, W, at = [], np.empty_like(Ssg), 0
        for idx in self._in_s:
            b, w = idx.shape
            inv = np.linalg.inv(S[idx[:, :, None], idx[:, None, :]])  # LinAlgError where a block is singular
            inverses.append(inv)
            W[at:at + b * w] = np.matmul(inv, Ssg[at:at + b * w].reshape(b, w, -1)).reshape(b * w, -1)
            at += b * w
        return Sgg, Ssg, inverses, W

    def _blocks_times(self, inverses, v: np.ndarray) -> np.ndarray:
        """The block-diagonal ``S_ss^-1`` (in block order) times ``v`` (s,)."""
        out, at = np.empty_like(v), 0
        for idx, inv in zip(self.blocks, inverses):
            b, w = idx.shape
            out[at:at + b * w] = np.matmul(inv, v[at:at + b * w].reshape(b, w, 1)).reshape(-1)
            at += b * w
        return out

    def solve(self, S: np.ndarray, rhs: np.ndarray) -> np.ndarray:
        """``S^-1 rhs`` (P,)."""
        Sgg, Ssg, inverses, W = self._parts(S)
        s_rows = self.s_rows
        y = self._blocks_times(inverses, rhs[s_rows])
        x_g = np.linalg.solve(Sgg - Ssg.T @ W, rhs[self.g] - Ssg.T @ y)
        out = np.empty_like(rhs)
        out[self.g] = x_g
        out[s_rows] = y - W @ x_g
        return out

    def inverse(self, S: np.ndarray) -> np.ndarray:
        """``S^-1`` (P, P)."""
        Sgg, Ssg, inverses, W = self._parts(S)
        Kinv = np.linalg.inv(Sgg - Ssg.T @ W)
        s_rows = self.s_rows
        out = np.empty_like(S)
        WK = W @ Kinv  # (s, g)
        out[np.ix_(self.g, self.g)] = Kinv
        out[np.ix_(s_rows, self.g)] = -WK
        out[np.ix_(self.g, s_rows)] = -WK.T
        Vss = WK @ W.T
        at = 0
        for idx, inv in zip(self.blocks, inverses):
            b, w = idx.shape
            k = at + np.arange(b * w).reshape(b, w)
            Vss[k[:, :, None], k[:, None, :]] += inv
            at += b * w
        out[np.ix_(s_rows, s_rows)] = Vss
        return out
