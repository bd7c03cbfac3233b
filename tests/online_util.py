"""Helpers of the online engines' tests (tests/test_online.py, test_online_stations.py,
test_online_contacts.py, test_online_pixels.py, test_measurement_protocol.py): a whole online run,
an engine's running estimate against the batch's prediction, an interrupted and resumed run, a
``--stdin`` session in a child."""
import json
import subprocess
import sys

import numpy as np
from predict_util import predicted_points

from fgcal.online.engines import make_engine, pose_records
from fgcal.online.run import OnlineRun


def run_online(ds, model, engine, checkpoint=None, records=None, require_accepted=False):
    """An :class:`~fgcal.online.run.OnlineRun` fed ``records`` (default: the dataset's pending
    poses); with ``require_accepted`` each record must be accepted."""
    run = OnlineRun(ds, model, engine, checkpoint)
    for rec in (run.pending() if records is None else records):
        reply = run.feed(rec)
        if require_accepted:
            assert reply["accepted"]
    return run


def deviation(names, a, b, sigma):
    """|a - b| / sigma (deg angles compared modulo 360: base.phi ends at 180.02 from one start, at
    -179.98 from another)."""
    d = np.asarray(a) - np.asarray(b)
    angle = np.array([n.split(".")[-1] in ("phi", "theta", "psi", "alpha") for n in names])
    d = np.where(angle, (d + 180.0) % 360.0 - 180.0, d)
    return np.abs(d) / sigma


def running_estimate_ratio(ds, model, batch, engine, ball):
    """How far, in the batch's prediction sigmas there (the root of the trace of each point's
    covariance), the engine's running estimate after every pose (before the final smoothing) puts
    the tool point ``ball`` (3,) mm from the batch's, at 30 random joint sets: (30,)."""
    e = make_engine(engine, ds, model)
    assert all(e.update(rec).accepted for rec in pose_records(ds, model=model))
    theta, _ = e.estimate()
    rng = np.random.default_rng(5)
    lo, hi = model.joint_limits[:, 0], model.joint_limits[:, 1]
    q = rng.uniform(np.maximum(lo, -np.pi), np.minimum(hi, np.pi), size=(30, model.n_joints))
    online, _, _ = predicted_points(e.params.full(theta, e.held), batch, model, q, ball)
    ref, J, cov = predicted_points(batch.slot_vector(model), batch, model, q, ball)
    sigma = np.sqrt(np.einsum("nip,pq,niq->n", J, cov, J))
    return np.linalg.norm(online - ref, axis=1) / sigma


def interrupted_and_resumed(ds, model, engine, tmp_path, n_first, require_accepted=False):
    """``(whole, first, second)``: an uninterrupted run (each pose accepted, with
    ``require_accepted``), one closed after ``n_first`` poses (a crash: the journal has no
    end-of-run mark) and its resumption from the checkpoint, run to the end."""
    whole = run_online(ds, model, engine, tmp_path / "a.ck", require_accepted=require_accepted)
    first = OnlineRun(ds, model, engine, tmp_path / "b.ck")
    for rec in first.pending()[:n_first]:
        first.feed(rec)
    first.close()
    second = OnlineRun(ds, model, engine, tmp_path / "b.ck")
    assert second.resume() == n_first
    for rec in second.pending():
        second.feed(rec)
    return whole, first, second


def assert_resumed_as_whole(second, whole):
    """The resumed run ends as the uninterrupted one: names, poses, estimate (to 1e-9 of the
    largest), covariance and set-up section."""
    got, want = second.result(), whole.result()
    assert got.names == want.names and got.pose_ids == want.pose_ids
    np.testing.assert_allclose(got.estimate, want.estimate, rtol=0, atol=1e-9 * np.abs(want.estimate).max())
    np.testing.assert_allclose(got.covariance, want.covariance, rtol=1e-7, atol=1e-12)
    assert got.setup == want.setup


def stdin_session(ds, engine, tmp_path, lines):
    """``fgcal online DATASET --stdin`` in a child fed ``lines``: its completed process (exit status
    0 asserted) and the result file it wrote, as JSON."""
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "online", str(ds.path), "--stdin", "--engine", engine,
                          "--checkpoint", str(tmp_path / "s.ck"), "--out", str(tmp_path / "s.json")],
                         input="\n".join(lines) + "\n", capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    return run, json.loads((tmp_path / "s.json").read_text())


def assert_streamed_as_files(streamed, expected, n_poses):
    """A streamed result (JSON) has the poses, parameters, estimates (to 1e-6 of the largest) and
    set-up fixtures of ``expected``, the run on the files."""
    assert streamed["n_poses"] == n_poses
    assert [p["name"] for p in streamed["parameters"]] == expected.names
    got = np.array([p["estimate"] for p in streamed["parameters"]])
    np.testing.assert_allclose(got, expected.estimate, rtol=0, atol=1e-6 * np.abs(expected.estimate).max())
    assert streamed["setup"]["estimated"].keys() == expected.setup["estimated"].keys()
