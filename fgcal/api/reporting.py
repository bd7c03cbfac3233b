"""``fgcal.report``: the uncertainty report of a calibration (HTML, Markdown, PNG) and its tolerance verdict."""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fgcal.api.selection import as_result
from fgcal.errors import FgcalError

__all__ = ["REPORT_FILES", "Report", "report"]

log = logging.getLogger(__name__)

REPORT_FILES = ("report.html", "report.md")


@dataclass(frozen=True)
class Report:
    """What :func:`report` wrote, and its verdict.

    Attributes
    ----------
    path : Path
        ``report.html`` (``report.md`` and the PNG figures beside it).
    verdict : ToleranceVerdict or None
        Pass or fail at the verification poses, with a tolerance and a verification; else None.
    """

    path: Path
    verdict: Any = None

    @property
    def passed(self) -> bool | None:
        """True or False with a verdict, None without."""
        return None if self.verdict is None else bool(self.verdict.passed)


def report(result, out, verification=None, tolerance: float | None = None, *, force: bool = False,
           title: str | None = None) -> Report:
    """Write the report of ``result`` into the folder ``out``.

    Parameters
    ----------
    result : path or CalibrationResult
    out : path
        Output folder (created); a report already there is replaced only with ``force``.
    verification : path, mapping or Verification, optional
        From :func:`fgcal.verify` (or its ``verify.json``): the errors at held-out poses.
    tolerance : float, optional
        Position tolerance (mm) the verification poses are judged against; needs ``verification``.
    force : bool
        Replace a report already in ``out``.
    title : str, optional

    Returns
    -------
    Report
        ``report.passed`` is the verdict (None without a tolerance).
    """
    from fgcal.api.verification import verification_dict
    from fgcal.report.accuracy import tolerance_verdict
    from fgcal.report.document import write_report

    if tolerance is not None:
        if not tolerance > 0:
            raise FgcalError(f"--tolerance must be a positive length in mm, got {tolerance:g}")
        if verification is None:
            raise FgcalError("--tolerance needs a verification (--verify verify.json from fgcal verify): "
                             "without it there is nothing to judge")
    existing = [Path(out) / name for name in REPORT_FILES if (Path(out) / name).exists()]
    if existing and not force:
        raise FgcalError(f"{existing[0]}: already exists (use --force to replace it)")
    if not force:
        from fgcal.util.yamlio import must_be_new

        for page in REPORT_FILES:
            must_be_new(Path(out) / page)
    name = result if isinstance(result, str | Path) else "the result"
    result = as_result(result)
    ver = None if verification is None else verification_dict(verification)
    robot = (ver or {}).get("robot")
    if robot is not None and robot != result.model().name:
        raise FgcalError(f"{verification if isinstance(verification, str | Path) else 'the verification'}: a "
                         f"verification of a {robot} result, but {name} is a result for {result.model().name}")
    volume = None
    try:
        volume = result.model().volume
    except FgcalError:
        log.info("robot %s not found: the pose plot has no measuring volume", result.robot)
    path = write_report(result, out, ver, volume, tolerance=tolerance, title=title)
    verdict = tolerance_verdict(ver, tolerance) if tolerance is not None and ver is not None else None
    return Report(Path(path), verdict)
