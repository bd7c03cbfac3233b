"""Batch calibration: whole-process CPU and peak memory of ``fgcal calibrate`` against a plain scipy solve.

The reference is ``../shared/bench/sparse_joint_solve.py`` (relative to the repository; another
path with ``--reference``), a numpy + scipy solve of the same probe-level problem written without
fgcal: the 30 parameters and a joint correction per pose, ball centres eliminated, analytic sparse
Jacobian, ``least_squares(method="trf", x_scale="jac")``, covariance by a per-pose Schur
complement. It is run as it is, never copied here; when it is absent the bench says so and stops.

Datasets: ``fgcal simulate DIR --robot puma560 --poses N --seed N`` (3 balls x 4 probe points per
pose, the paper's noise). Every run is a fresh process with single-threaded BLAS
(``OMP/OPENBLAS/MKL_NUM_THREADS=1``), measured from outside (``os.wait4``: user + system CPU of the
whole process and its children, imports, reading and writing included, and its peak RSS); the runs
of a size are interleaved ``--repeat`` times and the least CPU of each is kept (the machine is
shared: CPU time, not wall time).

Timed: ``fgcal calibrate DIR --out R.json`` with its defaults (noise estimated per level, outliers
excluded: what a user runs) and ``sparse_joint_solve.py DIR OUT.json --quiet``.
Checked, untimed: ``fgcal calibrate --noise declared --outliers none`` (the reference's problem:
declared noise, nothing excluded) against the reference's estimate, ``max |d| / sigma`` (goal 0.01),
and the sigmas' largest relative difference; and ``max |d| / sigma`` against the reference polished
(its own code, its ``least_squares`` result carried on by Gauss-Newton steps on its own residuals and
Jacobian to the optimum of its own objective: ``bench/bench_batch_convergence.py``), since at 10,000
poses the reference as shipped stops about 0.025 sigma short of that optimum.
``--own`` also runs ``bench/scipy_reference.py`` (our own scipy solve, which imports fgcal's
kinematics) beside it; it is never the reference.

Goals (issue 25): CPU ratio at most 0.8 at 1,000 and 10,000 poses; peak at 10,000 poses at most 400 MB.
Run: ``python bench/bench_batch.py [--poses 21 1000 10000] [--repeat 3] [--reference PATH] [--own]``.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

from _process import FGCAL, run
from bench_batch_convergence import polished_reference

HERE = Path(__file__).resolve().parent
REFERENCE = HERE.parent.parent / "shared" / "bench" / "sparse_joint_solve.py"


def estimates(path: Path) -> dict[str, tuple[float, float]]:
    """``{name: (estimate, sigma)}`` (file units: mm, deg) of a ``fgcal-result/1``-style JSON file."""
    return {p["name"]: (p["estimate"], p["sigma"]) for p in json.loads(path.read_text())["parameters"]}


def compare(ours: Path, ref: Path) -> tuple[float, float]:
    """``max |ours - ref| / sigma_ref`` and ``max |sigma_ours / sigma_ref - 1|`` over the reference's parameters."""
    a, b = estimates(ours), estimates(ref)
    if sorted(a) != sorted(b):
        raise RuntimeError(f"different parameters: fgcal {sorted(a)} against the reference {sorted(b)}")
    z = max(abs(a[n][0] - b[n][0]) / b[n][1] for n in b)
    s = max(abs(a[n][1] / b[n][1] - 1) for n in b)
    return z, s


def own_reference(stdout: bytes, ref: Path) -> float:
    """``max |own - ref| / sigma_ref`` of ``bench/scipy_reference.py``'s printed estimate."""
    d = json.loads(stdout)
    b = estimates(ref)
    return max(abs(e - b[n][0]) / b[n][1] for n, e in zip(d["names"], d["estimate"], strict=True))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--poses", type=int, nargs="+", default=[21, 1000, 10000])
    ap.add_argument("--repeat", type=int, default=3, help="runs per case, interleaved; the least CPU is kept")
    ap.add_argument("--reference", type=Path, default=REFERENCE, help=f"the reference solve (default {REFERENCE})")
    ap.add_argument("--own", action="store_true",
                    help="also run bench/scipy_reference.py (shown beside, never instead)")
    args = ap.parse_args()
    if not args.reference.is_file():
        print(f"bench_batch: the reference {args.reference} is absent: skipped (give its path with --reference)")
        return 0
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.poses:
            ds = Path(tmp) / f"puma{n}"
            run(FGCAL + ["simulate", str(ds), "--robot", "puma560", "--poses", str(n), "--seed", str(n)])
            out = {k: Path(tmp) / f"{k}{n}.json" for k in ("fgcal", "ref", "same")}
            cmds = {"fgcal": FGCAL + ["calibrate", str(ds), "--out", str(out["fgcal"]), "--force"],  # repeated: replace
                    "ref": [sys.executable, str(args.reference), str(ds), str(out["ref"]), "--quiet"]}
            if args.own:
                cmds["own"] = [sys.executable, str(HERE / "scipy_reference.py"), str(ds)]
            runs: dict[str, list[dict]] = {k: [] for k in cmds}
            for _ in range(args.repeat):  # interleaved: a slow spell of the shared machine hits all alike
                for k, cmd in cmds.items():
                    runs[k].append(run(cmd))
            best = {k: min(rs, key=lambda r: r["cpu"]) | {"peak_mb": max(r["peak_mb"] for r in rs)}
                    for k, rs in runs.items()}
            run(FGCAL + ["calibrate", str(ds), "--out", str(out["same"]), "--noise", "declared", "--outliers", "none"])
            z, s = compare(out["same"], out["ref"])
            polished_reference(args.reference, ds, Path(tmp) / f"polished{n}.json")
            z_opt, _ = compare(out["same"], Path(tmp) / f"polished{n}.json")
            own = (best["own"]["cpu"], own_reference(best["own"]["stdout"], out["ref"])) if args.own else None
            rows.append((n, best["fgcal"], best["ref"], z, s, z_opt, own))
    print(f"reference: {args.reference}; CPU = user + sys of the whole process, best of {args.repeat}, "
          "single-threaded BLAS")
    head = (f"{'poses':>6} {'fgcal s':>8} {'ref s':>8} {'ratio':>6} {'fgcal MB':>8} {'ref MB':>8} {'MB ratio':>8} "
            f"{'max|d|/sigma':>12} {'sigma rel':>9} {'|d|/sig opt':>11}")
    print(head + (f" {'own s':>7} {'own/ref':>7} {'own |d|/sig':>11}" if args.own else ""))
    for n, f, r, z, s, z_opt, own in rows:
        line = (f"{n:6d} {f['cpu']:8.2f} {r['cpu']:8.2f} {f['cpu'] / r['cpu']:6.2f} {f['peak_mb']:8.0f} "
                f"{r['peak_mb']:8.0f} {f['peak_mb'] / r['peak_mb']:8.2f} {z:12.2g} {s:9.1g} {z_opt:11.2g}")
        if own:
            line += f" {own[0]:7.2f} {own[0] / r['cpu']:7.2f} {own[1]:11.2g}"
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
