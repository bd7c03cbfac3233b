"""Benchmark: a camera calibration's solve time (DESIGN.md 8.4), standalone.

Eye-to-hand on a perturbed Kinova 6R (tests/pixel_sim.py's independent generator: OpenCV's
projectPoints, 0.3 px), a 7 x 10 board (70 corners), six intrinsics estimated. Reports the calibration's
CPU time (and wall time) of 100 images x 70 corners and, as ratios against the 25-image run in this same script, the
cost per image at 25, 50, 100 and 200 images (linear growth: ratios near 1). Run:
``python bench/bench_pixels.py [--images 25,50,100,200] [--corners 7x10]``.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import numpy as np  # noqa: E402

from fgcal.estimation.calibrate import CalibrationOptions, calibrate  # noqa: E402
from fgcal.io.dataset_io import dataset_model, load_dataset  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--images", default="25,50,100,200")
    ap.add_argument("--corners", default="7x10", help="board ROWSxCOLS")
    args = ap.parse_args(argv)
    from pixel_sim import camera_dataset

    rows, cols = (int(v) for v in args.corners.split("x"))
    counts = [int(v) for v in args.images.split(",")]
    urdf = ROOT / "tests" / "data" / "urdf" / "kinova.urdf"
    chain = {"tip": "j2s6s200_end_effector"}
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in counts:
            d = Path(tmp) / f"n{n}"
            camera_dataset(d, urdf, chain, np.random.default_rng(0), mode="eye-to-hand", n_images=n, rows=rows,
                           cols=cols, square=20.0, estimate=("fx", "fy", "cx", "cy", "k1", "k2"), n_held_out=0)
            ds = load_dataset(d)
            model = dataset_model(ds)
            t, c = time.perf_counter(), time.process_time()
            result = calibrate(ds, model, CalibrationOptions())
            wall, seconds = time.perf_counter() - t, time.process_time() - c  # CPU: less noisy on a shared machine
            out.append((n, seconds, result.iterations, result.levels["pixels"].rms))
            print(f"{n:4d} images x {rows * cols} corners: {seconds:7.2f} s CPU ({wall:.2f} s wall, "
                  f"{result.iterations} iterations, reprojection RMS {result.levels['pixels'].rms:.3f} px)", flush=True)
    n0, s0 = out[0][0], out[0][1]
    print(f"cost per image against {n0} images (1.0: linear growth):")
    for n, s, it, _ in out:
        print(f"  {n:4d} images: {s / n / (s0 / n0):5.2f}  ({s / it:.2f} s CPU per iteration)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
