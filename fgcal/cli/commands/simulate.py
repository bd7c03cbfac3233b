"""``fgcal simulate``: the command's body (its options are in :func:`fgcal.cli.build_parser`)."""
from __future__ import annotations

import logging
import os
import sys
from pathlib import Path

import numpy as np

from fgcal.cli.commands.checks import MAX_POSES, check_output_dir
from fgcal.errors import FgcalError

log = logging.getLogger("fgcal")


def _cmd_simulate(args) -> int:
    from fgcal.io.dataset_io import save_dataset
    from fgcal.measurements.dataset import Noise
    from fgcal.robots.deviations import Deviations
    from fgcal.robots.robot_file import load_model
    from fgcal.studies.simulate import SimulationSettings, simulate

    if args.cmm_sigma < 0 or args.joint_resolution < 0 or args.repeatability < 0:
        raise FgcalError("--cmm-sigma, --joint-resolution and --repeatability must not be negative")
    if not 0 <= args.outliers < 1:
        raise FgcalError("--outliers is a fraction of probe points, from 0 to below 1")
    if (args.poses or 0) > MAX_POSES or args.probes_per_ball > 1000:
        raise FgcalError(f"--poses at most {MAX_POSES} and --probes-per-ball at most 1000 (a dataset that large "
                         "would not fit in memory)")
    check_output_dir(args.out, [args.truth, Path(args.robot)], option="OUT", must_be_new=True, force=args.force)
    chain = None
    if args.chain:
        parts = args.chain.split(",")
        if len(parts) != 2 or not all(parts):
            raise FgcalError(f"--chain: expected BASE,TIP (URDF link names), got {args.chain!r}")
        chain = {"base": parts[0], "tip": parts[1]}
    model = load_model(args.robot, chain=chain)
    levels = args.levels
    if args.reflector is not None:
        from dataclasses import replace

        from fgcal.robots.model import Tooling

        model = replace(model, tooling=Tooling(0.0, {"R": _floats(args.reflector, 3, "--reflector")}))
        levels = levels or "centres"
    robot_ref = args.robot
    if Path(args.robot).suffix or "/" in args.robot:  # a file: name it relative to the dataset directory
        robot_ref = os.path.relpath(Path(args.robot).resolve(), Path(args.out).resolve())
    settings = SimulationSettings(
        n_poses=args.poses, plan=args.plan,
        noise=Noise(args.cmm_sigma, args.joint_resolution, args.repeatability),
        deviations=Deviations(args.length_sigma, args.angle_sigma, args.base_length_sigma, args.base_angle_sigma),
        n_balls=args.balls if args.balls is not None else min(3, len(model.tooling.balls) if model.tooling else 3),
        probes_per_ball=args.probes_per_ball, outlier_fraction=args.outliers,
        outlier_size=args.outlier_size, levels=tuple((levels or "probes").split(",")))
    truth = None
    if args.truth is not None:
        from fgcal.io.dataset_io import load_truth

        values, _ = load_truth(args.truth)
        missing = [n for n in model.slot_names if n not in values]
        if missing:
            raise FgcalError(f"{args.truth}: lacks {', '.join(missing[:5])}{' ...' if len(missing) > 5 else ''}")
        truth = model.slots_from_file_units(np.array([values[n] for n in model.slot_names]))
    ds, notes = simulate(model, np.random.default_rng(args.seed), settings, robot_ref=robot_ref, seed=args.seed,
                         truth=truth)
    ds.chain = chain
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    save_dataset(ds, args.out, overwrite=args.force)
    counts = ", ".join(f"{len(getattr(ds, lv))} {lv}" for lv in ds.levels())
    print(f"wrote {args.out}: {ds.n_poses} poses ({args.plan} plan), {counts}; truth in truth.yaml")
    return 0


def _floats(text: str, n: int, option: str) -> np.ndarray:
    try:
        values = np.array([float(v) for v in text.split(",")])
    except ValueError:
        values = np.zeros(0)
    if values.shape != (n,) or not np.all(np.isfinite(values)):
        raise FgcalError(f"{option}: expected {n} comma-separated numbers, got {text!r}")
    return values
