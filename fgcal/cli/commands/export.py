"""``fgcal export``: :func:`fgcal.api.exporting.export` after the output checks (options: ``build_parser``)."""
from __future__ import annotations

import logging
from pathlib import Path

from fgcal.api.exporting import export
from fgcal.cli.commands.checks import check_output_file
from fgcal.cli.commands.common import call
from fgcal.errors import FgcalError

log = logging.getLogger("fgcal")


def _cmd_export(args) -> int:
    ur_file = getattr(args, "ur_kinematics", None)
    if args.model is None and args.urdf is None and args.deltas is None and ur_file is None:
        raise FgcalError("export: give --model FILE, --urdf FILE, --deltas FILE and/or --ur-kinematics FILE")
    if ur_file:
        check_output_file(ur_file, [args.result, args.model, args.urdf, args.deltas], option="--ur-kinematics",
                          force=args.force)
    if args.model:
        check_output_file(args.model, [args.result], option="--model", force=args.force)
    if args.urdf:
        check_output_file(args.urdf, [args.result, args.model], option="--urdf", force=args.force)
        if args.model and args.model.absolute() == args.urdf.absolute():
            raise FgcalError(f"--model and --urdf: both are {args.urdf}; give two files")
    if args.deltas:
        check_output_file(args.deltas, [args.result, args.model, args.urdf], option="--deltas", force=args.force)
    from fgcal.estimation.result import load_result

    if load_result(args.result).joint_errors.get("names"):  # the side table is an output too: checked first
        check_output_file(Path(str(args.urdf or args.model or args.deltas) + ".joint_errors.csv"),
                          [args.result, args.model, args.urdf, args.deltas], option="joint-error table",
                          force=args.force)
    for path, what in call(export, args.result, model=args.model, urdf=args.urdf, deltas=args.deltas,
                           ur_kinematics=ur_file, ur_hash=getattr(args, "ur_hash", None), force=args.force):
        print(f"wrote {path}{': ' if what.startswith('the ') else ' ('}{what}{'' if what.startswith('the ') else ')'}")
    return 0

