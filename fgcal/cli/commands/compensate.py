"""``fgcal compensate``: :func:`fgcal.api.compensation.compensate`, written or printed (options: ``build_parser``)."""
from __future__ import annotations

import logging
import sys

import numpy as np

from fgcal.api.compensation import compensate
from fgcal.cli.commands.checks import check_output_file
from fgcal.cli.commands.common import call
from fgcal.util.numbers import format_number

PARTIAL = 3  # exit status of compensate when some targets were not reachable

log = logging.getLogger("fgcal")


def _cmd_compensate(args) -> int:
    if args.out:
        check_output_file(args.out, [args.result, args.targets], force=args.force)
    commands = call(compensate, args.result, args.targets, frame=args.frame, tcp=args.tcp, branch=args.branch,
                    max_change=args.max_change, seed_joints=getattr(args, "seed_joints", None), notes_to=sys.stderr)
    c, ok, ids = commands.solution, commands.reachable, commands.ids
    rows = commands.rows()
    if args.out:
        commands.save(args.out)
        if ok.any():
            angle = ("positions only, the orientation kept at the seed's" if commands.position_only else
                     f"{np.nanmax(c.orientation_error_deg):.2g} deg")
            print(f"wrote {args.out}: {len(rows)} of {len(ids)} joint commands; the calibrated model reaches them "
                  f"within {np.nanmax(c.position_error_mm):.2g} mm and {angle}, "
                  f"every joint within {np.nanmax(c.joint_change_deg):.2g} deg of its seed (same configuration)")
        else:
            print(f"wrote {args.out}: no target was reachable")
    else:
        print(",".join(commands.columns))
        for r in rows:
            print(",".join([str(r[0])] + [format_number(v) for v in r[1:]]))
    for p, why in zip(ids, commands.reasons, strict=True):
        if why:
            print(f"{args.targets}: pose {p}: not written: {why}", file=sys.stderr)
    if not ok.all():
        print(f"{int((~ok).sum())} of {len(ids)} targets not reachable (exit status {PARTIAL})", file=sys.stderr)
        return PARTIAL
    return 0
