"""Study throughput (trials per second): fig13-style trials (12 poses) on 1 and 2 local worker
processes and on a Dask LocalCluster of 2 workers on loopback, with peak memory per process.

Run: ``python bench/bench_study.py [--trials 40]``.
"""
from __future__ import annotations

import argparse
import resource
import tempfile
import time


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--trials", type=int, default=40)
    args = ap.parse_args()
    from fgcal.studies.study import trials_for
    from fgcal.studies.study_run import run_study

    trials = trials_for("fig13", trials=args.trials, poses=12, seed=7)
    rows = []
    for label, kw in (("1 local process", {"workers": 1}), ("2 local processes", {"workers": 2})):
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            run_study(trials, tmp, progress=False, **kw)
            rows.append((label, args.trials / (time.perf_counter() - t0)))
    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster, tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        run_study(trials, tmp, scheduler=cluster.scheduler_address, progress=False)
        rows.append(("Dask LocalCluster, 2 workers", args.trials / (time.perf_counter() - t0)))
    print(f"{'where':>30} {'trials/s':>9}")
    for label, rate in rows:
        print(f"{label:>30} {rate:9.2f}")
    print(f"peak memory of this process: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB; "
          f"of a worker: {resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main()
