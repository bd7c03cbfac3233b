"""The library functions of the commands: one typed function per command, the command line a thin layer over them.

``fgcal calibrate`` is :func:`calibrate` plus ``result.save(out)`` and a printed summary;
``fgcal verify`` is :func:`verify`; ``fgcal report`` is :func:`report`; and so on. Each function
takes paths or loaded objects, checks its input as the command does, issues the command's
warnings and notes as :class:`FgcalWarning` / :class:`FgcalNote` (Python warnings), and has the
command's defaults (the command reads them from the signature).
"""
from __future__ import annotations

from fgcal.api.calibration import calibrate, calibration_summary
from fgcal.api.checking import CheckReport, check
from fgcal.api.compensation import compensate
from fgcal.api.detecting import Detection, detect
from fgcal.api.exporting import export, export_deltas, export_model, export_urdf
from fgcal.api.notes import FgcalNote, FgcalWarning
from fgcal.api.planning import design
from fgcal.api.reporting import Report, report
from fgcal.api.simulation import simulate
from fgcal.api.verification import load_verification, verification_summary, verify

__all__ = ["CheckReport", "Detection", "FgcalNote", "FgcalWarning", "Report", "calibrate", "calibration_summary",
           "check", "compensate", "design", "detect", "export", "export_deltas", "export_model", "export_urdf", "load_verification",
           "report", "simulate", "verification_summary", "verify"]
