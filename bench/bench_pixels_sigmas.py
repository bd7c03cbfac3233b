"""Benchmark (evidence, not speed): are a camera calibration's sigmas honest? Over seeded datasets
of tests/pixel_sim.py's independent generator (a perturbed URDF's own FK, OpenCV's projectPoints,
0.3 px), the chi-square per degree of freedom of the camera mount and the estimated intrinsics
against the truth (in the calibration's base and tool frames), and the board's corners at held-out
poses against the accuracy the covariance predicts (RMS ratio). tests/test_pixels_simulated.py pins
the Kinova eye-to-hand case; this script runs any of the four robot/mount cases. Run:
``python bench/bench_pixels_sigmas.py [--robot panda|kinova] [--mode eye-to-hand|eye-in-hand]
[--estimate fx,fy,cx,cy,k1,k2|none] [--seeds 25] [--images 8]``.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import numpy as np  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default="panda", choices=("panda", "kinova"))
    ap.add_argument("--mode", default="eye-in-hand", choices=("eye-to-hand", "eye-in-hand"))
    ap.add_argument("--estimate", default="fx,fy,cx,cy,k1,k2", help="intrinsics estimated, or none")
    ap.add_argument("--seeds", type=int, default=25)
    ap.add_argument("--images", type=int, default=8)
    args = ap.parse_args(argv)
    from test_pixels_simulated import _held_out_check, _solve, _z_scores

    estimate = () if args.estimate == "none" else tuple(args.estimate.split(","))
    z, err2, pred2 = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seeds):
            truth, model, result = _solve(Path(tmp) / f"ds{seed}", args.robot, args.mode, estimate, seed=200 + seed,
                                          n_images=args.images, rows=3, cols=4, square=40.0, n_held_out=10)
            z.append(_z_scores(result, model, truth, estimate))
            err, predicted = _held_out_check(result, model, truth)
            err2.append(err**2)
            pred2.append(predicted**2)
    z = np.array(z)
    print(f"{args.robot} {args.mode}, intrinsics estimated: {', '.join(estimate) or 'none'}; {args.seeds} datasets "
          f"of {args.images} images x 12 corners")
    print(f"  chi-square per dof of the mount and intrinsics: {float(np.mean(z**2)):.3f} (0.7-1.5 wanted); per "
          f"entry {np.round(np.mean(z**2, axis=0), 2).tolist()}")
    print(f"  held-out corners: RMS error / predicted {float(np.sqrt(np.mean(err2) / np.mean(pred2))):.3f} "
          f"(predicted {float(np.sqrt(np.mean(pred2))):.3f} mm)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
