"""Following the drift of a real UR10 session (Landgraf et al. 2021, Series B), one pose ahead.

In time order (pose id = line in the file), the first 60% of the rows train and the rest are
predicted: the batch reference is ``compare_models`` on the training poses (the model it
recommends and compliance+map, its map chosen by cross-validation) evaluated at the later poses;
the online drift follower (:func:`fgcal.api.drift.follow`, the same joint-error block) runs
through every pose in order, predicting each from the poses before it (its drift and noise
chosen by the training poses' one-step-ahead likelihood only), and its one-step-ahead errors at
the same later poses are compared: mean and max (mm), the ratio online / batch.

Run: ``python bench/bench_drift.py [--series PATH] [--save-batch DIR | --batch DIR] [--harmonics H --map-sigma URAD]``
(``--batch DIR``: the batch results a run with ``--save-batch DIR`` wrote, to skip the comparison's minutes).
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small dense solves: threads only contend

import numpy as np
from _series import default_series, time_split


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--series", type=Path, default=default_series())
    ap.add_argument("--batch", type=Path, default=None,
                    help="folder of saved batch results of the training poses (MODEL.json: geometric, compliance, "
                         "compliance+map) written by --save-batch, to skip the comparison's minutes")
    ap.add_argument("--harmonics", type=int, default=None, help="online map harmonics (default: the batch's)")
    ap.add_argument("--map-sigma", type=float, default=None, help="online map prior, urad (default: the batch's)")
    ap.add_argument("--save-batch", type=Path, default=None, help="write the batch results into this folder")
    args = ap.parse_args()
    if args.series is None or not args.series.exists():
        print("real data not found (../shared/data/landgraf-ur10/Series_B); give --series PATH")
        return 0
    from fgcal.api.drift import follow
    from fgcal.estimation.calibrate import CalibrationOptions
    from fgcal.estimation.joint_errors import JointErrorSpec
    from fgcal.estimation.result import load_result, save_result
    from fgcal.estimation.verification import verify
    from fgcal.io.landgraf import read_series, series_to_datasets
    from fgcal.robots.robot_file import model_from_dict

    series = read_series(args.series)
    calib, _, model_dict, _ = series_to_datasets(series, str(args.series))
    model = model_from_dict(model_dict)
    train, later = time_split(series, calib)
    print(f"{args.series}: {calib.n_poses} poses in time order; {len(train)} train, {len(later)} later")
    t0 = time.perf_counter()
    batch = {}
    if args.batch is not None:
        for name in ("geometric", "compliance", "compliance+map"):
            if (args.batch / f"{name}.json").exists():
                batch[name] = load_result(args.batch / f"{name}.json")
    else:
        from fgcal.estimation.model_select import compare_models

        results, sel = compare_models(calib.select(train), model, CalibrationOptions(estimate_noise=True,
                                                                                     robust="huber"),
                                      rng=np.random.default_rng(0))
        batch = dict(results)
        print(f"batch comparison {time.perf_counter() - t0:.0f} s; recommended {sel.recommended}")
        if args.save_batch:
            args.save_batch.mkdir(parents=True, exist_ok=True)
            for name, res in results.items():
                save_result(res, args.save_batch / f"{name}.json")
    t_batch = time.perf_counter() - t0
    later_ds = calib.select(later)
    print(f"\n  {'model':28s} {'mean mm':>8s} {'max mm':>8s}")
    batch_err = {}
    for name, res in batch.items():
        e = verify(res, later_ds, model).after.position_mm
        batch_err[name] = e
        print(f"  batch {name:22s} {e.mean():8.4f} {e.max():8.4f}")
    ref = batch["compliance+map"]
    spec = JointErrorSpec.from_dict(ref.joint_errors["spec"])
    if args.harmonics is not None or args.map_sigma is not None:
        from dataclasses import replace

        spec = replace(spec, harmonics=spec.harmonics if args.harmonics is None else args.harmonics,
                       map_sigma=spec.map_sigma if args.map_sigma is None else args.map_sigma * 1e-6)
    print(f"  online block: compliances of joints {list(spec.compliance)}, {spec.harmonics} map harmonics, prior "
          f"{spec.map_sigma * 1e6:.1f} urad")
    ds = calib.select(np.sort(calib.pose_ids))
    n_train = (len(train) + 0.5) / ds.n_poses  # the first len(train) poses choose the drift
    for label, kind in (("geometric", "geometric"), ("compliance+map", "compliance+map")):
        t1 = time.perf_counter()
        r = follow(ds, model=kind, joint_errors=spec if kind != "geometric" else None, train=n_train, robot=model)
        elapsed = time.perf_counter() - t1
        by_pose = {s.pose: s.error_mm for s in r.steps}
        e = np.array([by_pose[p] for p in later])
        lv = r.levels
        b = batch_err.get(label, batch_err["compliance+map"])
        print(f"  online {label:21s} {e.mean():8.4f} {e.max():8.4f}   (drift {lv.length_mm:g} mm, {lv.angle_deg:g} deg, "
              f"map {lv.map_urad:g} urad per pose; noise factor {r.extra['noise_factor']:g}; "
              f"{sum(not s.taken for s in r.steps)} not taken; {elapsed:.0f} s" +
              (f" = {elapsed / t_batch:.2f} x the batch comparison's time)" if args.batch is None else ")"))
        print(f"    online / batch {label}: mean {e.mean() / b.mean():.3f}, max {e.max() / b.max():.3f}")
        for row in r.choice:
            print(f"    candidate drift x{row['geometry']:g} geometry, x{row['block']:g} block, noise "
                  f"x{row['noise_factor']:g}: training log-likelihood "
                  f"{row['loglik']:.1f}, one-step-ahead mean {row['mean_mm']:.4f} mm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
