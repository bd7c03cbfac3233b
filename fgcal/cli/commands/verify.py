"""``fgcal verify``: :func:`fgcal.api.verification.verify`, printed and written (options: ``build_parser``)."""
from __future__ import annotations

import logging

from fgcal.api.verification import verification_summary, verify
from fgcal.cli.commands.checks import check_output_file, dataset_inputs
from fgcal.cli.commands.common import call

log = logging.getLogger("fgcal")


def _cmd_verify(args) -> int:
    if args.out:
        check_output_file(args.out, [args.result, *dataset_inputs(args.dataset)], force=args.force)
    report = call(verify, args.result, args.dataset, poses=args.poses)
    print("\n".join(verification_summary(report)))
    if args.out:
        report.save(args.out)
        print(f"wrote {args.out}")
    return 0
