"""The online engines on contacts (DESIGN.md 8.2): data from the independent generator
``tests/contact_sim.py`` (a perturbed Kinova URDF; two plates of two sockets 50 mm apart, 8
seatings each; then the same robot touching a table 24 times). Each engine (EKF, UKF, iSAM2) must
end at the batch solve of the same data (parameters, sigmas, held set, set-up section), its own
running estimate must predict the tool point near the batch's, a resumed run must end as an
uninterrupted one, and a ``--stdin`` stream of contact lines as the files."""
import shutil
from pathlib import Path

import numpy as np
import pytest
from contact_sim import plane_dataset, two_socket_dataset
from online_util import (
    assert_resumed_as_whole,
    assert_streamed_as_files,
    interrupted_and_resumed,
    running_estimate_ratio,
    stdin_session,
)
from online_util import run_online as _online
from test_contacts_simulated import _merge

from fgcal.estimation.calibrate import GAUGE_REASON, CalibrationOptions, calibrate
from fgcal.io.dataset_io import dataset_model, load_dataset, save_dataset
from fgcal.online.engines import make_engine, pose_records

URDF = Path(__file__).parent / "data" / "urdf" / "kinova.urdf"
CHAIN = {"tip": "j2s6s200_end_effector"}
ENGINES = ("ekf", "ukf", "isam2")


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    """``{"sockets": path, "both": path}``: 2 plates x 2 sockets x 8 seatings; the same plus 24 table contacts."""
    tmp = tmp_path_factory.mktemp("online_contacts")
    rng = np.random.default_rng(3)
    sockets = two_socket_dataset(tmp / "sockets", URDF, CHAIN, rng, n_placements=2, configs_per_socket=8,
                                 contact_sigma_mm=0.02, distance_sigma_mm=0.0005)
    plane_dataset(tmp / "plane", URDF, CHAIN, rng, n_contacts=24, ball_radius_mm=0.0, contact_sigma_mm=0.02,
                  true_urdf=sockets.urdf, patch_radius_mm=200.0, max_tries=5)
    save_dataset(_merge(load_dataset(tmp / "sockets"), load_dataset(tmp / "plane")), tmp / "both")
    shutil.copy(tmp / "sockets" / "robot.urdf", tmp / "both" / "robot.urdf")
    return {"sockets": tmp / "sockets", "both": tmp / "both"}


_BATCH = {}


def _batch(path):
    """The batch solve (its default options: the held set decided without a prior, as the final smoothing decides it)."""
    if path not in _BATCH:
        ds = load_dataset(path)
        model = dataset_model(ds)
        _BATCH[path] = (ds, model, calibrate(ds, model, CalibrationOptions()))
    return _BATCH[path]


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("which", ["sockets", "both"])
def test_online_contacts_end_at_the_batch(datasets, engine, which):
    ds, model, batch = _batch(datasets[which])
    run = _online(ds, model, engine)
    res = run.result()
    assert res.n_poses == ds.n_poses  # no pose refused (before: every one, "no measurements")
    assert res.names == batch.names  # fixture and plane parameters named and ordered as the batch's
    dev = np.abs(res.estimate - batch.estimate) / batch.sigma
    assert dev.max() < 0.05
    np.testing.assert_allclose(res.sigma, batch.sigma, rtol=0.05)
    assert {h["name"] for h in res.held} == {h["name"] for h in batch.held}
    gauge = {h["name"] for h in batch.held if h["reason"] == GAUGE_REASON}
    assert len(gauge) == 6 and gauge == {h["name"] for h in res.held if h["reason"] == GAUGE_REASON}
    assert res.setup["gauge"] == GAUGE_REASON and res.setup["fixtures"] == batch.setup["fixtures"]
    assert res.setup["constraints"] == batch.setup["constraints"]
    for name, est in batch.setup["estimated"].items():
        got = res.setup["estimated"][name]
        key = "position" if est["type"] == "point" else "normal"
        np.testing.assert_allclose(got[key], est[key], atol=1e-3 if key == "position" else 1e-6)


@pytest.mark.parametrize("engine", ["ekf", "isam2", pytest.param("ukf", marks=pytest.mark.xfail(
    strict=True, reason="the UKF's single unscented update per pose stays ~30 batch sigmas off on contacts "
                        "(measured 30.5 here; EKF and iSAM2 0.12); its final smoothing is at the batch. Cause "
                        "(measured): the unscented prediction is the mean of h over the prior, h(x0) + tr(Hess P0)/2; "
                        "over a just-started plane's 0.1 rad tilt prior that is 6.5 mm on a table 655 mm away, "
                        "taken into its offset (648.8 mm, EKF 655.5, sigma 0.4). Relinearising over the posterior "
                        "(iterated posterior linearisation) gives 1.74 here but, on stations (tests/"
                        "test_online_stations.py), rejects 31 of 45 poses (the robot's posterior is still wide when "
                        "a station starts): not taken"))])
def test_running_estimate_predicts_the_tool_point_near_the_batch(datasets, engine):
    """Before the final smoothing the engine's own estimate puts the ball, at 30 new joint sets,
    within 3 sigmas (the batch's prediction sigma there) of where the batch puts it (measured:
    0.12 for the EKF and iSAM2)."""
    ds, model, batch = _batch(datasets["both"])
    ratio = running_estimate_ratio(ds, model, batch, engine, ds.tooling.balls["B"])
    assert ratio.max() < 3.0, ratio.max()


def test_a_plane_starts_after_three_contacts(datasets):
    """The table's first two contacts are kept pending (nothing of the plane in the state); the
    third starts it, and its known distances enter once both sockets are in."""
    ds, model, _ = _batch(datasets["both"])
    records = pose_records(ds, model=model)
    table = [r for r in records if r.contacts and r.contacts[0][2] == "table"]
    e = make_engine("ekf", ds, model)
    n = len(e.params)
    assert e.update(records[0]).accepted and len(e.kf.x) == n + 3  # the first socket
    assert e.update(table[0]).accepted and e.update(table[1]).accepted
    assert len(e.kf.x) == n + 3 and len(e.setup.pending) == 2
    assert e.update(table[2]).accepted
    assert len(e.kf.x) == n + 6 and not e.setup.pending and "table" in e.setup.layout.offset


@pytest.mark.parametrize("engine", ENGINES)
def test_resume_of_contacts_is_identical(datasets, engine, tmp_path, monkeypatch):
    """Interrupted after 40 of 56 poses (the table started at pose 35) and resumed: the same result
    as an uninterrupted run; the filters from a snapshot (every 15 poses here) holding the blocks."""
    monkeypatch.setattr("fgcal.online.run.SNAPSHOT_EVERY", 15)
    ds, model, _ = _batch(datasets["both"])
    whole, first, second = interrupted_and_resumed(ds, model, engine, tmp_path, 40)
    assert_resumed_as_whole(second, whole)
    # the running estimate at the interruption is the same too (the blocks restored, not re-started)
    np.testing.assert_allclose(second.history[39]["estimate"], first.history[39]["estimate"], rtol=0, atol=1e-9)


@pytest.mark.parametrize("engine", ["ekf", "isam2"])
def test_stdin_contacts_as_the_files(datasets, engine, tmp_path):
    ds, model, _ = _batch(datasets["both"])
    lines = ["# contacts as a measuring program would write them"]
    for pid, q in zip(ds.pose_ids, ds.joints_deg):
        lines.append(f"joints,{pid},{','.join(repr(float(v)) for v in q)}")
        for obs in (ds.contacts, ds.plane_contacts):
            sel = obs.pose == pid
            lines += [f"contact,{pid},{b},{f}" for b, f in zip(obs.ball[sel], obs.fixture[sel])]
    lines.insert(3, "contact,1,B,nowhere")  # an unknown fixture: reported, skipped, the session goes on
    run, streamed = stdin_session(ds, engine, tmp_path, lines)
    assert "line 4 skipped: unknown fixture 'nowhere'" in run.stderr
    expected = _online(ds, model, engine).result()
    assert_streamed_as_files(streamed, expected, ds.n_poses)
    assert {h["name"] for h in streamed["held"]} == {h["name"] for h in expected.held}
