"""Design for contacts (DESIGN.md 8.2): which configurations to record at each fixture.

The candidates are a dataset's poses, each at its fixture; the information is over the
parameters and the fixture blocks, with the blocks' known distances, and the criterion (the
predicted tool-point accuracy) marginalises the blocks. Checked here: that information is the
batch estimator's own (the graph's normal equations at the same point), and on two-socket plates
from the independent generator (tests/contact_sim.py) a designed plan of 12 poses per placement
predicts a better accuracy than the median random plan of 12 per placement, and calibrating on it
is verified at other placements (consistency) no worse than the median of 8 random plans."""
import numpy as np
import pytest
from contact_sim import two_socket_dataset
from test_contacts_simulated import DATA, ROBOTS

from fgcal.estimation.calibrate import CalibrationOptions, build_graph, calibrate
from fgcal.estimation.noise import NoiseMode
from fgcal.estimation.verification import verify
from fgcal.io.dataset_io import dataset_model, load_dataset
from fgcal.studies.design import Candidates
from fgcal.studies.design_dataset import dataset_layout, design_from_dataset, placement_of, with_dataset_tooling

PER_PLACEMENT = 12


def _plates(tmp, robot, seed):
    """3 plates of two sockets, 20 configurations per socket (the candidates), and 3 other
    plates of the same true robot (the verification)."""
    name, chain = ROBOTS[robot]
    rng = np.random.default_rng(seed)
    train = two_socket_dataset(tmp / "train", DATA / name, chain, rng, n_placements=3, configs_per_socket=20,
                               contact_sigma_mm=0.02, distance_sigma_mm=0.0005)
    two_socket_dataset(tmp / "check", DATA / name, chain, rng, n_placements=3, configs_per_socket=10,
                       contact_sigma_mm=0.02, distance_sigma_mm=0.0005, true_urdf=train.urdf)
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


@pytest.mark.parametrize("robot", ["kinova", "panda"])
def test_designed_plan_beats_random_plans(tmp_path, robot):
    ds, held = _plates(tmp_path, robot, 1)
    model = dataset_model(ds)
    plan = design_from_dataset(ds, model, PER_PLACEMENT, per_placement=True, rng=np.random.default_rng(0),
                               random_sets=200)
    layout = dataset_layout(ds, model)
    groups = placement_of(layout, layout.setup.spec)
    chosen = groups[ds.row_of(plan.pose_ids)]
    assert np.array_equal(np.bincount(chosen), [PER_PLACEMENT] * 3)  # 12 at each placement
    assert plan.values["pred"] < np.median(plan.random_pred)

    def consistency(ids):
        result = calibrate(ds.select(ids), model)
        return verify(result, held, model).contacts["after"]["consistency_mm"]["rms"]

    designed = consistency(plan.pose_ids)
    rng = np.random.default_rng(5)
    random = [consistency(ds.pose_ids[np.concatenate([rng.choice(np.nonzero(groups == g)[0], PER_PLACEMENT,
                                                                 replace=False) for g in range(3)])])
              for _ in range(8)]
    print(f"{robot}: pred {plan.values['pred']:.4f} mm (random median {np.median(plan.random_pred):.4f}); "
          f"held-out consistency {designed:.4f} mm (random {np.round(random, 4)}, median {np.median(random):.4f})")
    assert designed <= np.median(random)


def test_design_refuses_what_it_cannot_do(tmp_path):
    from fgcal.errors import FgcalError

    ds, _ = _plates(tmp_path, "kinova", 3)
    model = dataset_model(ds)
    with pytest.raises(FgcalError, match="touch no fixture"):
        design_from_dataset(ds, model, 12, candidates=(ds.pose_ids, ds.joints_deg), noise=NoiseMode.DECLARED)
    with pytest.raises(FgcalError, match="placement"):
        design_from_dataset(ds, model, 41, per_placement=True, noise=NoiseMode.DECLARED)
