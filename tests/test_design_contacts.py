"""Design for contacts (DESIGN.md 8.2): which configurations to record at each fixture.

The candidates are a dataset's poses, each at its fixture; the information is over the
parameters and the fixture blocks, with the blocks' known distances, and the criterion
marginalises the blocks. The verification weight is the consistency's (what a contact user
verifies at new placements, :mod:`fgcal.studies.design_consistency`), not the tool positions'.
Checked here: that information is the batch estimator's own (the graph's normal equations at the
same point); the weight is the curvature of the consistency verify computes (by refitting); and
on two-socket plates from the independent generator (tests/contact_sim.py), over 6 datasets per
robot, the designed plans of 12 poses per placement verify at 3 other plates with a mean
consistency below the mean of the random plans' medians, and the predicted value ranks the random
plans' realised consistency, whose mean square is the expected one (the seatings' scatter plus
tr(W_check Sigma) at the check plates' contacts)."""
from dataclasses import replace

import numpy as np
import pytest
from contact_sim import two_socket_dataset
from scipy.stats import spearmanr
from test_contacts_simulated import DATA, ROBOTS

from fgcal.estimation.calibrate import CalibrationOptions, build_graph, calibrate
from fgcal.estimation.noise import NoiseMode
from fgcal.estimation.verification import verify
from fgcal.io.dataset_io import dataset_model, load_dataset
from fgcal.robots.deviations import Deviations
from fgcal.studies.design import Candidates, random_design_values, verification_weight
from fgcal.studies.design_consistency import candidates_of, consistency_weight
from fgcal.studies.design_dataset import (
    dataset_layout,
    dataset_noise,
    design_from_dataset,
    placement_of,
    with_dataset_tooling,
)

PER_PLACEMENT = 12
SEATING_MM = 0.02  # each seating's error per axis (mm), as _plates simulates it


def _plates(tmp, robot, seed):
    """3 plates of two sockets, 20 configurations per socket (the candidates), and 3 other
    plates of the same true robot (the verification)."""
    name, chain = ROBOTS[robot]
    rng = np.random.default_rng(seed)
    train = two_socket_dataset(tmp / "train", DATA / name, chain, rng, n_placements=3, configs_per_socket=20,
                               contact_sigma_mm=SEATING_MM, distance_sigma_mm=0.0005)
    two_socket_dataset(tmp / "check", DATA / name, chain, rng, n_placements=3, configs_per_socket=10,
                       contact_sigma_mm=SEATING_MM, distance_sigma_mm=0.0005, true_urdf=train.urdf)
    return load_dataset(tmp / "train"), load_dataset(tmp / "check")


def test_design_information_is_the_estimators(tmp_path):
    ds, _ = _plates(tmp_path, "kinova", 2)
    model = with_dataset_tooling(ds, dataset_model(ds))
    names = [n for n in model.parameters().names if not n.startswith("base.") and n not in ("tool.phi", "tool.theta",
                                                                                              "tool.psi")]
    graph, state, _ = build_graph(ds, model, names, CalibrationOptions(prior="none"))
    layout = dataset_layout(ds, model)  # the blocks started at the nominal geometry, as the graph's
    np.testing.assert_allclose(layout.setup.start, graph.setup.start)
    params = type(model.parameters())(model, tuple(names))
    prep = Candidates.build(model, model.joints_to_internal(ds.joints_deg), ds.noise, layout=layout, params=params,
                            sigmas=graph.sigmas)
    assert prep.n_setup == graph.S and not prep.dropped
    total, _ = prep.total(np.arange(ds.n_poses))
    expected = graph.parameter_information(state)
    np.testing.assert_allclose(total, expected, rtol=1e-8, atol=1e-9 * np.abs(expected).max())


SEEDS = (1, 2, 3, 4, 5, 6)
RANDOM_PLANS = 24


def _consistency(ds, held, model, sel):
    """Held-out socket consistency (mm) of a calibration from ``ds``'s poses at rows ``sel``."""
    result = calibrate(ds.select(ds.pose_ids[sel]), model)
    return verify(result, held, model).contacts["after"]["consistency_mm"]["rms"]


@pytest.mark.parametrize("robot", ["kinova", "panda"])
def test_designed_plan_beats_random_plans(tmp_path, robot):
    """In expectation over datasets: the consistency a plan is verified by at 3 other plates has a
    large share no plan removes (each seating's 0.02 mm per axis: 0.033 mm RMS at the true robot), so
    one dataset's plan beats the random median only as often as the gain (a few per cent) beats the
    scatter. Over 6 datasets: the designed plans' mean consistency is below the mean of the random
    plans' medians, the predicted value ranks the random plans' realised ones (Spearman > 0 on
    average), and on every dataset the design predicts better than the median random plan."""
    designed, medians, ranks, realised2, expected2 = [], [], [], [], []
    for seed in SEEDS:
        ds, held = _plates(tmp_path / str(seed), robot, seed)
        model = with_dataset_tooling(ds, dataset_model(ds))
        found = dataset_noise(ds, model)
        plan = design_from_dataset(ds, model, PER_PLACEMENT, per_placement=True, rng=np.random.default_rng(0),
                                   random_sets=50, noise=found)
        assert plan.measure == "consistency"
        layout = dataset_layout(ds, model, slots=found.slots)
        groups = placement_of(layout, layout.setup.spec)
        chosen = ds.row_of(plan.pose_ids)
        assert np.array_equal(np.bincount(groups[chosen]), [PER_PLACEMENT] * 3)  # 12 at each placement
        assert plan.values["pred"] < np.median(plan.random_pred)
        prep = candidates_of(ds, model, model.joints_to_internal(ds.joints_deg), layout, found)
        # the expectation at the check plates: the seatings' own scatter (3 axes of SEATING_MM, less
        # what each socket's refitted point takes) plus tr(W_check Sigma), W_check from their contacts
        check = dataset_layout(held, model, slots=found.slots)
        W_check = consistency_weight(model, model.joints_to_internal(held.joints_deg), check,
                                     type(model.parameters())(model, prep.names), found.slots)
        at_check = replace(prep, W=np.pad(W_check, (0, prep.n_setup)))
        n_f = np.unique(held.contacts.fixture, return_counts=True)[1]
        seating2 = 3 * SEATING_MM**2 * np.sum(n_f - 1) / np.sum(n_f)
        rng = np.random.default_rng(seed)
        pred, real = [], []
        for _ in range(RANDOM_PLANS):
            sel, values = random_design_values(prep, PER_PLACEMENT, rng, groups)
            pred.append(values["pred"])
            real.append(_consistency(ds, held, model, sel))
            expected2.append(seating2 + at_check.values(sel)["pred"] ** 2)
        realised2 += [r**2 for r in real]
        designed.append(_consistency(ds, held, model, chosen))
        medians.append(float(np.median(real)))
        ranks.append(spearmanr(pred, real)[0])
    print(f"{robot}: designed {np.round(designed, 4)} (mean {np.mean(designed):.4f}); random medians "
          f"{np.round(medians, 4)} (mean {np.mean(medians):.4f}); rank(pred, realised) {np.round(ranks, 2)}; "
          f"mean squared consistency {np.mean(realised2):.3e} mm^2 against {np.mean(expected2):.3e} expected")
    assert 0.85 < np.mean(realised2) / np.mean(expected2) < 1.2
    assert np.mean(designed) < np.mean(medians)
    assert np.mean(ranks) > 0


def test_consistency_weight_is_the_consistencys_curvature(tmp_path):
    """``W_c`` against the consistency verify computes (fgcal.estimation.consistency, by refitting):
    the squared consistency at the held-out plates is quadratic in a parameter change ``d`` with
    curvature ``d^T W_c d`` (the even part of ``c(x + d)^2``, exact for the linearised model)."""
    from fgcal.estimation.consistency import contact_consistency

    ds, held = _plates(tmp_path, "kinova", 2)
    model = with_dataset_tooling(held, dataset_model(held))
    layout = dataset_layout(held, model)
    params = model.parameters()
    q = model.joints_to_internal(held.joints_deg)
    Wc = consistency_weight(model, q, layout, params)
    obs = held.contacts
    qc = q[held.row_of(obs.pose)]

    def squared(x):
        c = contact_consistency(model, x, qc, obs.pose, obs.ball, obs.fixture, held.tooling.offsets, held.setup)
        return float(np.mean(c.distance_mm**2))

    rng = np.random.default_rng(4)
    sig = Deviations().sigmas(params.names)
    for _ in range(3):
        d = rng.normal(size=len(sig)) * sig * 0.002
        x = model.nominal.copy()
        plus, minus = x.copy(), x.copy()
        plus[params.index] += d
        minus[params.index] -= d
        even = (squared(plus) + squared(minus)) / 2 - squared(x)
        # (W_c is the Gauss-Newton curvature: it leaves out the seatings' residuals, 0.03 mm, times
        # the centres' second derivatives, of relative size 1e-3 here)
        np.testing.assert_allclose(even, d @ Wc @ d, rtol=5e-3)
        # the tool positions' weight counts each socket's common motion, which no consistency sees
        assert d @ verification_weight(model, qc, params) @ d > 3 * d @ Wc @ d


def test_design_refuses_what_it_cannot_do(tmp_path):
    from fgcal.errors import FgcalError

    ds, _ = _plates(tmp_path, "kinova", 3)
    model = dataset_model(ds)
    with pytest.raises(FgcalError, match="touch no fixture"):
        design_from_dataset(ds, model, 12, candidates=(ds.pose_ids, ds.joints_deg), noise=NoiseMode.DECLARED)
    with pytest.raises(FgcalError, match="placement"):
        design_from_dataset(ds, model, 41, per_placement=True, noise=NoiseMode.DECLARED)
