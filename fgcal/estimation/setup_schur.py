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

__all__ = ["connected_blocks", "marginal_information"]

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
    labels = connected_blocks(C)
    _, comp = np.unique(labels, return_inverse=True)
    members = [np.flatnonzero(comp == k) for k in range(comp.max() + 1)]
    sizes = np.array([len(m) for m in members])
    parts = []  # (indices (b, w), U (b, w, w), singular values (b, w), Vt (b, w, w)) per block width
    for w in np.unique(sizes):
        idx = np.array([m for m in members if len(m) == w])
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
