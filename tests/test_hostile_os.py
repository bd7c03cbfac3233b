"""Operating-system faults and output paths: one line, exit 2, checked before the work, nothing left over."""
import os
import resource
import signal
import stat

import pytest
from hostile_util import call, copy_dataset, one_line_error, run_cli, small_dataset

from fgcal.io.dataset_io import load_dataset, save_dataset
from fgcal.util import yamlio
from fgcal.util.yamlio import atomic_write_text


@pytest.fixture(scope="module")
def base(puma, tmp_path_factory):
    path = tmp_path_factory.mktemp("os") / "ds"
    small_dataset(puma, path, n_poses=5)
    return path


def test_output_folder_checked_before_reading_the_input(tmp_path, capsys):
    # The dataset does not even exist: the --out typo must be what is reported.
    code, _, err = call(["calibrate", tmp_path / "nothing", "--out", tmp_path / "nodir" / "r.json"], capsys)
    one_line_error(code, err, "nodir", "does not exist")
    code, _, err = call(["design", "--out", tmp_path / "nodir" / "plan.csv"], capsys)
    one_line_error(code, err, "nodir", "does not exist")
    code, _, err = call(["verify", tmp_path / "r.json", tmp_path / "ds", "--out", tmp_path], capsys)
    one_line_error(code, err, "is a folder")


@pytest.mark.parametrize("args, words", [
    (lambda d, t: ["calibrate", d, "--out", d / "joints.csv"], ["joints.csv", "input of this run"]),
    (lambda d, t: ["measure", d, "--out", d, "--force"], ["overlaps the input folder"]),
    (lambda d, t: ["measure", d, "--out", d / "sub", "--force"], ["overlaps the input folder"]),
    (lambda d, t: ["simulate", t, "--force", "--truth", d / "truth.yaml"], ["would replace the input"]),
])
def test_output_never_replaces_an_input(base, tmp_path, capsys, args, words):
    d = copy_dataset(base, tmp_path / "ds")
    before = {p.name: p.read_bytes() for p in d.iterdir()}
    code, _, err = call(args(d, tmp_path), capsys)
    one_line_error(code, err, *words)
    assert {p.name: p.read_bytes() for p in d.iterdir()} == before


@pytest.mark.parametrize("kind", ["file", "fifo", "loop", "missing"])
def test_dataset_that_is_not_a_folder(tmp_path, capsys, kind):
    d = tmp_path / "ds"
    if kind == "file":
        d.write_text("x")
    elif kind == "fifo":
        os.mkfifo(d)
    elif kind == "loop":
        os.symlink("ds", d)
    code, _, err = call(["check", d], capsys)
    one_line_error(code, err, str(d), "not a dataset directory")


def test_input_file_that_is_a_fifo_or_folder_does_not_hang(base, tmp_path):
    d = copy_dataset(base, tmp_path / "ds")
    (d / "probes.csv").unlink()
    os.mkfifo(d / "probes.csv")
    (d / "truth.yaml").unlink()
    (d / "truth.yaml").mkdir()
    run = run_cli(["check", d], timeout=120)
    one_line_error(run.returncode, run.stderr, "probes.csv", "not a regular file")


def test_full_disk_is_one_line_and_leaves_nothing(tmp_path):
    """A file-size limit stands in for a full disk: the write fails with EFBIG like ENOSPC would."""
    def small_disk():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (2000, 2000))

    run = run_cli(["simulate", tmp_path / "sim", "--poses", "8"], preexec_fn=small_disk, timeout=300)
    one_line_error(run.returncode, run.stderr, "too large")
    assert list(tmp_path.iterdir()) == []  # no dataset, no temporary folder


def test_atomic_write_interrupted_leaves_old_file_and_no_tmp(tmp_path, monkeypatch):
    f = tmp_path / "r.json"
    f.write_text("old\n")

    def interrupt(fd):
        raise KeyboardInterrupt

    monkeypatch.setattr(yamlio.os, "fsync", interrupt)
    with pytest.raises(KeyboardInterrupt):
        atomic_write_text(f, "new\n" * 1000)
    assert f.read_text() == "old\n" and sorted(p.name for p in tmp_path.iterdir()) == ["r.json"]


@pytest.mark.parametrize("umask, file_mode, dir_mode", [(0o022, 0o644, 0o755), (0o077, 0o600, 0o700),
                                                        (0o002, 0o664, 0o775)])
def test_permissions_follow_the_umask(base, tmp_path, umask, file_mode, dir_mode):
    old = os.umask(umask)
    try:
        atomic_write_text(tmp_path / "a.txt", "x")
        save_dataset(load_dataset(base), tmp_path / "copy")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "a.txt").stat().st_mode) == file_mode
    assert stat.S_IMODE((tmp_path / "copy").stat().st_mode) == dir_mode
    assert stat.S_IMODE((tmp_path / "copy" / "joints.csv").stat().st_mode) == file_mode
