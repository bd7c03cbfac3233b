#!/usr/bin/env python3
"""fgcal against the MUKCa authors' method on the real two-socket data of one Panda.

Data: ``../shared/data/mukca-panda`` (nine placements of a plate with two sockets 50 mm apart; the
ball on the flange seated in each socket in ~30 configurations). Protocols: trained on one
placement (``back_left``), on three (``back_left, back_right, front_center``) and on each single
placement in turn (``--all-single``, the fairer summary of one-placement training); evaluated at
every other placement. Metric (the authors'): per placement, the RMS distance of each socket's
predicted ball centres from their mean, averaged over the two sockets ("consistency"), and
``| |mean_0 - mean_1| - 50 mm |`` (distance error); means over the held-out placements.

fgcal: ``fgcal import mukca`` as a library call, then ``calibrate`` at its defaults (the sockets as
unknown fixture points, the 50 mm as a distance constraint with sigma 0.05 mm, noise estimated,
outliers excluded, unidentifiable parameters held). The authors' method: ``bench/mukca_baseline.py``
(a standalone reimplementation of their objective, regulariser and parameter set). Both models
are scored by the same function (:func:`score`) on their predicted ball centres.

    python bench/bench_mukca.py [--data ../shared/data/mukca-panda] [--all-single] [--out bench-mukca.json]
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
DEFAULT_DATA = HERE.parent.parent / "shared" / "data" / "mukca-panda"
CHAIN = {"base": "panda_link0", "tip": "ball_link"}
PROTOCOLS = {"train1": ["back_left"], "train3": ["back_left", "back_right", "front_center"]}


def _baseline():
    spec = importlib.util.spec_from_file_location("mukca_baseline", HERE / "mukca_baseline.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def score(points_of, sets) -> dict:
    """Mean consistency RMS and |distance error| (mm) over placements; ``points_of(Q)`` -> (N, 3) mm."""
    cons, dist = [], []
    for Q0, Q1 in sets.values():
        P0, P1 = points_of(Q0), points_of(Q1)
        cons.append(np.mean([np.sqrt(np.mean(np.sum((P - P.mean(0)) ** 2, axis=1))) for P in (P0, P1)]))
        dist.append(abs(np.linalg.norm(P0.mean(0) - P1.mean(0)) - 50.0))
    return {"consistency_rms_mm": float(np.mean(cons)), "abs_distance_error_mm": float(np.mean(dist)),
            "max_abs_distance_error_mm": float(np.max(dist))}


def fgcal_calibration(data: Path, train: list, work: Path, prior: str = "none"):
    """fgcal's calibration from the training placements: ``(result, model)``."""
    from fgcal.estimation.calibrate import CalibrationOptions, calibrate
    from fgcal.io.dataset_io import dataset_model, load_dataset, save_dataset
    from fgcal.io.mukca import read_mukca
    from fgcal.robots.robot_file import load_model

    urdf = data / "panda.urdf"
    model = load_model(urdf, chain=CHAIN)
    placements = sorted(p.name for p in (data / "panda_2").iterdir() if p.is_dir())
    imp = read_mukca(data / "panda_2", "robot.urdf", model.n_joints, CHAIN,
                     holdout_placements=[p for p in placements if p not in train])
    out = work / ("ds-" + "-".join(train))
    save_dataset(imp.calibration, out, overwrite=True, extra_files={"robot.urdf": urdf.read_text()})
    ds = load_dataset(out)
    model = dataset_model(ds)
    return calibrate(ds, model, CalibrationOptions(prior=prior)), model


def run(data: Path, train: list, work: Path, base, prior: str = "none") -> dict:
    sets = base.load_sets(data, None)
    test = {k: v for k, v in sets.items() if k not in train}
    nominal = base.nominal_params(str(data / "panda.urdf"))
    t0 = time.process_time()
    theirs = base.calibrate_mukca({k: sets[k] for k in train}, str(data / "panda.urdf"))
    t1 = time.process_time()
    result, model = fgcal_calibration(data, train, work, prior)
    t2 = time.process_time()
    slots = result.slot_vector(model)
    return {"train": train, "test": sorted(test),
            "nominal": score(lambda Q: 1e3 * base.fk(nominal, Q), test),
            "mukca": score(lambda Q: 1e3 * base.fk(theirs, Q), test),
            "fgcal": score(lambda Q: model.forward(slots, Q)[:, :3, 3], test),
            "fgcal_held": [h["name"] for h in result.held],
            "fgcal_contact_sigma_mm": result.noise["contacts"].used if "contacts" in result.noise else None,
            "fgcal_outliers": len(result.outliers),
            "cpu_s": {"mukca": t1 - t0, "fgcal": t2 - t1}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--all-single", action="store_true", help="also train on each placement in turn")
    ap.add_argument("--out", type=Path, default=None, help="JSON of every protocol's numbers")
    ap.add_argument("--prior", choices=("none", "weak"), default="none", help="fgcal's --prior (default none)")
    args = ap.parse_args(argv)
    if not (args.data / "panda_2").is_dir():
        print(f"bench_mukca: {args.data}: no MUKCa data (panda_2/) there", file=sys.stderr)
        return 2
    import tempfile

    base = _baseline()
    protocols = dict(PROTOCOLS)
    if args.all_single:
        for p in sorted(q.name for q in (args.data / "panda_2").iterdir() if q.is_dir()):
            protocols[f"single:{p}"] = [p]
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, train in protocols.items():
            out[name] = r = run(args.data, train, Path(tmp), base, args.prior)
            print(f"{name:<22} nominal {r['nominal']['consistency_rms_mm']:.3f} / "
                  f"{r['nominal']['abs_distance_error_mm']:.3f}   MUKCa {r['mukca']['consistency_rms_mm']:.3f} / "
                  f"{r['mukca']['abs_distance_error_mm']:.3f}   fgcal {r['fgcal']['consistency_rms_mm']:.3f} / "
                  f"{r['fgcal']['abs_distance_error_mm']:.3f} mm (consistency / |distance error|, held-out mean)",
                  flush=True)
    singles = [v for k, v in out.items() if k.startswith("single:")]
    if singles:
        for who in ("nominal", "mukca", "fgcal"):
            c = np.mean([s[who]["consistency_rms_mm"] for s in singles])
            d = np.mean([s[who]["abs_distance_error_mm"] for s in singles])
            print(f"all single placements, {who:<8} consistency {c:.3f}  |distance error| {d:.3f} mm")
    if args.out:
        args.out.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
