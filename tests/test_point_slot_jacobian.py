"""Chain.point_slot_jacobian against the full Jacobians' point columns and finite differences."""
import numpy as np
import pytest

from fgcal.robots.jacobian_rank import slot_jacobian
from fgcal.robots.robot_file import load_model as load_robot


@pytest.mark.parametrize("n,balls", [(3000, 1), (400, 3), (5, 1), (1, 2)])
def test_same_numbers_as_full_jacobians(n, balls):
    model = load_robot("ur10")
    chain, rng = model.chain, np.random.default_rng(n + balls)
    x = model.nominal + rng.normal(size=model.nominal.shape) * 1e-3
    q = rng.uniform(-3, 3, size=(n, model.n_joints))
    off = rng.normal(size=(balls, 3)) * 50
    idx = rng.permutation(chain.n_slots)[:25]
    full = chain.jacobians(x, q, offsets=off).point_slots[..., idx].reshape(-1, len(idx))
    np.testing.assert_array_equal(slot_jacobian(chain, x, q, idx, off), full)


def test_against_finite_differences():
    model = load_robot("ur10")
    chain, rng = model.chain, np.random.default_rng(7)
    x = model.nominal + rng.normal(size=model.nominal.shape) * 1e-3
    q = rng.uniform(-3, 3, size=(2000, model.n_joints))
    off = np.array([[10.0, -5.0, 60.0]])
    idx = np.arange(chain.n_slots)
    J = chain.point_slot_jacobian(x, q, off, idx)
    h = 1e-6
    for s in rng.choice(chain.n_slots, 6, replace=False):
        dx = np.zeros_like(x)
        dx[s] = h
        fp = chain.jacobians(x + dx, q, offsets=off).points.reshape(-1)
        fm = chain.jacobians(x - dx, q, offsets=off).points.reshape(-1)
        np.testing.assert_allclose(J[:, s], (fp - fm) / (2 * h), atol=1e-5)
