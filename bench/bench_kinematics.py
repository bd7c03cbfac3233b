"""Kinematics timings, each pair interleaved in this process, the least time of the rounds kept
(wall time per call, one thread):

1. one joint set: the scan of 4x4 operation matrices (``fgcal.robots.single_pose``, what the online
   engines, GTSAM's per-pose factors and IK use) against the walk (``Chain.jacobians_walk``, what a
   batch of poses uses), both with the Jacobians of three tool-frame points;
2. batches of poses (``--poses``, default 1,000 and 3,000): the walk by frame columns
   (``fgcal.robots.chain_walk``) against the operation-by-operation walk it replaced, kept in
   ``tests/kinematics_reference.py``: ``jacobians_walk`` (tool pose only, and with one tool point per
   pose, as the batch calibration asks), ``forward`` and ``forward_frames``, on the UR10's chain, a
   coupled chain (joint map and offsets) with a tool offset, and one with a prismatic joint.

Run: ``python bench/bench_kinematics.py [--calls 3000] [--poses 1000 3000] [--rounds 7]``.

Measured (2 cores shared with other work: runs on a quiet and a loaded machine), old -> new per call,
UR10: jacobians at 1,000 poses 9.4-16.6 -> 0.8-1.5 ms (7-11x), at 3,000 poses 22-33 -> 2.6-5.7 ms
(6-8.5x); with one tool point per pose 1,000 10-17 -> 1.2-2.0 ms, 3,000 23-32 -> 3.6-6.4 ms (4-7x); the
coupled chain with a tool offset and the prismatic one 2.2-8x; forward 4.5-7x; forward_frames 1.5-2x
(it writes every frame); at 21 poses about even (0.85-1.2x; forward_frames 0.65-0.75x). Most of the
old walk's time was its large temporaries: on this machine a fresh array costs ~2.5 us a 4 kB page in
faults, which is why the new walk writes its columns straight into the outputs.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))


def interleaved(cases: dict, rounds: int, calls: int) -> dict:
    """Least seconds per call of each of ``cases`` (label: function), the labels taking turns."""
    best = dict.fromkeys(cases, np.inf)
    for _ in range(rounds):
        for label, f in cases.items():
            t = time.perf_counter()
            for _ in range(calls):
                f()
            best[label] = min(best[label], (time.perf_counter() - t) / calls)
    return best


def one_pose(calls: int) -> None:
    from fgcal import load_model
    from fgcal.robots.single_pose import jacobians_one

    for name in ("puma560", "ur10"):
        model = load_model(name)
        chain = model.chain
        rng = np.random.default_rng(0)
        x = model.nominal
        q = rng.uniform(model.joint_limits[:, 0], model.joint_limits[:, 1])[None] * np.pi / 180
        offsets = np.array(list(model.tooling.balls.values()))[:3] if model.tooling else rng.normal(size=(3, 3))
        best = interleaved({"scan": lambda: jacobians_one(chain, x, q, offsets),
                            "walk": lambda: chain.jacobians_walk(x, q, offsets)}, 5, calls // 5)
        print(f"one pose {name:8s} scan {best['scan'] * 1e6:7.1f} us  walk {best['walk'] * 1e6:7.1f} us  "
              f"ratio {best['scan'] / best['walk']:.2f}")


def chains():
    from fgcal import load_model
    from fgcal.robots.kinematics import Chain

    ur10 = load_model("ur10")
    rng = np.random.default_rng(2)
    x = ur10.nominal + rng.normal(size=ur10.chain.n_slots) * 1e-3  # calibrated values: no slot exactly zero
    coupled = Chain(("revolute",) * 6, joint_map=np.eye(6) + 0.3 * np.eye(6, k=1), joint_offset=rng.normal(size=6),
                    tool_offset=np.array([[0, -1, 0, 5], [1, 0, 0, 6], [0, 0, 1, 7], [0, 0, 0, 1.0]]))
    prismatic = Chain(("revolute", "revolute", "prismatic", "revolute", "revolute", "revolute"))
    return {"ur10": (ur10.chain, x), "coupled+tool_offset": (coupled, x), "prismatic": (prismatic, x)}


def batches(poses, rounds: int) -> None:
    import kinematics_reference as ref

    for name, (chain, x) in chains().items():
        for n in poses:
            rng = np.random.default_rng(n)
            q = rng.uniform(-3.0, 3.0, size=(n, chain.n_joints))
            point = rng.normal(size=(n, 1, 3)) * 100  # one tool point per pose, as the batch graph asks
            calls = max(3, 20000 // n)
            pairs = {
                "jacobians": (lambda: chain.jacobians_walk(x, q), lambda: ref.jacobians_walk(chain, x, q)),
                "jacobians+point": (lambda: chain.jacobians_walk(x, q, point),
                                    lambda: ref.jacobians_walk(chain, x, q, point)),
                "forward": (lambda: chain.forward(x, q), lambda: ref.forward(chain, x, q)),
                "forward_frames": (lambda: chain.forward_frames(x, q), lambda: ref.forward_frames(chain, x, q)),
            }
            for what, (new, old) in pairs.items():
                best = interleaved({"new": new, "old": old}, rounds, calls)
                print(f"{name:20s} {n:6d} poses {what:16s} old {best['old'] * 1e3:7.2f} ms  "
                      f"new {best['new'] * 1e3:7.2f} ms  speed-up {best['old'] / best['new']:5.2f}x")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--calls", type=int, default=3000, help="single-pose calls per timing (default 3000)")
    ap.add_argument("--poses", type=int, nargs="+", default=[1000, 3000], help="batch sizes (default 1000 3000)")
    ap.add_argument("--rounds", type=int, default=7, help="interleaved rounds per batch timing (default 7)")
    args = ap.parse_args()
    one_pose(args.calls)
    batches(args.poses, args.rounds)


if __name__ == "__main__":
    main()
