"""Solves and inverses by the set-up block's connected blocks (SetupSplit) against the dense ones."""
import numpy as np
import pytest

from fgcal.estimation.elimination import scaled_inverse
from fgcal.estimation.setup_schur import DENSE_UP_TO, MAX_BLOCK, SetupSplit

G = 21


def _information(rng, widths):
    """A robot-and-fixtures information (P, P): every fixture block couples with the robot's G
    parameters and itself only; blocks of the given widths, their entries shuffled among the set-up's."""
    P = G + sum(widths)
    J = []
    at = G
    for w in widths:
        for _ in range(4 * w):  # rows seeing the robot and this block
            row = np.zeros(P)
            row[:G] = rng.normal(size=G)
            row[at:at + w] = rng.normal(size=w)
            J.append(row)
        at += w
    J = np.array(J)
    S = J.T @ J + 1e-3 * np.eye(P)
    order = np.concatenate([np.arange(G), G + rng.permutation(P - G)])
    return S[np.ix_(order, order)]


@pytest.mark.parametrize("widths", [[3] * 30, [6] * 10 + [3] * 8, [3, 6, 9] * 5])
def test_solve_and_inverse_equal_the_dense_ones(widths):
    rng = np.random.default_rng(len(widths))
    S = _information(rng, widths)
    P = len(S)
    split = SetupSplit.of(S, np.arange(G), np.arange(G, P))
    assert split is not None and sorted(b.shape[1] for b in split.blocks) == sorted(set(widths))
    b = rng.normal(size=P)
    x = np.linalg.solve(S, b)
    np.testing.assert_allclose(split.solve(S, b), x, rtol=0, atol=1e-10 * np.abs(x).max())
    V = np.linalg.inv(S)
    np.testing.assert_allclose(split.inverse(S), V, rtol=0, atol=1e-10 * np.abs(V).max())
    np.testing.assert_allclose(scaled_inverse(S, split), V, rtol=0, atol=1e-10 * np.abs(V).max())


def test_dense_algebra_for_few_set_up_unknowns_or_wide_blocks():
    rng = np.random.default_rng(1)
    few = _information(rng, [3] * (DENSE_UP_TO // 3))
    assert SetupSplit.of(few, np.arange(G), np.arange(G, len(few))) is None
    wide = _information(rng, [MAX_BLOCK + 3] * 3)
    assert SetupSplit.of(wide, np.arange(G), np.arange(G, len(wide))) is None


def test_a_singular_block_falls_back_to_the_dense_pseudo_inverse():
    rng = np.random.default_rng(2)
    S = _information(rng, [3] * 20)
    P = len(S)
    split = SetupSplit.of(S, np.arange(G), np.arange(G, P))
    k = G + int(np.flatnonzero(np.any(S[G:, G:] != 0, axis=0))[0])  # one set-up entry: no information at all
    S[k, :] = S[:, k] = 0.0
    with pytest.raises(np.linalg.LinAlgError):
        split.inverse(S)
    V = scaled_inverse(S, split)
    np.testing.assert_array_equal(V, scaled_inverse(S))  # the dense path's pseudo-inverse
    live = np.arange(P) != k
    np.testing.assert_allclose(V[np.ix_(live, live)], np.linalg.inv(S[np.ix_(live, live)]), rtol=1e-8, atol=1e-12)
