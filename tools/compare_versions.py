"""Calibrate fixed datasets with the fgcal on PYTHONPATH and save the estimates and covariances, so
that two versions can be compared number for number (a refactoring must not move them).

    cd OLD_CHECKOUT && PYTHONPATH=$PWD python tools/compare_versions.py /tmp/old.npz
    cd NEW_CHECKOUT && PYTHONPATH=$PWD python tools/compare_versions.py /tmp/new.npz --against /tmp/old.npz

The datasets: the bundled paper dataset and simulated UR10 reflector centres, PUMA poses, probes and
ballbar lengths (seeded), each with declared and estimated noise. Works with the flat layout of
older versions too.
"""
import sys

import numpy as np

from fgcal import SimulationSettings, load_dataset, load_model, simulate

out = sys.argv[1]
try:
    from fgcal.estimation.calibrate import CalibrationOptions, calibrate
except ImportError:
    from fgcal.calibrate import CalibrationOptions, calibrate

res = {}
cases = {
    "paper": None,
    "ur10_centres": ("ur10", dict(n_poses=40, levels=("centres",), n_balls=1)),
    "puma_poses": ("puma560", dict(n_poses=30, levels=("poses",))),
    "puma_probes": ("puma560", dict(n_poses=21, levels=("probes",))),
    "puma_ballbar": ("puma560", dict(n_poses=60, levels=("distances",), n_balls=1)),
}
for name, spec in cases.items():
    if spec is None:
        import os
        ds = load_dataset("datasets/puma560-paper") if os.path.isdir("datasets/puma560-paper") else None
        if ds is None:
            continue
        from fgcal import dataset_model
        model = dataset_model(ds)
    else:
        model = load_model(spec[0])
        ds, _ = simulate(model, np.random.default_rng(11), SimulationSettings(**spec[1]))
    for mode in ("declared", "estimated"):
        r = calibrate(ds, model, CalibrationOptions(noise=mode))
        res[f"{name}-{mode}-names"] = np.array(r.names)
        res[f"{name}-{mode}-est"] = r.estimate
        res[f"{name}-{mode}-cov"] = r.covariance
np.savez(out, **res)
print("saved", len(res), "arrays to", out)
if "--against" in sys.argv:
    a, b = np.load(sys.argv[sys.argv.index("--against") + 1]), np.load(out)
    for k in sorted(a.files):
        if k.endswith("-est"):
            case = k[:-4]
            if not np.array_equal(a[case + "-names"], b[case + "-names"]):
                print(f"{case}: different parameters")
                continue
            sig = np.sqrt(np.diag(a[case + "-cov"]))
            d_est = np.max(np.abs(a[k] - b[k]) / sig)
            d_cov = np.max(np.abs(a[case + "-cov"] - b[case + "-cov"]) / np.outer(sig, sig))
            print(f"{case:28s} max |d estimate| / sigma {d_est:.2e}   max |d covariance| / (sigma sigma) {d_cov:.2e}")
