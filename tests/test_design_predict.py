"""The predicted accuracy of a plan (fgcal.studies.design_predict): finite and equal to the
inverse's where the plan determines what the verification weight sees, +inf where it does not,
the same in any parameter units and with set-up blocks marginalised or estimated. Checked on
constructed information (a parameter no pose sees) and on the 12-pose random sets of contacts
and planes (tests/test_matrix.py's dataset), whose decisions are checked independently: the
ridge-regularised solve ``trace(Ws (Ms + e I)^-1)`` converges as ``e`` falls (to the prediction)
where the plan predicts, and grows like ``1 / e`` where it does not."""
import re

import numpy as np
import pytest
from test_matrix import _contacts

import fgcal.studies.design_dataset as design_dataset
from fgcal.io.dataset_io import dataset_model, load_dataset
from fgcal.studies.design import marginal, random_design_values
from fgcal.studies.design_dataset import DatasetDesign
from fgcal.studies.design_predict import predicted_mse, predicted_rms


def _problem(rng, P=8, rows=40, unseen=None):
    J = rng.normal(size=(rows, P)) * rng.uniform(0.1, 10.0, size=P)
    if unseen is not None:
        J[:, unseen] = 0.0
    V = rng.normal(size=(12, P))
    return J.T @ J, V.T @ V / 12, rng.uniform(0.5, 2.0, size=P)


def test_full_rank_equals_the_inverse_and_units_do_not_matter():
    rng = np.random.default_rng(3)
    info, W, scale = _problem(rng)
    B = info * rng.uniform(0.5, 2.0)  # a sandwich middle
    inv = np.linalg.inv(info)
    assert predicted_rms(info, W, scale=scale) == pytest.approx(np.sqrt(np.trace(W @ inv)), rel=1e-12)
    assert predicted_rms(info, W) == pytest.approx(np.sqrt(np.trace(W @ inv)), rel=1e-12)  # default scale
    assert predicted_rms(info, W, B, scale) == pytest.approx(np.sqrt(np.trace(W @ inv @ B @ inv)), rel=1e-12)
    # parameter 2 in units a thousand times smaller (mm -> um): its rows of J, so of info and W, /1e3
    t = np.ones(len(scale))
    t[2] = 1e3
    T = np.outer(1 / t, 1 / t)
    for mid in (None, B):
        before = predicted_rms(info, W, mid, scale)
        after = predicted_rms(info * T, W * T, None if mid is None else mid * T, scale * t)
        assert after == pytest.approx(before, rel=1e-12)


def test_a_parameter_no_pose_sees():
    rng = np.random.default_rng(4)
    info, W, scale = _problem(rng, unseen=5)
    assert not np.any(info[5])
    assert predicted_rms(info, W, scale=scale) == np.inf  # W sees it: no plan of these poses predicts
    assert predicted_rms(info, W, info, scale) == np.inf
    t = np.ones(len(scale))
    t[5] = 1e3  # in any unit
    assert predicted_rms(info / np.outer(t, t), W / np.outer(t, t), scale=scale * t) == np.inf
    # W does not see it: the prediction is the inverse's over the others, exactly
    W[5], W[:, 5] = 0.0, 0.0
    keep = np.arange(len(scale)) != 5
    sub = np.ix_(keep, keep)
    expected = np.sqrt(np.trace(W[sub] @ np.linalg.inv(info[sub])))
    assert predicted_rms(info, W, scale=scale) == pytest.approx(expected, rel=1e-12)


@pytest.fixture(scope="module")
def contacts(tmp_path_factory):
    """Contacts and planes (test_matrix's), the information of its candidates and a 12-pose design."""
    ds_path = _contacts(tmp_path_factory.mktemp("predict"))
    ds = load_dataset(ds_path)
    seen = {}
    plan_of = design_dataset.design_plan

    def spy(*args, **kwargs):
        seen["prep"] = kwargs["prepared"]
        return plan_of(*args, **kwargs)

    design_dataset.design_plan = spy
    try:
        plan = design_dataset.design_from_dataset(ds, dataset_model(ds), 12, random_sets=10)
    finally:
        design_dataset.design_plan = plan_of
    return plan, seen["prep"]


def _ridge_limit(M, W, scale, eps):
    """trace(Ws (Ms + eps I)^-1): a solve, the ridge far above the matrices' rounding."""
    D = np.outer(scale, scale)
    return np.trace(np.linalg.solve(M * D + eps * np.eye(len(scale)), W * D))


def test_random_contact_plans_predict_a_value_or_inf(contacts):
    plan, prep = contacts
    P, S = len(prep.names), prep.n_setup
    W, scale = prep.W[:P, :P], prep.scale[:P]
    assert 0 < plan.values["pred"] < 1.0 and np.isfinite(plan.values["pred"])  # measured 0.155 mm
    everything = prep.values(np.nonzero(prep.usable)[0])["pred"]
    rng = np.random.default_rng(11)
    finite = infinite = 0
    for _ in range(60):
        sel, values = random_design_values(prep, 12, rng)
        pred = values["pred"]
        total, _ = prep.total(sel)
        M = marginal(total, S)
        top = np.linalg.eigvalsh(M * np.outer(scale, scale))[-1]
        small, smaller = (_ridge_limit(M, W, scale, f * top) for f in (1e-7, 1e-8))
        # estimated with the set-up blocks as parameters the verification does not see: the same
        whole = np.sqrt(predicted_mse(total[None], prep.W, prep.scale)[0])
        # the first length in metres (its information and weight 1e6 times larger, its scale 1e3 smaller)
        t = np.ones(P)
        t[0] = 1e-3
        T = np.outer(1 / t, 1 / t)
        metres = np.sqrt(predicted_mse((M * T)[None], W * T, scale * t)[0])
        assert metres == pred or metres == pytest.approx(pred, rel=1e-9)
        if np.isfinite(pred):
            finite += 1
            assert pred >= everything * (1 - 1e-9)  # fewer poses never predict better than all of them
            assert smaller / small == pytest.approx(1.0, abs=1e-2)
            assert pred**2 == pytest.approx(smaller, rel=1e-2)
            assert whole == pytest.approx(pred, rel=1e-6)
        else:
            infinite += 1
            assert smaller / small > 5.0  # grows like 1/eps: W sees a direction the plan leaves free
            assert whole == np.inf
    assert finite >= 1 and infinite >= 1, (finite, infinite)  # both occur (measured: 4 and 56)


def test_summary_with_random_plans_that_cannot_predict():
    d = DatasetDesign(np.arange(3), np.zeros((3, 6)), "pred", {"pred": 0.15}, np.array([0.3, 0.2, np.inf, np.inf]),
                      ("contacts",), 10, 10, 2, floor_mm=0.05)
    assert d.random_quartiles() == (0.275, np.inf, np.inf)
    text = "\n".join(d.summary())
    assert "median inf" in text and not re.search(r"\bnan\b", text) and "gain of" not in text
    assert "2 of them inf" in text
    d.random_pred = np.array([0.3, 0.2, 0.4, np.inf])
    assert d.random_quartiles()[1] == pytest.approx(0.35)
    assert "a gain of" in "\n".join(d.summary())
