"""``fgcal design``: :func:`fgcal.api.planning.design`, its plan written (options: ``build_parser``)."""
from __future__ import annotations

import logging
from pathlib import Path

from fgcal.api.planning import design, progress_printer
from fgcal.cli.commands.checks import check_output_file, dataset_inputs
from fgcal.cli.commands.common import call

log = logging.getLogger("fgcal")


def _cmd_design(args) -> int:
    if args.dataset is not None:
        from fgcal.io.dataset_io import load_dataset

        ds = load_dataset(args.dataset)
        files = [Path(args.candidates)] if args.candidates is not None and not args.candidates.isdigit() else []
        check_output_file(args.out, [*dataset_inputs(args.dataset, ds.robot), *files], force=args.force)
        plan = call(design, dataset=ds, poses=args.poses, candidates=args.candidates, index=args.index,
                    seed=args.seed, noise=args.noise, per_placement=args.per_placement, progress=progress_printer())
        plan.save(args.out)
        print("\n".join(plan.lines))
        print(f"wrote {args.out} (pose ids of the candidates)")
        return 0
    check_output_file(args.out, [Path(args.robot)], force=args.force)
    plan = call(design, args.robot, poses=args.poses, candidates=args.candidates, index=args.index, level=args.level,
                seed=args.seed, cmm_sigma=args.cmm_sigma, joint_resolution=args.joint_resolution,
                repeatability=args.repeatability, progress=progress_printer())
    plan.save(args.out)
    lines = list(plan.lines)
    lines[0] += f"; wrote {args.out}"
    print("\n".join(lines))
    return 0
