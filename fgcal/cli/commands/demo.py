"""``fgcal demo``: the main job on the bundled dataset, through the library functions the commands call."""
from __future__ import annotations

import logging
import tempfile
from pathlib import Path

from fgcal.api.calibration import calibrate, calibration_summary
from fgcal.api.checking import check
from fgcal.api.reporting import report
from fgcal.api.verification import verification_summary, verify
from fgcal.cli.commands.checks import check_output_dir
from fgcal.cli.commands.common import call

log = logging.getLogger("fgcal")

DEMO_TOLERANCE_MM = 0.2  # the verdict the demo shows: every verification pose within 0.2 mm


def _cmd_demo(args) -> int:
    """The paper's experiment on the bundled dataset: identify on 24 poses, verify on the other 24, judge."""
    from fgcal.util.resources import default_dataset_dir

    ds_dir = default_dataset_dir()
    if args.out is None:  # never into the working tree unasked
        out = Path(tempfile.mkdtemp(prefix="fgcal-demo-"))
    else:
        out = check_output_dir(args.out, [ds_dir])
        taken = [out / n for n in ("result.json", "verify.json", "report") if (out / n).exists()]
        if taken and not args.force:
            from fgcal.errors import FgcalError

            raise FgcalError(f"{taken[0]}: already exists (use --force to replace it)")
        out.mkdir(parents=True, exist_ok=True)
    print(f"fgcal demo: {ds_dir} (a simulated PUMA 560, the paper's 48-pose plan); results in {out}/")
    print("\n== check: what the poses can identify")
    print("\n".join(call(check, ds_dir).lines))
    print("\n== calibrate on the odd poses: one factor graph from raw probe points")
    result = call(calibrate, ds_dir, poses="odd")
    result.save(out / "result.json")
    print("\n".join(calibration_summary(result)))
    print("\n== verify on the even poses (the paper's VERIFY)")
    verification = call(verify, out / "result.json", ds_dir, poses="even")
    verification.save(out / "verify.json")
    print("\n".join(verification_summary(verification)))
    print(f"\n== the uncertainty report, judged against a {DEMO_TOLERANCE_MM:g} mm tolerance")
    written = report(out / "result.json", out / "report", verification, tolerance=DEMO_TOLERANCE_MM,
                     force=args.force)
    print(f"wrote {written.path} (and report.md, figures as PNG)")
    print(written.verdict.sentence())
    return 0 if written.passed else 1
