"""``fgcal report``: the command's body (its options are in :func:`fgcal.cli.build_parser`)."""
from __future__ import annotations

import logging

from fgcal.cli.commands.checks import check_output_dir
from fgcal.errors import FgcalError

log = logging.getLogger("fgcal")


def _cmd_report(args) -> int:
    import json

    from fgcal.estimation.result import load_result
    from fgcal.report.document import write_report
    from fgcal.util.yamlio import read_text_file

    check_output_dir(args.out, [args.result, args.verify])
    result = load_result(args.result)
    verification = None
    if args.verify is not None:
        text = read_text_file(args.verify, max_bytes=256 * 1024 * 1024)
        try:
            verification = json.loads(text)
        except json.JSONDecodeError as exc:
            raise FgcalError(f"{args.verify}: not a verification file (invalid JSON: {exc.msg}, "
                             f"line {getattr(exc, 'lineno', '?')})") from None
        from fgcal.estimation.verification import check_verification

        check_verification(verification, args.verify)
        robot = verification.get("robot")
        if robot is not None and robot != result.model().name:
            raise FgcalError(f"{args.verify}: a verification of a {robot} result, but {args.result} is a "
                             f"result for {result.model().name}")
    volume = None
    try:
        volume = result.model().volume
    except FgcalError:
        log.info("robot %s not found: the pose plot has no measuring volume", result.robot)
    tolerance = getattr(args, "tolerance", None)
    if tolerance is not None and not tolerance > 0:
        raise FgcalError(f"--tolerance must be a positive length in mm, got {tolerance:g}")
    path = write_report(result, args.out, verification, volume, tolerance=tolerance)
    print(f"wrote {path} (and report.md, figures as PNG) in {args.out}")
    if tolerance is not None and verification is not None:
        from fgcal.report.accuracy import tolerance_verdict
        tv = tolerance_verdict(verification, tolerance)
        print(tv.sentence())
        return 0 if tv.passed else 1
    return 0
