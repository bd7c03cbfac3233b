"""Honest by default (issue 14): chi-square of the true error, coverage and accuracy per scenario.

For each row of :data:`fgcal.studies.honesty.SCENARIOS`, ``--seeds`` seeded datasets (25 by default) are
calibrated with default options. Columns: mean chi-square of the true error per parameter
(honest: 0.7-1.5), share of 95% intervals covering the truth (90-99%), mean RMS ball-position
error at 100 random joint sets for fgcal and for the two-stage method, excluded outliers per
dataset and how many of the planted gross errors were among them. Then (``--online``) the online
engines against the batch solve of the same data, forward and reversed: the largest difference
over the parameters in batch sigmas (target: below 0.5), poses rejected, and balls whose plain
sphere fit lands on the mirror image of the centre. Run: ``python bench/bench_honest.py [--seeds 25] [--rows NAME ...]``.
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np


def batch_table(model, rows, seeds):
    from fgcal.studies.honesty import SCENARIOS, run_scenario, summarise

    print(f"{'scenario':36s} {'n':>3s} {'chi2/dof':>9s} {'cover95':>8s} {'fgcal mm':>9s} {'2-stage':>9s} "
          f"{'outl.':>6s} {'planted':>8s} {'held':>5s} {'ok':>4s} {'s':>6s}")
    failed = []
    for name in rows:
        t = time.perf_counter()
        s = summarise(run_scenario(model, SCENARIOS[name], range(2000, 2000 + seeds)))
        ok = 0.7 <= s["chi2_per_dof"] <= 1.5 and 0.90 <= s["coverage"] <= 0.99 and s["fgcal_mm"] <= s["baseline_mm"]
        if not ok:
            failed.append(name)
        print(f"{name:36s} {s['n']:3d} {s['chi2_per_dof']:9.3f} {s['coverage']:8.3f} {s['fgcal_mm']:9.4f} "
              f"{s['baseline_mm']:9.4f} {s['outliers']:6.2f} {s['planted_found']:8.2f} {s['held']:5.1f} "
              f"{'yes' if ok else 'NO':>4s} {time.perf_counter() - t:6.1f}", flush=True)
    return failed


ONLINE_SCENARIOS = ("paper noise, 3 mirrored sphere fits", "repeatability 0.01 deg undeclared")


def online_table(model, seeds):
    from fgcal.studies.honesty import SCENARIOS, Scenario, online_agreement

    scenarios = {ONLINE_SCENARIOS[0]: Scenario(mirrored=3), ONLINE_SCENARIOS[1]: SCENARIOS[ONLINE_SCENARIOS[1]]}
    print(f"\n{'scenario':36s} {'engine':6s} {'order':8s} {'n':>3s} {'|online-batch|/sigma median':>28s} {'max':>6s} "
          f"{'rejected':>9s} {'mirrored':>9s}")
    failed = []
    for name, scenario in scenarios.items():
        for kind in ("isam2", "ekf", "ukf"):
            for order in ("forward", "reversed"):
                t = time.perf_counter()
                rows = [online_agreement(model, kind, seed, order == "reversed", scenario)
                        for seed in range(3000, 3000 + seeds)]
                dev = np.array([r["max_sigma"] for r in rows])
                if dev.max() > 0.5:
                    failed.append(f"{name} {kind} {order}")
                print(f"{name:36s} {kind:6s} {order:8s} {len(rows):3d} {np.median(dev):28.3f} {dev.max():6.3f} "
                      f"{sum(r['rejected'] for r in rows):9d} {sum(r['mirrored'] for r in rows):9d} "
                      f"{time.perf_counter() - t:6.1f}s", flush=True)
    return failed


if __name__ == "__main__":
    from fgcal.robots.robot_file import load_model
    from fgcal.studies.honesty import SCENARIOS

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=25)
    ap.add_argument("--rows", nargs="*", default=list(SCENARIOS))
    ap.add_argument("--online", action="store_true", help="also the online engines against the batch")
    ap.add_argument("--online-only", action="store_true")
    args = ap.parse_args()
    puma = load_model("puma560")
    failed = [] if args.online_only else batch_table(puma, args.rows, args.seeds)
    if args.online or args.online_only:
        failed += online_table(puma, args.seeds)
    if failed:
        print("rows outside the targets:", ", ".join(failed))
        sys.exit(1)
