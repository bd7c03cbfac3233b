"""Helpers of the hostile-input tests: run the CLI in a child or in this process, small datasets."""
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

from fgcal.cli import main
from fgcal.io.dataset_io import save_dataset
from fgcal.measurements.dataset import Noise
from fgcal.studies.simulate import SimulationSettings, simulate

REPO = Path(__file__).resolve().parent.parent


def run_cli(args, cwd=None, timeout=300, preexec_fn=None):
    """``fgcal ARGS`` in a child process (this checkout first on the path)."""
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-m", "fgcal.cli", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=timeout, env=env, preexec_fn=preexec_fn)


def call(args, capsys):
    """``fgcal ARGS`` in this process: ``(status, stdout, stderr)``; a traceback would fail the test."""
    try:
        code = main([str(a) for a in args])
    except SystemExit as exc:  # argparse rejects an option
        code = exc.code
    out = capsys.readouterr()
    return code, out.out, out.err


def one_line_error(code, err, *words):
    """Status 2, one line on standard error, no traceback, and all ``words`` in it."""
    assert code == 2, err
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    for w in words:
        assert w in err, (w, err)


def small_dataset(model, path, n_poses=6, seed=3, levels=("probes",)):
    ds, _ = simulate(model, np.random.default_rng(seed),
                     SimulationSettings(n_poses=n_poses, levels=levels, noise=Noise(0.01, 0.01)))
    save_dataset(ds, path)
    return ds


def copy_dataset(src, dst):
    shutil.copytree(src, dst)
    return Path(dst)
