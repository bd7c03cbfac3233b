"""Batch solve time and peak memory: fgcal's joint graph solve against the two-stage method.

Each case runs in a fresh process (so peak RSS is its own), on a simulated PUMA 560 with the
paper's noise (3 balls x 4 probe points per pose), whole process: read the dataset from disk,
solve, covariance. Run: ``python bench/bench_batch.py [--poses 21 200 1000] [--repeat 3]``.

Methods:
  fgcal       ``fgcal.calibrate``: one factor graph from raw probe points, covariance by gtsam.Marginals
  two-stage   the paper's path: sphere fits with fgcal's checks (``fgcal.measure``), then
              ``scipy.optimize.least_squares`` on the centres (``fgcal.baseline.two_stage``)
  scipy-2s    the same written with scipy only: one ``least_squares`` per sphere, then on the centres
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def scipy_two_stage(ds, model):
    from scipy.optimize import least_squares
    from scipy.sparse import csr_matrix

    from fgcal.kinematics import jacobians

    pr = ds.probes
    keys = list(dict.fromkeys(zip(pr.pose.tolist(), pr.ball.tolist())))
    centres = []
    for p, b in keys:
        pts = pr.xyz[(pr.pose == p) & (pr.ball == b)]
        guess = pts.mean(axis=0) - ds.tooling.radius * np.array([0, 0, 1.0])
        sol = least_squares(lambda c: np.linalg.norm(pts - c, axis=1) - ds.tooling.radius, guess)
        centres.append(sol.x)
    centres = np.array(centres)
    q = ds.joints_rad[ds.row_of([p for p, _ in keys])]
    offsets = np.array([ds.tooling.balls[b] for _, b in keys]).reshape(-1, 1, 3)
    params = model.parameters()
    idx = params.index
    res = lambda th: (jacobians(params.full(th), q, offsets).points[:, 0] - centres).ravel()  # noqa: E731
    jac = lambda th: csr_matrix(jacobians(params.full(th), q, offsets).point_slots[:, 0][:, :, idx]  # noqa: E731
                                .reshape(-1, len(idx)))
    sol = least_squares(res, params.nominal(), jac=jac, method="trf", x_scale="jac", tr_solver="lsmr")
    return sol.x


def run_case(method: str, path: str) -> dict:
    # Imports first: the clock measures reading, solving and the covariance, not Python start-up.
    import fgcal.baseline  # noqa: F401
    import fgcal.calibrate  # noqa: F401
    from fgcal import dataset_model, load_dataset

    t0 = time.perf_counter()
    ds = load_dataset(path)
    model = dataset_model(ds)
    if method == "fgcal":
        from fgcal.calibrate import calibrate
        r = calibrate(ds, model)
        est = r.slot_vector()
    elif method == "two-stage":
        from fgcal.baseline import two_stage
        est = two_stage(ds, model)[0]
    else:
        est = model.parameters().full(scipy_two_stage(ds, model))
    elapsed = time.perf_counter() - t0
    from fgcal.model import SLOT_NAMES, slots_from_file_units
    truth = slots_from_file_units(np.array([ds.truth[n] for n in SLOT_NAMES]))
    from fgcal.kinematics import forward
    from fgcal.transforms import pose_difference
    q = np.random.default_rng(0).uniform(model.joint_limits[:, 0], model.joint_limits[:, 1], size=(500, 6))
    d, _ = pose_difference(forward(est, q), forward(truth, q))
    return {"seconds": elapsed, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "position_rms_mm": float(np.sqrt(np.mean(np.sum(d**2, axis=1))))}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--poses", type=int, nargs="+", default=[21, 200, 1000])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--methods", nargs="+", default=["fgcal", "two-stage", "scipy-2s"])
    ap.add_argument("--case", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.case:
        print(json.dumps(run_case(*args.case)))
        return
    from fgcal import SimulationSettings, load_model, save_dataset, simulate

    model = load_model("puma560")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.poses:
            ds, _ = simulate(model, np.random.default_rng(n), SimulationSettings(n_poses=n))
            path = Path(tmp) / f"d{n}"
            save_dataset(ds, path)
            for method in args.methods:
                runs = [json.loads(subprocess.run([sys.executable, __file__, "--case", method, str(path)],
                                                  capture_output=True, text=True, check=True).stdout)
                        for _ in range(args.repeat)]
                best = min(runs, key=lambda r: r["seconds"])
                rows.append((n, method, best["seconds"], max(r["peak_rss_mb"] for r in runs), best["position_rms_mm"]))
    print(f"{'poses':>6} {'method':>10} {'seconds':>9} {'peak MB':>8} {'pos. RMS mm':>12}")
    for n, method, sec, mb, rms in rows:
        print(f"{n:6d} {method:>10} {sec:9.3f} {mb:8.0f} {rms:12.4f}")


if __name__ == "__main__":
    main()
