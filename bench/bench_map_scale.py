"""``fgcal calibrate --model compliance+map`` at scale: CPU and peak memory against the geometric solve.

Datasets: UR10 laser-tracker series simulated by ``bench/ur10_series_sim.py`` (independent of
fgcal's kinematics: gravity compliance and a 30-harmonic joint error map, Series B's noise),
written in Landgraf's format and imported with ``fgcal import landgraf``, at ``--poses`` sizes
(default 1,000, 4,000 and 8,400); and the real Series B (1,495 poses) when it is found.

Timed, each in a fresh process measured from outside (``os.wait4``: user + system CPU of the whole
process, imports, reading and writing included, and its peak RSS), single-threaded BLAS, the runs
of a size interleaved ``--repeat`` times and the least CPU of each kept (the machine is shared):
``fgcal calibrate DIR --out R.json`` (the reference: the geometric solve, fgcal's defaults) and
``fgcal calibrate DIR --model compliance+map --out R.json``. The cross-validation alone
(:func:`fgcal.estimation.cross_validation.cv_problem` and :func:`~fgcal.estimation.cross_validation.cross_validate`,
its CPU and its ``tracemalloc`` peak) is timed in a child process per size: its cost per pose
should not grow with the poses.

Held-out accuracy on Series B (``--accuracy``): each model's mean position error (mm) on poses the
fit never saw, for a time-ordered split (the first 60% of the rows train, the rest test; a goal
repeated across the cut stays on the training side) and a random 40% of the goals held out
(seed 0), the models chosen with 5 random folds. ``--src PATH`` runs every child with another
fgcal checkout first on the path (a before/after comparison in one script).

Goals (issue 25): on 8,000+ poses the compliance+map run at most 10 times the geometric run's CPU
and at most 500 MB peak, the same held-out accuracy, the cross-validation's cost linear in the poses.
Run: ``python bench/bench_map_scale.py [--poses 1000 4000 8400] [--repeat 1] [--accuracy] [--src PATH]``.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from _process import FGCAL
from _process import run as run_process
from _series import default_series, time_split

HERE = Path(__file__).resolve().parent
CPU_GOAL, PEAK_GOAL_MB, CV_GROWTH_GOAL = 10.0, 500.0, 1.25  # the last: per-pose CV cost, largest over smallest
SRC: list[str] = []  # another fgcal checkout first on the children's path (--src)


def run(cmd: list[str]) -> dict:
    """``cmd`` in a fresh process, ``--src`` first on its path (:func:`_process.run`)."""
    return run_process(cmd, SRC)


def make_dataset(work: Path, n: int, seed: int) -> Path:
    """A simulated series of ``n`` poses, imported: the dataset directory."""
    sys.path.insert(0, str(HERE))
    import ur10_series_sim as sim

    csv, out = work / f"ur10-{n}.csv", work / f"ur10-{n}"
    sim.write_series(csv, sim.simulate(n, np.random.default_rng(seed)))
    run(FGCAL + ["import", "landgraf", str(csv), str(out), "--force"])
    return out


def best(cmds: dict[str, list[str]], repeat: int) -> dict[str, dict]:
    """Each command run ``repeat`` times, interleaved; the run of least CPU of each."""
    out: dict[str, dict] = {}
    for _ in range(repeat):
        for key, cmd in cmds.items():
            r = run(cmd)
            if key not in out or r["cpu"] < out[key]["cpu"]:
                out[key] = r
    return out


def cv_child(directory: str) -> int:
    """Time the cross-validation alone on a dataset (run in a child): prints one JSON line."""
    import tracemalloc

    from fgcal.estimation.calibrate import calibrate
    from fgcal.estimation.joint_errors import JointErrorSpec
    from fgcal.estimation.model_select import HARMONICS_GRID, cross_validate, cv_problem
    from fgcal.io.dataset_io import dataset_model, load_dataset

    ds = load_dataset(directory)
    model = dataset_model(ds)
    geo = calibrate(ds, model)
    spec = JointErrorSpec(compliance=(2, 3), harmonics=max(HARMONICS_GRID))
    tracemalloc.start()
    t0 = time.process_time()
    prob = cv_problem(ds, model, geo, spec)
    t1 = time.process_time()
    cross_validate(prob, 5, np.random.default_rng(0))
    t2 = time.process_time()
    peak = tracemalloc.get_traced_memory()[1] / 2**20
    print(json.dumps({"poses": ds.n_poses, "problem": t1 - t0, "cv": t2 - t1, "peak_mb": peak}))
    return 0


def accuracy_child(series_path: str) -> int:
    """Held-out mean position error per model on Series B, two splits (run in a child): one JSON line."""
    from fgcal.estimation.calibrate import CalibrationOptions
    from fgcal.estimation.model_select import compare_models
    from fgcal.io.landgraf import read_series, series_to_datasets
    from fgcal.robots.robot_file import model_from_dict

    series = read_series(series_path)
    out = {}
    calib, _, model_dict, _ = series_to_datasets(series, series_path)
    train, test = time_split(series, calib, 0.6)
    splits = {"time-ordered 60/40": (calib.select(train), calib.select(test), model_dict)}
    c2, h2, d2, _ = series_to_datasets(series, series_path, holdout=0.4, rng=np.random.default_rng(0))
    splits["random 40% of goals"] = (c2, h2, d2)
    for label, (train_ds, test_ds, md) in splits.items():
        t0 = time.process_time()
        _, sel = compare_models(train_ds, model_from_dict(md), CalibrationOptions(estimate_noise=True, robust="huber"),
                                verification=test_ds, rng=np.random.default_rng(0))
        out[label] = {"train": train_ds.n_poses, "test": test_ds.n_poses, "cpu": time.process_time() - t0,
                      "recommended": sel.recommended,
                      "heldout": {s.model: s.heldout_error for s in sel.scores},
                      "harmonics": sel.score("compliance+map").spec.get("harmonics")}
    print(json.dumps(out))
    return 0


def time_pair(directory: Path, work: Path, repeat: int, label: str) -> dict:
    geo = FGCAL + ["calibrate", str(directory), "--out", str(work / "geo.json"), "--force"]
    mapped = FGCAL + ["calibrate", str(directory), "--model", "compliance+map", "--out", str(work / "map.json"),
                      "--force"]
    r = best({"geometric": geo, "map": mapped}, repeat)
    g, m = r["geometric"], r["map"]
    ratio = m["cpu"] / g["cpu"]
    print(f"{label:>22s}  geometric {g['cpu']:6.2f} s {g['peak_mb']:5.0f} MB   compliance+map {m['cpu']:6.2f} s "
          f"{m['peak_mb']:5.0f} MB   CPU ratio {ratio:5.2f} (goal <= {CPU_GOAL:g})   peak "
          f"{m['peak_mb'] / PEAK_GOAL_MB:4.2f} of {PEAK_GOAL_MB:g} MB", flush=True)
    return {"geometric": g, "map": m, "ratio": ratio}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, nargs="*", default=[1000, 4000, 8400])
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--series", type=Path, default=default_series())
    ap.add_argument("--accuracy", action="store_true", help="held-out accuracy per model on Series B")
    ap.add_argument("--no-cv", action="store_true", help="skip the cross-validation's own timing")
    ap.add_argument("--src", type=Path, help="another fgcal checkout to run (first on the children's path)")
    ap.add_argument("--cv-child", help=argparse.SUPPRESS)
    ap.add_argument("--accuracy-child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.cv_child:
        return cv_child(args.cv_child)
    if args.accuracy_child:
        return accuracy_child(args.accuracy_child)
    if args.src:
        SRC.append(str(args.src.resolve()))
    me = [sys.executable, str(Path(__file__).resolve())]
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        print("compliance+map against the geometric solve (whole-process CPU, peak RSS; best of "
              f"{args.repeat})", flush=True)
        cv = []
        for n in args.poses:
            d = make_dataset(work, n, args.seed)
            time_pair(d, work, args.repeat, f"simulated, {n} poses")
            if not args.no_cv:
                r = json.loads(run(me + ["--cv-child", str(d)])["stdout"])
                cv.append(r)
        if args.series is not None and args.series.exists():
            sb = work / "series-b"
            run(FGCAL + ["import", "landgraf", str(args.series), str(sb), "--force"])
            time_pair(sb, work, args.repeat, "Series B, 1495 poses")
        else:
            print("Series B not found (../shared/data/landgraf-ur10/Series_B): give --series PATH")
        if cv:
            print("\ncross-validation alone (CPU, tracemalloc peak):")
            for r in cv:
                per = (r["problem"] + r["cv"]) / r["poses"] * 1e3
                print(f"  {r['poses']:6d} poses: linearisation {r['problem']:6.2f} s, folds and grid {r['cv']:6.2f} s, "
                      f"{per:6.3f} ms per pose, peak {r['peak_mb']:5.0f} MB")
            if len(cv) > 1:
                first, last = cv[0], cv[-1]
                growth = ((last["problem"] + last["cv"]) / last["poses"]) / ((first["problem"] + first["cv"])
                                                                              / first["poses"])
                print(f"  cost per pose at {last['poses']} over {first['poses']} poses: {growth:.2f} "
                      f"(linear: 1; goal <= {CV_GROWTH_GOAL:g})")
        if args.accuracy and args.series is not None and args.series.exists():
            r = json.loads(run(me + ["--accuracy-child", str(args.series)])["stdout"])
            print("\nheld-out mean position error on Series B (mm; models chosen by 5 random folds):")
            for label, v in r.items():
                h = v["heldout"]
                print(f"  {label:20s} {v['train']:4d} train / {v['test']:4d} test: geometric {h['geometric']:.4f}, "
                      f"compliance {h['compliance']:.4f}, compliance+map {h['compliance+map']:.4f} "
                      f"({v['harmonics']} harmonics); recommended {v['recommended']}; comparison {v['cpu']:.1f} s CPU")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
