"""Calibrate fixed datasets with the fgcal on PYTHONPATH and save the estimates and covariances, so
that two versions can be compared number for number (a refactoring must not move them).

    cd OLD_CHECKOUT && PYTHONPATH=$PWD python /path/to/tools/compare_versions.py /tmp/old.npz
    cd NEW_CHECKOUT && PYTHONPATH=$PWD python tools/compare_versions.py /tmp/new.npz --against /tmp/old.npz

The datasets: the paper dataset of the checkout that is imported (its ``datasets/puma560-paper``)
and simulated UR10 reflector centres, PUMA poses, probes and ballbar lengths (seeded), each with
declared and estimated noise. Each is solved by the estimator itself
(:func:`fgcal.estimation.calibrate.calibrate` with the robot given, not the one the dataset names),
so any version with the package's subpackage layout (November 2026 on) can be compared.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import fgcal
from fgcal import SimulationSettings, load_dataset, load_model, simulate
from fgcal.estimation.calibrate import calibrate
from fgcal.estimation.options import CalibrationOptions

SIMULATED = {  # case -> (built-in robot, simulation settings); simulated with seed 11
    "ur10_centres": ("ur10", dict(n_poses=40, levels=("centres",), n_balls=1)),
    "puma_poses": ("puma560", dict(n_poses=30, levels=("poses",))),
    "puma_probes": ("puma560", dict(n_poses=21, levels=("probes",))),
    "puma_ballbar": ("puma560", dict(n_poses=60, levels=("distances",), n_balls=1)),
}
NOISE_MODES = ("declared", "estimated")


def cases():
    """``(name, dataset, model)`` of every case: the paper dataset (when the checkout has it), then the simulated."""
    paper = Path(fgcal.__file__).resolve().parents[1] / "datasets" / "puma560-paper"
    if paper.is_dir():
        from fgcal import dataset_model

        ds = load_dataset(paper)
        yield "paper", ds, dataset_model(ds)
    for name, (robot, settings) in SIMULATED.items():
        model = load_model(robot)
        ds, _ = simulate(model, np.random.default_rng(11), SimulationSettings(**settings))
        yield name, ds, model


def estimates() -> dict[str, np.ndarray]:
    """Per case and noise mode: the parameters' names, estimates and covariance (internal units)."""
    out = {}
    for name, ds, model in cases():
        for mode in NOISE_MODES:
            r = calibrate(ds, model, CalibrationOptions(noise=mode))
            out[f"{name}-{mode}-names"] = np.array(r.names)
            out[f"{name}-{mode}-est"] = r.estimate
            out[f"{name}-{mode}-cov"] = r.covariance
    return out


def compare(old, new) -> list[str]:
    """One line per case of ``old``: the largest change of an estimate in its sigma and of a covariance
    entry in the product of the sigmas (both taken from ``old``)."""
    lines = []
    for k in sorted(old.files):
        if not k.endswith("-est"):
            continue
        case = k[:-4]
        if k not in new.files:
            lines.append(f"{case}: not in the new file")
        elif not np.array_equal(old[case + "-names"], new[case + "-names"]):
            lines.append(f"{case}: different parameters")
        else:
            sig = np.sqrt(np.diag(old[case + "-cov"]))
            d_est = np.max(np.abs(old[k] - new[k]) / sig)
            d_cov = np.max(np.abs(old[case + "-cov"] - new[case + "-cov"]) / np.outer(sig, sig))
            lines.append(f"{case:28s} max |d estimate| / sigma {d_est:.2e}   "
                         f"max |d covariance| / (sigma sigma) {d_cov:.2e}")
    return lines


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", type=Path, help="the .npz file the estimates and covariances are saved to")
    parser.add_argument("--against", type=Path, metavar="OLD_NPZ",
                        help="a file saved before (by another version): print how far each case moved")
    args = parser.parse_args(argv)
    if args.out.suffix != ".npz":  # np.savez would add it
        args.out = args.out.with_name(args.out.name + ".npz")
    res = estimates()
    np.savez(args.out, **res)
    print("saved", len(res), "arrays to", args.out)
    if args.against is not None:
        with np.load(args.against) as old, np.load(args.out) as new:
            print("\n".join(compare(old, new)))


if __name__ == "__main__":
    main()
