"""``fgcal simulate``: :func:`fgcal.api.simulation.simulate` writing the dataset (options: ``build_parser``)."""
from __future__ import annotations

import logging
import sys
from pathlib import Path

from fgcal.api.simulation import simulate
from fgcal.cli.commands.checks import check_output_dir
from fgcal.cli.commands.common import call

log = logging.getLogger("fgcal")


def _cmd_simulate(args) -> int:
    check_output_dir(args.out, [args.truth, Path(args.robot)], option="OUT", must_be_new=True, force=args.force)
    ds = call(simulate, args.robot, poses=args.poses, seed=args.seed, plan=args.plan, cmm_sigma=args.cmm_sigma,
              joint_resolution=args.joint_resolution, repeatability=args.repeatability, outliers=args.outliers,
              outlier_size=args.outlier_size, balls=args.balls, probes_per_ball=args.probes_per_ball,
              levels=args.levels, length_sigma=args.length_sigma, angle_sigma=args.angle_sigma,
              base_length_sigma=args.base_length_sigma, base_angle_sigma=args.base_angle_sigma, chain=args.chain,
              reflector=args.reflector, truth=args.truth, out=args.out, force=args.force, notes_to=sys.stderr)
    counts = ", ".join(f"{len(getattr(ds, lv))} {lv}" for lv in ds.levels())
    print(f"wrote {args.out}: {ds.n_poses} poses ({args.plan} plan), {counts}; truth in truth.yaml")
    return 0
