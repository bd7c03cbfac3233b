"""Online calibration through the CLI: the whole step per pose, first poses against last, and the
total CPU against one batch calibration of the same poses.

``fgcal online DATASET --engine E --out R`` runs in a fresh process (single-threaded BLAS) on a
simulated PUMA 560 (3 balls x 4 probe points per pose); it prints one line per pose (not a
terminal), and the time between lines is the whole step: sphere fits, the engine's update, the
estimate, the checkpoint's journal record (fsync) and the display. Its total CPU (user + sys,
``os.wait4``) is compared with ``fgcal calibrate`` of the same dataset. Goals (issue 16): the step
flat from the first to the last poses; total CPU at most 1.5x the batch's (EKF), 3x (iSAM2).
Each process runs ``--repeat`` times (3 by default), interleaved, and the least CPU of each counts
(the machine is shared: other jobs only ever add to a run's CPU).
Run: ``python bench/bench_online.py [--poses 1000] [--engines ekf isam2] [--repeat 3]``.

Measured (issue 25; 8 runs of ``--poses 1000 --engines ekf isam2 --repeat 3`` on the shared 2-core
machine, load 1.8-4): EKF 1.34-1.51x the batch (median 1.42; 1.42-1.70, median ~1.6 before), step
0.35-0.56 ms over the first 100 poses, 0.26-0.45 ms over the last 100; iSAM2 2.08-2.58x (median
2.18), 0.72-1.02 / 0.68-1.12 ms. Round 3, session 5, after the batch kinematics became 6-11x faster
(the batch calibration 1.4x, the EKF's single-pose kinematics 14 %): EKF 1.27-1.56 in best-of-3 runs
(one run at 2.17, its batch in a fast spell), 1.56 with ``--repeat 7`` (EKF 1.07 s, batch 0.68 s);
iSAM2 1.95-2.72, 2.44 with ``--repeat 7``. The machine's speed moves by up to 1.6x between runs of the
same command at a load of 0.5: only many repeats give a steady least CPU. Round 3, session 6 (the
EKF relinearising only where a step bends the measurement, 484 -> 20 relinearisations; the Joseph
form by its thin factors; the final smoothing's build taking the engine's sphere fits): five
interleaved pairs of ``--poses 1000 --engines ekf --repeat 7`` (load 0.7-1.9, another helper's jobs
beside): before (09bf146) 1.42-1.55 (EKF 0.90-0.97 s, batch 0.58-0.66 s), after 1.46-1.50 (EKF
0.87-0.95 s, batch 0.59-0.63 s): the ratio moves with the batch's fast spells more than with the
change; step 0.29-0.35 ms over the first 100 poses (0.36 before), 0.25-0.28 ms over the last 100. In
one process (least of 8 runs each, CPU): the per-pose loop 0.295 -> 0.262 s, the smoothing's nominal
build 55 -> 43 ms, the whole run 0.835 -> 0.794 s: about 5 % of the EKF's CPU, within the machine's
spread between runs. The 1.35 aimed at is not reached: the smoothing (~0.30 s) is the batch solve
less its start's three Levenberg-Marquardt steps, and what is left of a pose's step (~0.26 ms:
kinematics 53 us, the journal's JSON ~30 us, the rest small numpy calls) is about 0.4x of a batch
calibration by itself.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SINGLE_THREAD = {k: "1" for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}


def run(cmd):
    """``(CPU seconds, peak MB, times at which each output line arrived)`` of ``cmd``."""
    env = dict(os.environ, **SINGLE_THREAD)
    env["PYTHONPATH"] = os.pathsep.join([str(HERE.parent)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=env)
    stamps = []
    for line in proc.stdout:
        if line.startswith(b"pose "):
            stamps.append(time.perf_counter())
    _, status, usage = os.wait4(proc.pid, 0)
    if os.waitstatus_to_exitcode(status):
        raise RuntimeError(f"{' '.join(cmd)} failed")
    return usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024, np.array(stamps)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--poses", type=int, nargs="+", default=[1000])
    ap.add_argument("--engines", nargs="+", default=["ekf", "isam2"])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    from fgcal import SimulationSettings, load_model, save_dataset, simulate

    model = load_model("puma560")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.poses:
            ds, _ = simulate(model, np.random.default_rng(n), SimulationSettings(n_poses=n))
            path = Path(tmp) / f"d{n}"
            save_dataset(ds, path)
            cli = [sys.executable, "-m", "fgcal.cli"]
            best = {}
            for _ in range(args.repeat):  # interleaved: a slow spell of the machine hits every process alike
                cpu, _, _ = run(cli + ["calibrate", str(path), "--out", str(Path(tmp) / f"b{n}.json"), "--force"])
                best["batch"] = min(best.get("batch", (np.inf,)), (cpu,))
                for engine in args.engines:
                    cpu, mb, t = run(cli + ["online", str(path), "--engine", engine, "--restart", "--out",
                                            str(Path(tmp) / f"{engine}{n}.json")])
                    step = np.diff(t) * 1000
                    best[engine] = min(best.get(engine, (np.inf,)),
                                       (cpu, mb, np.median(step[:100]), np.median(step[-100:])))
            for engine in args.engines:
                cpu, mb, first, last = best[engine]
                rows.append((engine, n, first, last, cpu, best["batch"][0], mb))
    print(f"{'engine':>6} {'poses':>6} {'first 100 ms':>12} {'last 100 ms':>11} {'CPU s':>7} {'batch s':>7} "
          f"{'ratio':>6} {'peak MB':>7}")
    for engine, n, first, last, cpu, batch, mb in rows:
        print(f"{engine:>6} {n:6d} {first:12.2f} {last:11.2f} {cpu:7.2f} {batch:7.2f} {cpu / batch:6.2f} {mb:7.0f}")


if __name__ == "__main__":
    main()
