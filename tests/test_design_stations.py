"""Design for centres from several stations (DESIGN.md 8.3): on the reflector seen from three
stations (tests/test_stations.py's independent URDF generator), ``fgcal design`` chooses which
poses to record from which station (a ``station`` column in the plan), and its criterion is the
robot's accuracy with the stations' frames marginalised: checked against the covariance of the
batch solve (stations estimated with the robot) on the designed poses, an independent computation."""
import subprocess
import sys

import numpy as np
import pytest
from test_stations import _simulate

from fgcal.estimation.calibrate import CalibrationOptions, calibrate
from fgcal.estimation.noise import NoiseMode
from fgcal.io.dataset_io import dataset_model, load_dataset, read_joints_and_stations
from fgcal.studies.design import Candidates, marginal
from fgcal.studies.design_dataset import dataset_layout, design_from_dataset, with_dataset_tooling
from fgcal.studies.design_predict import predicted_mse


@pytest.fixture(scope="module")
def stations_ds(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("design_stations")
    _simulate(tmp, 1, n=45)
    return tmp / "all"


def test_design_chooses_poses_from_each_station(stations_ds, tmp_path):
    out = subprocess.run([sys.executable, "-m", "fgcal.cli", "design", "--dataset", str(stations_ds), "--poses", "20",
                          "--out", str(tmp_path / "p.csv")], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "poses from each station: A " in out.stdout
    ids, _, stations = read_joints_and_stations(tmp_path / "p.csv")
    ds = load_dataset(stations_ds)
    of = dict(zip(ds.pose_ids.tolist(), ds.stations.tolist(), strict=True))
    assert len(ids) == 20 and [of[int(i)] for i in ids] == stations.tolist()
    # a station's frame needs three centres across a line: a plan gives a station none (its poses
    # only tell the robot through the others') or at least three; the world's are always worth it
    counts = [int((stations == s).sum()) for s in "ABC"]
    assert counts[0] >= 3 and all(c == 0 or c >= 3 for c in counts), counts
    pred = float(out.stdout.split("new poses: ")[1].split(" mm")[0])
    median = float(out.stdout.split("median ")[1].split(",")[0])
    assert pred < median  # better than random plans of 20 from the same candidates


def test_design_criterion_marginalises_the_stations(stations_ds):
    """The design's marginal information about the robot (the stations' six entries each eliminated
    by the Schur complement) on 20 designed poses is the inverse of the batch solve's covariance of
    the robot's parameters on those poses at the declared noise, both at the batch's estimate (the
    sigmas within 0.1%; measured at the nominal geometry instead, within 3.8%); leaving the stations out (as if known)
    would give smaller sigmas (down to 0.80 of the batch's)."""
    ds = load_dataset(stations_ds)
    model = dataset_model(ds)
    plan = design_from_dataset(ds, model, 20, noise=NoiseMode.DECLARED, random_sets=5)
    sel = np.isin(ds.pose_ids, plan.pose_ids)
    batch = calibrate(ds.select(ds.pose_ids[sel]), model, CalibrationOptions(noise="declared"))
    model = with_dataset_tooling(ds, model)
    slots = batch.slot_vector(model)  # both linearised at the batch's estimate
    layout = dataset_layout(ds, model, slots=slots)
    prep = Candidates.build(model, model.joints_to_internal(ds.joints_deg), ds.noise, layout=layout, slots=slots,
                            params=type(model.parameters())(model, tuple(n for n in batch.names
                                                                          if not n.startswith("station."))))
    total, _ = prep.total(np.nonzero(sel)[0])
    P = len(prep.names)
    assert prep.n_setup == 12 and list(prep.names) == [n for n in batch.names if not n.startswith("station.")]
    design_cov = np.linalg.inv(marginal(total, prep.n_setup))
    # the plan determines what the verification sees: its prediction is the inverse's, whether the
    # stations are marginalised or estimated with the robot (a station it does not visit: undetermined, unseen)
    pred = np.sqrt(np.trace(prep.W[:P, :P] @ design_cov))
    assert prep.values(np.nonzero(sel)[0])["pred"] == pytest.approx(pred, rel=1e-9)
    assert np.sqrt(predicted_mse(total[None], prep.W, prep.scale)[0]) == pytest.approx(pred, rel=1e-6)
    cols = [batch.names.index(n) for n in prep.names]
    scale = np.where(model.slot_is_angle[[model.slot(n) for n in prep.names]], np.radians(1.0), 1.0)
    batch_cov = batch.covariance[np.ix_(cols, cols)] * np.outer(scale, scale)
    ratio = np.sqrt(np.diag(design_cov) / np.diag(batch_cov))
    assert np.abs(ratio - 1).max() < 1e-3, ratio
    known = np.sqrt(np.diag(np.linalg.inv(total[:P, :P])) / np.diag(batch_cov))  # the stations taken as known
    assert known.min() < 0.9, known.min()  # measured 0.80
