"""What tools/hostile_sweep3.py found (every option of every command with hostile values), one test each."""
import numpy as np
import pytest
from hostile_util import call, one_line_error, small_dataset


@pytest.fixture(scope="module")
def probes_ds(puma, tmp_path_factory):
    path = tmp_path_factory.mktemp("sweep3") / "ds"
    small_dataset(puma, path, n_poses=8, seed=7)
    return path


def test_model_comparison_of_probe_data(puma, probes_ds):
    """``calibrate --verification`` of probe points was a broadcast traceback: J_theta holds only each
    pose's kinematic rows. Padded with the probe rows' zeros, the projected problem is the one the
    ball centres leave: residual and Jacobian orthogonal to the per-pose variables' columns."""
    from fgcal.estimation.build import build_graph
    from fgcal.estimation.calibrate import CalibrationOptions, calibrate
    from fgcal.estimation.joint_errors import JointErrorSpec
    from fgcal.estimation.model_select import cv_problem
    from fgcal.io.dataset_io import load_dataset

    ds = load_dataset(probes_ds)
    geo = calibrate(ds, puma, CalibrationOptions())
    prob = cv_problem(ds, puma, geo, JointErrorSpec())
    opts = CalibrationOptions(joint_noise=False, robust=None, prior="none", joint_errors=JointErrorSpec())
    scale = {k: float(v) for k, v in (geo.options.get("noise_scale") or {}).items()}
    graph, state, _ = build_graph(ds, puma, list(geo.names), opts, scale=scale)  # as cv_problem linearises
    graph.held = geo.slot_vector(puma)
    state.theta = graph.params.take(graph.held)
    lin = graph.linearise(state)
    assert prob.J.shape == (8, lin.r.shape[1], len(geo.names)) and prob.unit == "sigma"
    size = np.abs(lin.J_local).max() * np.abs(lin.J_theta).max()
    np.testing.assert_allclose(np.einsum("nmz,nmp->nzp", lin.J_local, prob.J), 0, atol=1e-10 * size)
    np.testing.assert_allclose(np.einsum("nmz,nm->nz", lin.J_local, prob.r), 0,
                               atol=1e-10 * np.abs(lin.J_local).max() * np.abs(lin.r).max())
    assert lin.J_theta.shape[1] < lin.r.shape[1]  # the case: probe rows beyond J_theta's


def test_report_into_a_dataset_folder_is_refused(probes_ds, tmp_path, capsys):
    """report --out DS wrote its pages and figures into a dataset's folder."""
    code, _, err = call(["calibrate", probes_ds, "--out", tmp_path / "r.json"], capsys)
    assert code == 0, err
    before = sorted(p.name for p in probes_ds.iterdir())
    code, _, err = call(["report", tmp_path / "r.json", "--out", probes_ds], capsys)
    one_line_error(code, err, "is a dataset folder")
    assert sorted(p.name for p in probes_ds.iterdir()) == before


@pytest.mark.parametrize("joints", ["", ",,,"])
def test_tum_import_without_joint_columns(tmp_path, capsys, joints):
    (tmp_path / "t.tum").write_text("1 0 0 0 0 0 0 1\n")
    (tmp_path / "j.csv").write_text("time,q1\n1,0\n")
    code, _, err = call(["import", "tum", tmp_path / "t.tum", tmp_path / "o", "--robot", "ur10", "--joint-log",
                         tmp_path / "j.csv", "--joints", joints], capsys)
    one_line_error(code, err, "--joints: give the joint log's joint columns")


@pytest.mark.parametrize("address", ["-1", "localhost", "tcp://10.0.0.1"])
def test_scheduler_address_needs_a_port(tmp_path, capsys, address):
    """--scheduler without a port passed the option check and ended in Dask's ValueError."""
    code, _, err = call(["study", "fig13", "--out", tmp_path / "st", "--scheduler", address], capsys)
    one_line_error(code, err, "--scheduler", "has no port")
    assert not (tmp_path / "st").exists()


def test_ur_hash_without_ur_kinematics_is_refused(probes_ds, tmp_path, capsys):
    """export --ur-hash without --ur-kinematics was dropped without a word (the sweep's text values)."""
    code, _, err = call(["calibrate", probes_ds, "--out", tmp_path / "r.json"], capsys)
    assert code == 0, err
    code, _, err = call(["export", tmp_path / "r.json", "--model", tmp_path / "m.yaml", "--ur-hash", "calib_1"], capsys)
    one_line_error(code, err, "--ur-hash", "--ur-kinematics FILE")
    assert not (tmp_path / "m.yaml").exists()


def test_a_dataset_written_meanwhile_is_not_replaced(puma, tmp_path, monkeypatch):
    """Two simulate (or import) runs on one new OUT both passed the 'exists' check and the second
    replaced the first, both saying 'wrote'. Without --force the rename to OUT now fails instead."""
    import fgcal.io.dataset_write as dataset_write
    from fgcal.errors import FgcalError
    from fgcal.io.dataset_io import load_dataset

    first = small_dataset(puma, tmp_path / "a", n_poses=6, seed=8)
    write_into = dataset_write._write_into

    def racing(ds, tmp):  # the other run finishes while this one writes
        write_into(ds, tmp)
        if ds is not first:
            dataset_write.save_dataset(first, tmp_path / "out")

    monkeypatch.setattr(dataset_write, "_write_into", racing)
    other = load_dataset(tmp_path / "a")
    other.joints_deg = other.joints_deg + 1.0
    with pytest.raises(FgcalError, match="already exists \\(written meanwhile by another run"):
        dataset_write.save_dataset(other, tmp_path / "out")
    np.testing.assert_array_equal(load_dataset(tmp_path / "out").joints_deg, load_dataset(tmp_path / "a").joints_deg)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "out"]  # no temporary folder left


def test_an_output_file_written_meanwhile_is_not_replaced(tmp_path):
    """An output checked absent (no --force) is created by its atomic write, never replaces a file that
    appeared meanwhile (two calibrate runs on one --out both said 'wrote'); --force replaces."""
    from fgcal.errors import FgcalError
    from fgcal.util.yamlio import atomic_write_text, may_replace, must_be_new

    out = tmp_path / "r.json"
    must_be_new(out)
    out.write_text("the other run's\n")  # written while this run worked
    with pytest.raises(FgcalError, match="already exists \\(written meanwhile by another run"):
        atomic_write_text(out, "this run's\n")
    assert out.read_text() == "the other run's\n" and sorted(p.name for p in tmp_path.iterdir()) == ["r.json"]
    may_replace(out)
    atomic_write_text(out, "this run's\n")
    assert out.read_text() == "this run's\n"
    must_be_new(tmp_path / "new.json")
    atomic_write_text(tmp_path / "new.json", "x\n")  # absent: created
    atomic_write_text(tmp_path / "new.json", "y\n")  # one claim, one write: later writes replace as before
    assert (tmp_path / "new.json").read_text() == "y\n"
