"""``fgcal design``: the command's body (its options are in :func:`fgcal.cli.build_parser`)."""
from __future__ import annotations

import logging
import sys
from pathlib import Path

import numpy as np

from fgcal.cli.commands.checks import MAX_POSES, check_output_file, dataset_inputs
from fgcal.errors import FgcalError

log = logging.getLogger("fgcal")


def _progress(every: float = 2.0):
    """A progress reporter for long runs: a line on standard error at most every ``every`` s."""
    import time

    t0 = time.perf_counter()
    last = [t0]

    def say(text: str) -> None:
        now = time.perf_counter()
        if now - last[0] >= every:
            print(f"design: {text} ({now - t0:.0f} s)", file=sys.stderr, flush=True)
            last[0] = now
    return say


def _cmd_design_dataset(args) -> int:
    from fgcal.io.dataset_io import dataset_model, load_dataset
    from fgcal.studies.design_dataset import DATASET_INDEX, design_from_dataset, load_plan, save_plan

    ds = load_dataset(args.dataset)
    candidates = None
    if args.candidates is not None:
        if args.candidates.isdigit():
            raise FgcalError("with --dataset, --candidates is a joints.csv-like file (pose,q1..q6 deg), "
                             f"not a count: {args.candidates}")
        candidates = load_plan(Path(args.candidates))
    check_output_file(args.out, [*dataset_inputs(args.dataset, ds.robot)]
                      + ([Path(args.candidates)] if candidates is not None else []))
    plan = design_from_dataset(ds, dataset_model(ds), args.poses, candidates, index=args.index or DATASET_INDEX,
                               rng=np.random.default_rng(args.seed), progress=_progress(), noise=args.noise,
                               per_placement=getattr(args, "per_placement", False))
    save_plan(plan, args.out)
    print("\n".join(plan.summary()))
    print(f"wrote {args.out} (pose ids of the candidates)")
    return 0


def _cmd_design(args) -> int:
    from fgcal.io.dataset_io import joint_columns, write_csv
    from fgcal.measurements.dataset import Noise
    from fgcal.robots.robot_file import load_model
    from fgcal.studies.design import INDICES, Candidates, candidate_pool, design_plan, random_design_values
    from fgcal.studies.design_info import layout_from_access
    from fgcal.studies.plans import random_plan

    if args.dataset is not None:
        return _cmd_design_dataset(args)
    if args.poses < 5:
        raise FgcalError("--poses must be at least 5 (30 parameters, 6 equations per pose)")
    if args.candidates is not None and not args.candidates.isdigit():
        raise FgcalError(f"--candidates {args.candidates}: a file of candidate poses needs --dataset (for the "
                         "robot, tool, measurement type and noise); without it, give a number of random poses")
    n_candidates = 2000 if args.candidates is None else int(args.candidates)
    if not 1 <= n_candidates <= MAX_POSES:
        raise FgcalError(f"--candidates: from 1 to {MAX_POSES} random poses")
    check_output_file(args.out, [Path(args.robot)])
    model = load_model(args.robot)
    if model.tooling is None:
        raise FgcalError(f"robot model {model.name} has no tooling (balls) to plan for")
    rng = np.random.default_rng(args.seed)
    noise = Noise(args.cmm_sigma, args.joint_resolution, args.repeatability)
    levels = (args.level,)
    pool = candidate_pool(model, n_candidates, rng, levels=levels)
    q_verify = pool if model.volume is None else random_plan(
        model, model.nominal, 1000, rng, model.tooling, model.volume, min(3, len(model.tooling.balls)))
    prepared = Candidates.build(model, pool, noise, q_verify, layout=layout_from_access(model, pool, levels))
    d = design_plan(model, args.poses, pool, noise, index=args.index or "pred", prepared=prepared,
                    progress=_progress())
    write_csv(args.out, joint_columns(model.n_joints),
              [[i + 1, *map(float, model.joints_to_file_units(q))] for i, q in enumerate(d.q)])
    random_pred = [random_design_values(prepared, args.poses, np.random.default_rng([args.seed, k]))[1]["pred"]
                   for k in range(200)]
    print(f"designed {args.poses} poses from {len(pool)} candidates by {d.index} ({d.iterations} DETMAX steps); "
          f"wrote {args.out}")
    print("  " + ", ".join(f"{k} {d.values[k]:.4g}" for k in INDICES if k != "pred"))
    print(f"  predicted position error RMS at new poses: {d.values['pred']:.4g} mm "
          f"(random {args.poses}-pose sets from the same candidates: median {np.median(random_pred):.4g}, "
          f"quartiles {np.percentile(random_pred, 25):.4g}-{np.percentile(random_pred, 75):.4g} mm)")
    if prepared.dropped:
        print(f"  not identifiable from these candidates, not designed for: {', '.join(prepared.dropped)}")
    return 0
