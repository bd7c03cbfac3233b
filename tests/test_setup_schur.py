"""The set-up block marginalised per connected block equals the dense pseudo-inverse's Schur complement."""
import numpy as np

from fgcal.estimation.setup_schur import connected_blocks, marginal_information


def _information(rng, blocks, n_geo=12, singular=()):
    """A PSD information J^T J whose set-up rows touch the geometric columns and one block each;
    the blocks in ``singular`` are rank-deficient (a coordinate no row sees)."""
    n_s = sum(blocks)
    rows = []
    start = n_geo
    for b, w in enumerate(blocks):
        for _ in range(3 * w):
            r = np.zeros(n_geo + n_s)
            r[:n_geo] = rng.normal(size=n_geo)
            r[start:start + w] = rng.normal(size=w)
            if b in singular:
                r[start + w - 1] = 0.0
            rows.append(r)
        start += w
    J = np.array(rows)
    return J.T @ J


def _dense(info, g, s):
    return info[np.ix_(g, g)] - info[np.ix_(g, s)] @ np.linalg.pinv(info[np.ix_(s, s)]) @ info[np.ix_(s, g)]


def test_connected_blocks_follow_chains():
    M = np.zeros((7, 7))
    M[0, 3] = M[3, 5] = 1.0  # 0-3-5 a chain
    M[1, 2] = 2.0
    np.fill_diagonal(M, 1.0)
    labels = connected_blocks(M + M.T)
    assert labels.tolist() == [0, 1, 1, 0, 4, 0, 6]


def test_blocks_equal_dense_pinv():
    rng = np.random.default_rng(3)
    blocks = [3] * 20 + [6] * 10 + [9]  # sockets, plates of two, a chain of three
    info = _information(rng, blocks, singular=(4, 25))
    n_geo = 12
    g, s = np.arange(n_geo), np.arange(n_geo, len(info))
    assert len(s) > 36  # past the dense shortcut
    dense = _dense(info, g, s)
    blocked = marginal_information(info, g, s)
    assert np.abs(blocked - dense).max() <= 1e-10 * np.abs(dense).max()
    # and the singular blocks matter: an inverse of their regularised form differs
    assert np.linalg.matrix_rank(info[np.ix_(s, s)]) == len(s) - 2


def test_small_set_up_block_is_dense():
    rng = np.random.default_rng(4)
    info = _information(rng, [3, 3, 6])
    g, s = np.arange(12), np.arange(12, len(info))
    np.testing.assert_allclose(marginal_information(info, g, s), _dense(info, g, s), rtol=0, atol=1e-12 * np.abs(info).max())
