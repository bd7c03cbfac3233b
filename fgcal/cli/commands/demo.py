"""``fgcal demo``: the command's body (its options are in :func:`fgcal.cli.build_parser`)."""
from __future__ import annotations

import argparse
import logging

from fgcal.cli.commands.calibrate import _cmd_calibrate
from fgcal.cli.commands.check import _cmd_check
from fgcal.cli.commands.checks import check_output_dir
from fgcal.cli.commands.report import _cmd_report
from fgcal.cli.commands.verify import _cmd_verify

log = logging.getLogger("fgcal")


def _cmd_demo(args) -> int:
    """The paper's experiment on the bundled dataset: identify on 24 poses, verify on the other 24."""
    from fgcal.util.resources import default_dataset_dir

    ds_dir = default_dataset_dir()
    out = check_output_dir(args.out, [ds_dir])
    out.mkdir(parents=True, exist_ok=True)
    print(f"fgcal demo: {ds_dir} (a simulated PUMA 560, the paper's 48-pose plan); results in {out}/")
    print("\n== check: what the poses can identify")
    _cmd_check(argparse.Namespace(dataset=ds_dir))
    print("\n== calibrate on the odd poses: one factor graph from raw probe points")
    _cmd_calibrate(argparse.Namespace(dataset=ds_dir, out=out / "result.json", poses="odd", levels=None, robust=None,
                                      prior="none", exact_joints=False, noise="estimated", outliers="exclude", extra=None,
                                      exclude=None))
    print("\n== verify on the even poses (the paper's VERIFY)")
    _cmd_verify(argparse.Namespace(result=out / "result.json", dataset=ds_dir, poses="even", out=out / "verify.json"))
    print("\n== the uncertainty report")
    return _cmd_report(argparse.Namespace(result=out / "result.json", verify=out / "verify.json", out=out / "report"))
