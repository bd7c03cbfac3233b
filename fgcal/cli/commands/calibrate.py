"""``fgcal calibrate``: :func:`fgcal.api.calibration.calibrate`, saved and printed (options: ``build_parser``)."""
from __future__ import annotations

import logging

from fgcal.api.calibration import calibrate, calibration_summary
from fgcal.api.selection import parse_pose_selection
from fgcal.cli.commands.checks import check_output_file, dataset_inputs
from fgcal.cli.commands.common import call

__all__ = ["_cmd_calibrate", "calibrate_options", "parse_pose_selection"]

log = logging.getLogger("fgcal")


def calibrate_options(args) -> dict:
    """The keyword arguments of :func:`fgcal.api.calibration.calibrate` from the parsed options."""
    return {"poses": args.poses, "levels": args.levels, "robust": args.robust, "engine": args.engine,
            "prior": args.prior, "noise": args.noise, "outliers": args.outliers, "exact_joints": args.exact_joints,
            "extra": args.extra, "exclude": args.exclude, "model": args.model, "keep": args.keep,
            "verification": args.verification, "folds": args.folds, "max_harmonics": args.max_harmonics,
            "seed": args.seed, "fold_order": args.fold_order, "payload": args.payload}


def _cmd_calibrate(args) -> int:
    from fgcal.io.dataset_io import load_dataset

    paths = args.dataset if isinstance(args.dataset, list) else [args.dataset]
    for path in paths:
        check_output_file(args.out, dataset_inputs(path), force=args.force)
    loaded = [load_dataset(path) for path in paths]
    for path, one in zip(paths, loaded, strict=True):
        check_output_file(args.out, dataset_inputs(path, one.robot), force=args.force)
    result = call(calibrate, loaded if len(loaded) > 1 else loaded[0], **calibrate_options(args))
    result.save(args.out)
    print("\n".join(calibration_summary(result)))
    print(f"wrote {args.out}")
    return 0
