"""fgcal: robot arm geometry calibration as a probabilistic factor graph.

Calibrate, verify and report in five lines::

    import fgcal
    result = fgcal.calibrate(fgcal.default_dataset_dir(), poses="odd")
    verification = fgcal.verify(result, fgcal.default_dataset_dir(), poses="even")
    written = fgcal.report(result, "my-report", verification, tolerance=0.2, force=True)
    print(written.verdict.sentence())

Every command of the ``fgcal`` command line is a function here with the same checks, defaults
and notes (:mod:`fgcal.api`): :func:`calibrate`, :func:`verify`, :func:`report`, :func:`check`,
:func:`simulate`, :func:`design`, :func:`compensate`, :func:`export`, :func:`export_urdf`. The names
are loaded when first used: ``import fgcal`` imports neither GTSAM nor matplotlib.
"""
from __future__ import annotations

import importlib
import types
from typing import Any

import fgcal.report as _report_package
from fgcal._version import __version__ as __version__

_NAMES = {
    # the commands' functions (fgcal.api)
    "calibrate": "fgcal.api.calibration", "calibration_summary": "fgcal.api.calibration", "check": "fgcal.api.checking",
    "CheckReport": "fgcal.api.checking", "verify": "fgcal.api.verification",
    "verification_summary": "fgcal.api.verification",
    "load_verification": "fgcal.api.verification", "Report": "fgcal.api.reporting",
    "simulate": "fgcal.api.simulation", "design": "fgcal.api.planning", "Plan": "fgcal.api.planning",
    "compensate": "fgcal.api.compensation", "Commands": "fgcal.api.compensation", "export": "fgcal.api.exporting",
    "export_urdf": "fgcal.api.exporting", "export_model": "fgcal.api.exporting", "export_deltas": "fgcal.api.exporting",
    "FgcalWarning": "fgcal.api.notes", "FgcalNote": "fgcal.api.notes",
    # the objects they take and return
    "CalibrationResult": "fgcal.estimation.result", "load_result": "fgcal.estimation.result",
    "save_result": "fgcal.estimation.result", "Verification": "fgcal.estimation.verification",
    "Dataset": "fgcal.measurements.dataset", "Noise": "fgcal.measurements.dataset",
    "load_dataset": "fgcal.io.dataset_io", "save_dataset": "fgcal.io.dataset_io",
    "dataset_model": "fgcal.io.dataset_io",
    "FgcalError": "fgcal.errors", "DatasetError": "fgcal.errors", "ModelError": "fgcal.errors",
    "ParameterSet": "fgcal.robots.model", "RobotModel": "fgcal.robots.model", "load_model": "fgcal.robots.robot_file",
    "save_model": "fgcal.robots.robot_file", "Deviations": "fgcal.robots.deviations",
    "SimulationSettings": "fgcal.studies.simulate", "default_dataset_dir": "fgcal.util.resources",
}

__all__ = sorted([*_NAMES, "__version__", "report"])


class _CallableReport(types.ModuleType):
    """``fgcal.report`` is the package of the report modules and, called, :func:`fgcal.api.reporting.report`.

    The name belongs to both: the import system sets ``fgcal.report`` to the package whenever one
    of its modules is imported, so the package itself is made callable rather than shadowed.
    """

    def __call__(self, result, out, verification=None, tolerance=None, **kwargs):
        """``fgcal.report(result, out, verification=None, tolerance=None, *, force=False, title=None)``:
        see :func:`fgcal.api.reporting.report`."""
        from fgcal.api.reporting import report

        return report(result, out, verification, tolerance, **kwargs)


_report_package.__class__ = _CallableReport
report = _report_package


def __getattr__(name: str) -> Any:
    """Load a public name on first use (PEP 562), so that ``import fgcal`` stays light."""
    module = _NAMES.get(name)
    if module is None:
        raise AttributeError(f"module 'fgcal' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__
