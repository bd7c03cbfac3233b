"""What the benches share to time a command as a whole process: single-threaded BLAS, this checkout
first on the child's path, and its CPU (user + system, its children included) and peak RSS measured
from outside (``os.wait4``). Imported by a bench run as ``python bench/NAME.py`` (its folder is first
on the path)."""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
SINGLE_THREAD = {k: "1" for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS",
                                  "OPENBLAS_MAIN_FREE", "NUMEXPR_NUM_THREADS")}
FGCAL = [sys.executable, "-m", "fgcal.cli"]


def run(cmd: list[str], src: Sequence[str] = ()) -> dict:
    """``cmd`` in a fresh process (the checkouts ``src``, then this one, first on its path): its CPU
    seconds (user + sys, children included), peak RSS (MB), stdout; ``RuntimeError`` with its
    standard error when it fails."""
    env = dict(os.environ, **SINGLE_THREAD)
    env["PYTHONPATH"] = os.pathsep.join([*src, str(REPO)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        proc = subprocess.Popen(cmd, stdout=out, stderr=err, env=env)
        _, status, usage = os.wait4(proc.pid, 0)  # reaps it: its own and its children's CPU, its peak RSS
        out.seek(0)
        err.seek(0)
        if os.waitstatus_to_exitcode(status):
            raise RuntimeError(f"{' '.join(cmd)} failed:\n{err.read().decode()}")
        stdout = out.read()
    return {"cpu": usage.ru_utime + usage.ru_stime, "peak_mb": usage.ru_maxrss / 1024, "stdout": stdout}
