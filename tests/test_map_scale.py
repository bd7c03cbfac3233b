"""The joint-error map's solve at scale (issue 25): the compact design, the cross-validation's
products and the warm-started refits give the plain computation's numbers."""

import numpy as np
import pytest
from test_joint_errors import PHI, SPEC, _simulate

from fgcal.estimation.calibrate import CalibrationOptions, calibrate
from fgcal.estimation.graph_block import compact_design as _compact_design
from fgcal.estimation.joint_errors import JointErrorBlock, JointErrorSpec
from fgcal.estimation.model_select import CVProblem, _folds
from fgcal.estimation.time_validation import FoldSums
from fgcal.robots.gravity import model_inertials
from fgcal.robots.robot_file import load_model

UR10 = load_model("ur10")


def test_compact_design_is_the_dense_one():
    rng = np.random.default_rng(3)
    spec = JointErrorSpec(compliance=(2, 3), harmonics=3)
    block = JointErrorBlock.build(spec, 6, model_inertials(UR10))
    q = rng.uniform(-3, 3, (7, 6))
    G = block.design(q, UR10.nominal)
    g, joint = _compact_design(G, 7, 6)
    np.testing.assert_array_equal(joint, block.joints)
    np.testing.assert_array_equal(g, block.design_columns(q, UR10.nominal))
    dense = np.zeros_like(G)
    dense[:, joint, np.arange(len(block))] = g
    np.testing.assert_array_equal(dense, G)  # nothing of G is lost: one joint per parameter
    assert block.joints.tolist()[:2] == [1, 2] and G[:, 1, 0].std() > 1.0  # the compliances: gravity torques (N m)
    G[:, 0, 0] = 1.0  # a parameter moving two joints is refused, not folded silently
    with pytest.raises(ValueError, match="one joint"):
        _compact_design(G, 7, 6)


@pytest.mark.parametrize("same_rows", [True, False])
def test_cross_validation_matches_a_plain_refit_per_fold(same_rows):
    rng = np.random.default_rng(11)
    n, m, p, k = 90, 6, 9, 4
    J = rng.normal(size=(n, m, p))
    r = rng.normal(size=(n, m))
    rows = np.tile([3, 4, 5], (n, 1)) if same_rows else np.array([rng.permutation(m)[:3] for _ in range(n)])
    groups = np.repeat(np.arange(n // 2), 2)  # repeated configurations share a fold
    prob = CVProblem(r, J, rows, 2.0, [f"x{i}" for i in range(p)], 5, groups)
    fold = _folds(groups, k, np.random.default_rng(0))
    cols = [0, 1, 2, 3, 4, 6, 8]
    sigma = np.array([np.inf] * 5 + [0.3, 0.1])
    err = FoldSums(prob, fold, k).held_out_errors(cols, sigma)
    want = np.zeros(n)
    for f in range(k):  # the plain way: refit on the other folds' rows, predict this fold's
        out, inside = fold != f, fold == f
        Jo = J[out][:, :, cols].reshape(-1, len(cols))
        A = Jo.T @ Jo + np.diag(np.where(np.isfinite(sigma), 1 / sigma**2, 0.0))
        x = -np.linalg.solve(A, Jo.T @ r[out].reshape(-1))
        pred = r[inside] + J[inside][:, :, cols] @ x
        want[inside] = np.linalg.norm(np.take_along_axis(pred, rows[inside], axis=1), axis=1) * 2.0
    np.testing.assert_allclose(err, want, rtol=1e-7)
    assert len(np.unique(fold)) == k and all(len(set(fold[groups == g])) == 1 for g in np.unique(groups))


def test_warm_started_fit_reaches_the_cold_optimum():
    rng = np.random.default_rng(7)
    ds, _ = _simulate(rng, 150, PHI, SPEC)
    opts = CalibrationOptions(joint_errors=SPEC)
    cold = calibrate(ds, UR10, opts)
    geometric = calibrate(ds, UR10, CalibrationOptions())
    warm = calibrate(ds, UR10, opts, warm=geometric)
    again = calibrate(ds, UR10, opts, warm=cold)
    for res in (warm, again):
        assert res.names == cold.names
        d = [(a.estimate - b.estimate) / b.sigma for a, b in zip(res.parameters, cold.parameters)]
        assert np.max(np.abs(d)) < 1e-4
        np.testing.assert_allclose([p.sigma for p in res.parameters], [p.sigma for p in cold.parameters], rtol=1e-6)
        # the per-pose nominal residuals are those of the usual start, not of the warm one
        np.testing.assert_allclose([p.nominal_mm for p in res.pose_residuals],
                                   [p.nominal_mm for p in cold.pose_residuals], rtol=1e-12)
    assert again.iterations < cold.iterations and warm.iterations <= cold.iterations
