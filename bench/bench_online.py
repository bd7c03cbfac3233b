"""Per-pose update latency of the online engines on a simulated PUMA 560 (3 balls x 4 points).

Run: ``python bench/bench_online.py [--poses 1000] [--ukf-poses 200]``. Prints the median and
90th percentile of the time to take one pose (sphere fits, checks and the engine's update) over
the last 100 poses, and how far the final estimate is from the batch solve of the same poses.
"""
from __future__ import annotations

import argparse
import time

import numpy as np


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--poses", type=int, default=1000)
    ap.add_argument("--ukf-poses", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=2, help="runs per engine; the best median is kept")
    args = ap.parse_args()
    from fgcal import SimulationSettings, load_model, simulate
    from fgcal.calibrate import CalibrationOptions, calibrate
    from fgcal.online import make_engine, pose_records

    model = load_model("puma560")
    rows = []
    for engine, n in (("isam2", args.poses), ("ekf", args.poses), ("ukf", args.ukf_poses)):
        ds, _ = simulate(model, np.random.default_rng(n), SimulationSettings(n_poses=n))
        best = None
        for _ in range(args.repeat):
            e = make_engine(engine, ds, model)
            lat, accepted = [], []
            for rec in pose_records(ds):
                t0 = time.perf_counter()
                if e.update(rec).accepted:
                    accepted.append(rec.pose)
                lat.append(time.perf_counter() - t0)
            if best is None or np.median(lat[-100:]) < np.median(best[1][-100:]):
                best = (e, lat, accepted)
        e, lat, accepted = best
        e.finish()
        theta, cov = e.estimate()
        batch = calibrate(ds.select(accepted), model, CalibrationOptions(prior="weak"))
        z = np.abs((e.params.to_file_units(theta) - batch.estimate) / batch.sigma).max()
        sig = np.sqrt(np.diag(e.params.covariance_to_file_units(cov))) / batch.sigma
        last = np.array(lat[-100:]) * 1000
        rows.append((engine, n, np.median(last), np.percentile(last, 90), z, sig.min(), sig.max()))
    print(f"{'engine':>6} {'poses':>6} {'median ms':>10} {'p90 ms':>8} {'max |diff|/sigma':>17} {'sigma ratio':>14}")
    for engine, n, med, p90, z, lo, hi in rows:
        print(f"{engine:>6} {n:6d} {med:10.2f} {p90:8.2f} {z:17.4f} {lo:6.3f}-{hi:6.3f}")


if __name__ == "__main__":
    main()
