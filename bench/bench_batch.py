"""Batch calibration: whole-process CPU time and peak memory of fgcal against a scipy joint solve.

Each run is a fresh process with single-threaded BLAS (``OPENBLAS_NUM_THREADS=1`` and friends),
measured from outside (``os.wait4``: user + system CPU of the whole process, imports and reading
the files included, and its peak RSS), on a simulated PUMA 560 with the paper's noise (3 balls x
4 probe points per pose):

  fgcal   ``fgcal.estimation.calibrate`` (the factor graph from raw probe points, covariance included)
  scipy   ``bench/scipy_reference.py``: the same probe-level problem with ``least_squares``

The timed fgcal run is ``calibrate``'s default (noise estimated per level, outliers excluded: what
``fgcal calibrate`` does); the estimates are compared on the same problem as scipy's (declared
noise, every measurement kept) by one more, untimed, fgcal run: ``max |fgcal - scipy| / sigma``
(goal below 0.01) and the sigmas' largest relative difference.
Goals (issue 16): CPU ratio fgcal/scipy at most 0.8 at 1000 and 10000 poses, CPU per pose not
growing with the poses, peak at 10000 poses at most 400 MB.
Run: ``python bench/bench_batch.py [--poses 21 1000 10000] [--repeat 3]``.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SINGLE_THREAD = {k: "1" for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS",
                                  "OPENBLAS_MAIN_FREE", "NUMEXPR_NUM_THREADS")}

FGCAL_CASE = """
import json, sys
from fgcal import dataset_model, load_dataset
from fgcal.estimation.calibrate import CalibrationOptions, calibrate
ds = load_dataset(sys.argv[1])
same = CalibrationOptions(noise="declared", outliers="none")  # scipy's problem
r = calibrate(ds, dataset_model(ds), same if sys.argv[2:] == ["same"] else CalibrationOptions())
print(json.dumps({"names": r.names, "estimate": r.estimate.tolist(), "sigma": r.sigma.tolist(),
                  "iterations": r.iterations}))
"""


def run(cmd) -> dict:
    """``cmd`` in a fresh process: its JSON output, CPU seconds (user + sys) and peak RSS (MB)."""
    env = dict(os.environ, **SINGLE_THREAD)
    env["PYTHONPATH"] = os.pathsep.join([str(HERE.parent)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    out = proc.stdout.read()
    err = proc.stderr.read()
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{err.decode()}")
    d = json.loads(out)
    d["cpu"] = usage.ru_utime + usage.ru_stime
    d["peak_mb"] = usage.ru_maxrss / 1024
    return d


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--poses", type=int, nargs="+", default=[21, 1000, 10000])
    ap.add_argument("--repeat", type=int, default=3, help="runs per case, interleaved; the least CPU is kept")
    args = ap.parse_args()
    from fgcal import SimulationSettings, load_model, save_dataset, simulate

    model = load_model("puma560")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.poses:
            ds, _ = simulate(model, np.random.default_rng(n), SimulationSettings(n_poses=n))
            path = Path(tmp) / f"d{n}"
            save_dataset(ds, path)
            cmds = {"fgcal": [sys.executable, "-c", FGCAL_CASE, str(path)],
                    "scipy": [sys.executable, str(HERE / "scipy_reference.py"), str(path)]}
            runs = {name: [] for name in cmds}
            for _ in range(args.repeat):  # interleaved: a slow spell of the shared machine hits both alike
                for name, cmd in cmds.items():
                    runs[name].append(run(cmd))
            best = {}
            for name, rs in runs.items():
                best[name] = min(rs, key=lambda r: r["cpu"])
                best[name]["peak_mb"] = max(r["peak_mb"] for r in rs)
            f, s = best["fgcal"], best["scipy"]
            same = run([sys.executable, "-c", FGCAL_CASE, str(path), "same"])
            assert same["names"] == s["names"]
            z = np.max(np.abs(np.array(same["estimate"]) - s["estimate"]) / np.array(same["sigma"]))
            sig = np.max(np.abs(np.array(same["sigma"]) / s["sigma"] - 1))
            rows.append((n, f["cpu"], s["cpu"], f["peak_mb"], s["peak_mb"], z, sig, f["iterations"]))
    print(f"{'poses':>6} {'fgcal s':>8} {'scipy s':>8} {'ratio':>6} {'fgcal ms/pose':>13} "
          f"{'fgcal MB':>8} {'scipy MB':>8} {'max|d|/sigma':>12} {'sigma rel':>9} {'LM it':>5}")
    for n, fc, sc, fm, sm, z, sig, it in rows:
        print(f"{n:6d} {fc:8.2f} {sc:8.2f} {fc / sc:6.2f} {1000 * fc / n:13.2f} {fm:8.0f} {sm:8.0f} "
              f"{z:12.2g} {sig:9.1g} {it:5d}")


if __name__ == "__main__":
    main()
