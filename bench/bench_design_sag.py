"""Design from a dataset of a robot with an error no geometric model has, the plan measured anew (issue 24).

A PUMA 560 whose shoulder and elbow sag and whose wrist wobbles (``tests/probe_sim.py``'s
``droop_deg``, 0.02 deg gain; plain DH forward kinematics, ball centres at 0.01 mm, joints rounded
to 0.01 deg afresh at every measurement) is measured at 150 random poses; ``fgcal design --dataset``
(its library function) picks 12 of them, with each pose weighed by the misfit its nearest poses
predict (:mod:`fgcal.studies.design_floor`) and without (``plain``, every pose alike). Each plan and
nine random 12-pose sets are calibrated on the recorded measurements of their poses ("same") and on a
second measurement of the same poses ("anew": what a user who measures the plan gets), and scored by
the RMS tool-point error at 100 new poses of the true, sagging robot.

Measured 2026-12-02 (seeds 0-7): anew, the plan beats the median random set on 7 of 8 seeds
(plain: 5 of 8); on the same measurements 5 of 8 (plain 3 of 8).

Run: ``python bench/bench_design_sag.py [--seeds 0 1 2 3 4 5 6 7]`` (about 25 s of CPU per seed).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(8)))
    ap.add_argument("--gain", type=float, default=0.02, help="the sag's size (deg)")
    ap.add_argument("--random-sets", type=int, default=9)
    args = ap.parse_args()
    import logging

    logging.basicConfig(level=logging.ERROR)
    from probe_sim import centre_dataset, droop_deg, fk_from_truth, perturbed, random_poses, read_robot

    from fgcal.estimation.calibrate import calibrate
    from fgcal.io.dataset_io import load_dataset
    from fgcal.robots.robot_file import builtin_robot_path, load_model
    from fgcal.studies.design_dataset import dataset_noise, design_from_dataset

    model = load_model("puma560")
    robot_file = builtin_robot_path("puma560")
    robot = read_robot(robot_file)

    def sag(a):
        return droop_deg(a, args.gain)

    wins = {"plan same": 0, "plan anew": 0, "plain same": 0, "plain anew": 0}
    print(f"{'seed':>4} {'plan same':>10} {'plan anew':>10} {'plain same':>11} {'plain anew':>11} "
          f"{'rand same':>10} {'rand anew':>10}   (RMS mm at 100 new poses; random: median)")
    for seed in args.seeds:
        rng = np.random.default_rng(seed)
        truth = perturbed(robot, model.identifiable_names(), rng)
        q, q_held = random_poses(robot, truth, 150, rng), random_poses(robot, truth, 100, rng)
        true_points = np.array([fk_from_truth(truth, p + sag(p)[0])[:3, 3] for p in q_held])
        with tempfile.TemporaryDirectory() as tmp:
            for name in ("ds", "again"):
                centre_dataset(Path(tmp) / name, robot, robot_file, truth, q, rng, unmodelled=sag)
            ds, again = load_dataset(Path(tmp) / "ds"), load_dataset(Path(tmp) / "again")

        def rms(data, ids):
            x = model.slots_to_file_units(calibrate(data.select(ids), model).slot_vector(model))
            est = dict(zip(model.slot_names, map(float, x), strict=True))
            d = np.array([fk_from_truth(est, p)[:3, 3] for p in q_held]) - true_points
            return float(np.sqrt(np.mean(np.sum(d**2, axis=1))))

        noise = dataset_noise(ds, model)
        row = {}
        for name, weigh in (("plan", True), ("plain", False)):
            ids = design_from_dataset(ds, model, 12, noise=noise, random_sets=1, misfit_weights=weigh).pose_ids
            row[f"{name} same"], row[f"{name} anew"] = rms(ds, ids), rms(again, ids)
        rr = np.random.default_rng([seed, 1])
        sets = [rr.choice(ds.pose_ids, 12, replace=False) for _ in range(args.random_sets)]
        med = {"same": np.median([rms(ds, s) for s in sets]), "anew": np.median([rms(again, s) for s in sets])}
        for k in wins:
            wins[k] += row[k] < med[k.split()[1]]
        print(f"{seed:>4} {row['plan same']:10.4f} {row['plan anew']:10.4f} {row['plain same']:11.4f} "
              f"{row['plain anew']:11.4f} {med['same']:10.4f} {med['anew']:10.4f}", flush=True)
    n = len(args.seeds)
    print("beats the median random set: " + ", ".join(f"{k} {v} of {n}" for k, v in wins.items())
          + " (plan: each pose weighed by its predicted misfit; plain: every pose alike)")


if __name__ == "__main__":
    main()
