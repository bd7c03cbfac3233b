"""The online journal's flushes to the disk: every pose written at once, fsync batched in time
(a streamed pose, which is nowhere else, flushed at once)."""
import numpy as np
import pytest

from fgcal.errors import FgcalError
from fgcal.io.dataset_io import load_dataset, save_dataset
from fgcal.online import run as run_module
from fgcal.online.checkpoint import read_checkpoint
from fgcal.online.engines import pose_records
from fgcal.online.run import OnlineRun
from fgcal.studies.simulate import SimulationSettings, simulate


@pytest.fixture(scope="module")
def dataset(puma, tmp_path_factory):
    ds, _ = simulate(puma, np.random.default_rng(251), SimulationSettings(n_poses=12))
    path = tmp_path_factory.mktemp("sync") / "d"
    save_dataset(ds, path)
    return load_dataset(path)


def _counting_fsync(monkeypatch):
    """The file descriptors given to ``os.fsync`` (in order), the real fsync still done."""
    real, calls = run_module.os.fsync, []

    def fsync(fd):
        calls.append(fd)
        real(fd)

    monkeypatch.setattr(run_module.os, "fsync", fsync)
    return calls


@pytest.mark.parametrize("interval, streamed", [(1e9, False), (0.0, False), (1e9, True)])
def test_journal_is_written_per_pose_and_flushed_by_the_interval(puma, dataset, tmp_path, monkeypatch,
                                                                interval, streamed):
    monkeypatch.setattr(run_module, "SYNC_INTERVAL", interval)
    calls = _counting_fsync(monkeypatch)
    run = OnlineRun(dataset, puma, "ekf", tmp_path / "c.checkpoint")
    fd = run._fd
    records = pose_records(dataset) if streamed else run.pending()
    for k, rec in enumerate(records, start=1):
        run.feed(rec, streamed=streamed)
        # each pose is in the file (the page cache) before the next is taken, whatever the flushes
        assert [e["pose"] for e in read_checkpoint(tmp_path / "c.checkpoint")["entries"]] == \
            [int(r.pose) for r in records[:k]]
        flushed = sum(c == fd for c in calls)
        # the header and each pose flushed (interval 0, or a streamed pose); else none while poses come
        assert flushed == (k + 1 if interval == 0.0 else k if streamed else 0)
    run.result()  # the end flushes what is pending
    n = len(records)
    assert sum(c == fd for c in calls) == (n + 1 if interval == 0.0 else n if streamed else 1)
    run.close()


@pytest.mark.parametrize("value", ["1e400", str(10**400), "-" + str(10**400), "NaN"])
def test_a_journal_number_beyond_a_float_is_refused_by_its_entry(tmp_path, value):
    """JSON integers are unbounded: a journal's ``"f": 10**400`` is named as the entry's problem (it
    was an OverflowError from math.isfinite), as an infinite float is."""
    path = tmp_path / "c.checkpoint"
    header = '{"format": "fgcal-online-checkpoint/1"}'
    path.write_text(header + "\n" + '{"pose": 1, "accepted": false, "f": ' + value + "}\n"
                    + '{"pose": 2, "accepted": false}\n')
    with pytest.raises(FgcalError, match=r"c\.checkpoint: entry 2 of the checkpoint: pose 1: f is not a finite "
                                         r"number; use --restart"):
        read_checkpoint(path)
    path.write_text(header + "\n" + '{"pose": 1, "accepted": false, "f": ' + str(10**300) + "}\n")
    assert read_checkpoint(path)["entries"][0]["f"] == 10**300
