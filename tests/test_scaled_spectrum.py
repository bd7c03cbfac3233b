"""The scaled spectrum that the covariance check and the identifiability at the solution share."""
import numpy as np

from fgcal.robots.jacobian_rank import ScaledSpectrum, analyse_information


def _information(rng, P, rank=None):
    J = rng.normal(size=(3 * P, P)) * rng.uniform(0.01, 100.0, size=P)  # columns of very different scales
    if rank is not None:  # the last columns combinations of the first: P - rank null directions
        J[:, rank:] = J[:, :rank] @ rng.normal(size=(rank, P - rank))
    return J.T @ J


def test_values_are_the_scaled_eigenvalues_and_vectors_come_on_demand():
    rng = np.random.default_rng(3)
    S = _information(rng, 40)
    spec = ScaledSpectrum(S)
    d = np.sqrt(np.diag(S))
    ref = np.linalg.eigvalsh(S / np.outer(d, d))
    np.testing.assert_allclose(spec.values, ref, rtol=1e-10)
    V = spec.vectors
    np.testing.assert_allclose(V @ np.diag(spec.values) @ V.T, S / np.outer(d, d), atol=1e-10)


def test_a_shared_spectrum_names_the_same_redundancies():
    rng = np.random.default_rng(4)
    names = [f"p{i}" for i in range(12)]
    for rank in (None, 10):
        S = _information(rng, 12, rank)
        alone = analyse_information(S, names)
        shared = analyse_information(S, names, spectrum=ScaledSpectrum(S))
        assert alone.redundant == shared.redundant
        assert len(alone.redundant) == (0 if rank is None else 2)
        np.testing.assert_allclose(alone.singular_values, shared.singular_values, rtol=1e-10, atol=1e-12)


def test_a_parameter_without_information_is_not_live():
    rng = np.random.default_rng(5)
    S = _information(rng, 6)
    S[2, :] = S[:, 2] = 0.0
    spec = ScaledSpectrum(S)
    assert not spec.live[2] and spec.live.sum() == 5
    assert np.sum(spec.values <= 1e-12 * spec.values[-1]) == 1
    assert list(analyse_information(S, list("abcdef"), spectrum=spec).redundant) == ["c"]
