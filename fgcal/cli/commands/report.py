"""``fgcal report``: :func:`fgcal.api.reporting.report` and its verdict printed (options: ``build_parser``)."""
from __future__ import annotations

import logging

from fgcal.api.reporting import report
from fgcal.cli.commands.checks import check_output_dir

log = logging.getLogger("fgcal")


def _cmd_report(args) -> int:
    check_output_dir(args.out, [args.result, args.verify])
    written = report(args.result, args.out, verification=args.verify, tolerance=args.tolerance, force=args.force)
    print(f"wrote {written.path} (and report.md, figures as PNG) in {args.out}")
    if written.verdict is not None:
        print(written.verdict.sentence())
        return 0 if written.passed else 1
    return 0
