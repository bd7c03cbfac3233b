"""Kinematics of one joint set: the scan of 4x4 operation matrices (``fgcal.robots.single_pose``,
what the online engines, GTSAM's per-pose factors and IK use) against the operation-by-operation
walk (``Chain.jacobians_walk``, what a batch of poses uses), both with the Jacobians of three
tool-frame points, in this process, interleaved; wall time per call (one thread, small arrays).
Run: ``python bench/bench_kinematics.py [--calls 3000]``.
"""
from __future__ import annotations

import argparse
import time

import numpy as np


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--calls", type=int, default=3000)
    args = ap.parse_args()
    from fgcal import load_model
    from fgcal.robots.single_pose import jacobians_one

    for name in ("puma560", "ur10"):
        model = load_model(name)
        chain = model.chain
        rng = np.random.default_rng(0)
        x = model.nominal
        q = rng.uniform(model.joint_limits[:, 0], model.joint_limits[:, 1])[None] * np.pi / 180
        offsets = np.array(list(model.tooling.balls.values()))[:3] if model.tooling else rng.normal(size=(3, 3))
        best = {"scan": np.inf, "walk": np.inf}
        for _ in range(5):  # interleaved rounds; the least time of each counts
            for label, f in (("scan", lambda: jacobians_one(chain, x, q, offsets)),
                             ("walk", lambda: chain.jacobians_walk(x, q, offsets))):
                t = time.perf_counter()
                for _ in range(args.calls // 5):
                    f()
                best[label] = min(best[label], (time.perf_counter() - t) / (args.calls // 5))
        print(f"{name:8s} scan {best['scan'] * 1e6:7.1f} us  walk {best['walk'] * 1e6:7.1f} us  "
              f"ratio {best['scan'] / best['walk']:.2f}")


if __name__ == "__main__":
    main()
