import numpy as np
import pytest
from conftest import random_joints

from fgcal.robots.ik import BRANCHES, IKError, solve_numeric, solve_puma
from fgcal.robots.kinematics import forward
from fgcal.robots.model import SLOT_IS_ANGLE


def test_all_eight_branches_round_trip(puma):
    q = random_joints(puma, 40, seed=7)
    found = set()
    for qi in q:
        T = forward(puma.nominal, qi)[0]
        solutions = []
        for branch in BRANCHES:
            sol = solve_puma(puma, T, branch)
            np.testing.assert_allclose(forward(puma.nominal, sol)[0], T, atol=1e-8)
            solutions.append(sol)
        # The eight solutions are distinct and one of them is the joint set we started from.
        assert len({tuple(np.round(s, 6)) for s in solutions}) == 8
        dist = [np.abs(np.angle(np.exp(1j * (s - qi)))).max() for s in solutions]
        assert min(dist) < 1e-8
        found.add(str(BRANCHES[int(np.argmin(dist))]))
    assert len(found) >= 6  # random joint sets land in most branches


def test_branch_flags_are_honoured(puma):
    T = forward(puma.nominal, np.radians([10, 30, -50, 20, 40, 10]))[0]
    for branch in BRANCHES:
        q = solve_puma(puma, T, branch)
        assert (q[4] < 0) == branch.flip


def test_unreachable_target_raises(puma):
    T = np.eye(4)
    T[:3, 3] = [5000.0, 0, 0]
    with pytest.raises(IKError, match="out of reach"):
        solve_puma(puma, T, BRANCHES[0])


def test_numeric_ik_on_a_calibrated_model(puma):
    rng = np.random.default_rng(8)
    x = puma.nominal + np.where(SLOT_IS_ANGLE, np.radians(0.05), 0.5) * rng.normal(size=37)
    for qi in random_joints(puma, 10, seed=9):
        T = forward(x, qi)[0]
        seed = qi + rng.normal(size=6) * 0.02
        sol = solve_numeric(puma, T, seed, slots=x)
        np.testing.assert_allclose(forward(x, sol)[0], T, atol=1e-8)
    # closed form of the nominal seeds the numeric solve of the calibrated model
    T = forward(x, np.radians([30, 60, -80, 40, 50, 20]))[0]
    q0 = next(q for q in (solve_puma(puma, T, b) for b in BRANCHES) if puma.in_limits(q)[0])
    np.testing.assert_allclose(forward(x, solve_numeric(puma, T, q0, slots=x))[0], T, atol=1e-8)


def test_closed_form_refuses_other_structures(ur10):
    with pytest.raises(IKError, match="PUMA"):
        solve_puma(ur10, np.eye(4), BRANCHES[0])
