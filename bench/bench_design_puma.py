"""A designed PUMA 560 plan against random plans from the same candidates, scored by an independent simulator.

``fgcal design --robot puma560 --poses 12 --candidates 2000`` (its library function,
:func:`fgcal.api.planning.design`) picks 12 of 2000 random candidates; ``--random-sets`` random
12-pose sets are drawn from the same candidates. Each plan is probed on ``--truths`` simulated
robots by ``tests/probe_sim.py`` (plain 4x4 DH matrices, its own access rule and probe pattern,
the joint readings rounded to 0.01 deg afresh for each truth), calibrated by fgcal with its default
options, and scored by the RMS tool-point error at 300 new random poses of each truth (the
independent forward kinematics of the calibrated and the true parameters). The plan should beat the
25th percentile of the random plans' mean error over the same truths.

Measured 2026-12-02: seed 0 (40 random sets) plan 0.0367 mm against the random plans' 25th
percentile 0.0476 (median 0.0505; predicted 0.0388), the plan beating every random plan; seeds 1, 2, 3
(20 random sets): 0.0370, 0.0373, 0.0411 against 0.0489, 0.0507, 0.0493; ``--perturb all`` (seed 0):
0.0378 against 0.0467. The issue's 0.0434 against 0.0409 (another scorer) is not reproduced here.

Run: ``python bench/bench_design_puma.py [--truths 4] [--random-sets 40] [--seed 0] [--index pred]``
(about 1 s per calibration on one core: (1 + random sets) x truths calibrations).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))


def score(model, robot, robot_file, truth, q_plan_deg, q_new, rng, tmp: Path) -> float:
    """Probe ``truth`` at the plan, calibrate, and return the RMS tool-point error at ``q_new`` (mm)."""
    from probe_sim import position_rms, probe_dataset

    from fgcal.estimation.calibrate import calibrate
    from fgcal.io.dataset_io import load_dataset

    probe_dataset(tmp, robot, robot_file, truth, q_plan_deg, rng)
    result = calibrate(load_dataset(tmp), model)
    values = model.slots_to_file_units(result.slot_vector(model))
    estimate = dict(zip(model.slot_names, map(float, values), strict=True))
    return position_rms(truth, estimate, q_new)


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--truths", type=int, default=4)
    ap.add_argument("--random-sets", type=int, default=40)
    ap.add_argument("--poses", type=int, default=12)
    ap.add_argument("--candidates", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0, help="fgcal design --seed (the candidates)")
    ap.add_argument("--index", default=None, help="design criterion (default: fgcal design's)")
    ap.add_argument("--perturb", choices=("identifiable", "all"), default="identifiable",
                    help="which slots the truths perturb: the model's identifiable parameters (default), or all 37 "
                         "(the others are absorbed or left as an unmodelled error)")
    args = ap.parse_args()
    import logging

    logging.basicConfig(level=logging.ERROR)
    from probe_sim import perturbed, random_poses, read_robot

    from fgcal.api.planning import design
    from fgcal.robots.robot_file import builtin_robot_path, load_model
    from fgcal.studies.design import candidate_pool

    t0 = time.perf_counter()
    model = load_model("puma560")
    robot_file = builtin_robot_path("puma560")
    robot = read_robot(robot_file)
    plan = design("puma560", poses=args.poses, candidates=args.candidates, seed=args.seed, index=args.index)
    # the same candidates as fgcal design drew (its seed), for the random plans
    pool = np.degrees(candidate_pool(model, args.candidates, np.random.default_rng(args.seed)))
    assert np.allclose(pool[plan.design.chosen], plan.joints_deg), "the bench's pool is not the design's"
    print("\n".join(plan.lines))
    print(f"designed in {time.perf_counter() - t0:.1f} s")
    rng = np.random.default_rng([args.seed, 7])
    sets = [pool[rng.choice(len(pool), size=args.poses, replace=False)] for _ in range(args.random_sets)]
    names = model.identifiable_names() if args.perturb == "identifiable" else list(model.slot_names)
    plan_err, rand_err = [], np.zeros((args.random_sets, args.truths))
    with tempfile.TemporaryDirectory() as tmp:
        for t in range(args.truths):
            t1 = time.perf_counter()
            truth_rng = np.random.default_rng([args.seed, 100 + t])
            truth = perturbed(robot, names, truth_rng)
            q_new = random_poses(robot, truth, 300, truth_rng)
            plan_err.append(score(model, robot, robot_file, truth, plan.joints_deg, q_new, truth_rng, Path(tmp) / "p"))
            for k, q in enumerate(sets):
                rand_err[k, t] = score(model, robot, robot_file, truth, q, q_new, truth_rng, Path(tmp) / f"r{k}")
            q = np.percentile(rand_err[:, t], [25, 50])
            print(f"truth {t}: plan {plan_err[-1]:.4f} mm, random q25 {q[0]:.4f} median {q[1]:.4f} "
                  f"({time.perf_counter() - t1:.0f} s)", flush=True)
    mine, theirs = float(np.mean(plan_err)), rand_err.mean(axis=1)
    q25, q50, q75 = np.percentile(theirs, [25, 50, 75])
    print(f"mean over {args.truths} truths: plan {mine:.4f} mm; random plans q25 {q25:.4f}, median {q50:.4f}, "
          f"q75 {q75:.4f} mm; the plan beats {100 * np.mean(theirs > mine):.0f}% of the random plans: "
          f"{'beats' if mine < q25 else 'DOES NOT beat'} the 25th percentile (predicted {plan.values['pred']:.4f} mm)")


if __name__ == "__main__":
    main()
