"""The result of following a drifting robot (:mod:`fgcal.online.drift`): the one-step-ahead error
series, its summary, the chosen drift and the final state; a JSON file (``fgcal-drift/1``)."""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fgcal.errors import FgcalError
from fgcal.online.drift import DriftFilter, DriftLevels, DriftStep

__all__ = ["DRIFT_FORMAT", "DriftResult", "load_drift_result", "save_drift_result", "summary"]

DRIFT_FORMAT = "fgcal-drift/1"


def summary(errors) -> dict:
    """``{"n", "mean", "rms", "max"}`` of errors (mm); zeros and n 0 for none."""
    e = np.asarray(errors, dtype=float)
    if not e.size:
        return {"n": 0, "mean": 0.0, "rms": 0.0, "max": 0.0}
    return {"n": int(e.size), "mean": float(e.mean()), "rms": float(np.sqrt(np.mean(e**2))), "max": float(e.max())}


@dataclass
class DriftResult:
    """Following a session's drift.

    Attributes
    ----------
    robot : str
    model : str
        ``geometric``, ``compliance`` or ``compliance+map``.
    spec : dict
        The joint-error block (:meth:`fgcal.estimation.joint_errors.JointErrorSpec.to_dict`), empty
        for geometry alone.
    levels : DriftLevels
        The drift per pose used.
    noise_factors : dict of str to float
        The measurement-noise factors (variance, per component) at the end.
    train : int
        The poses (the first, in order) the drift was chosen on; 0 when it was given.
    choice : list of dict
        The candidates tried (:func:`fgcal.online.drift.choose_drift`), training poses only.
    steps : list of DriftStep
        Per pose in order: its one-step-ahead prediction error, then whether it was taken.
    names : list of str
    estimate, sigma : ndarray (S,)
        The final state and its standard deviations (mm, deg, µrad, µrad/Nm).
    dataset : str or None
    """

    robot: str
    model: str
    spec: dict
    levels: DriftLevels
    noise_factors: dict
    train: int
    choice: list
    steps: list
    names: list
    estimate: np.ndarray
    sigma: np.ndarray
    dataset: str | None = None
    extra: dict = field(default_factory=dict)

    @classmethod
    def of(cls, f: DriftFilter, model: str, spec: dict, train: int = 0, choice=(), dataset=None) -> DriftResult:
        names, est, sig = f.estimate()
        return cls(f.model.name, model, dict(spec), f.levels, f.factors(), int(train), list(choice),
                   list(f.steps), names, est, sig, dataset)

    def errors(self, after: int = 0) -> np.ndarray:
        """One-step-ahead position errors (mm) of the poses from index ``after`` on."""
        return np.array([s.error_mm for s in self.steps[after:]], dtype=float)

    def summary(self, after: int | None = None) -> dict:
        """The one-step-ahead error's summary after the training poses (``after``: default
        :attr:`train`), with the poses not taken."""
        k = self.train if after is None else after
        out = summary(self.errors(k))
        out["not_taken"] = [s.pose for s in self.steps[k:] if not s.taken]
        return out

    def to_dict(self) -> dict:
        return {"format": DRIFT_FORMAT, "robot": self.robot, "model": self.model, "spec": self.spec,
                "levels": self.levels.to_dict(), "noise_factors": {k: float(v) for k, v in self.noise_factors.items()},
                "train": self.train, "choice": self.choice, "summary": self.summary(),
                "steps": [{"pose": s.pose, "error_mm": s.error_mm, "sigma_mm": s.sigma_mm, "loglik": s.loglik,
                           "nis": s.nis, "rows": s.rows, "taken": s.taken} for s in self.steps],
                "parameters": [{"name": n, "estimate": float(v), "sigma": float(s)}
                               for n, v, s in zip(self.names, self.estimate, self.sigma)],
                "dataset": self.dataset, "extra": self.extra}

    @classmethod
    def from_dict(cls, d: dict, where: str = "drift result") -> DriftResult:
        if not isinstance(d, dict) or d.get("format") != DRIFT_FORMAT:
            raise FgcalError(f"{where}: not an {DRIFT_FORMAT} file")
        try:
            steps = [DriftStep(int(s["pose"]), float(s["error_mm"]), float(s["sigma_mm"]), float(s["loglik"]),
                               float(s["nis"]), int(s["rows"]), bool(s["taken"])) for s in d["steps"]]
            params = d["parameters"]
            out = cls(str(d["robot"]), str(d["model"]), dict(d.get("spec") or {}), DriftLevels.from_dict(d["levels"]),
                      {str(k): float(v) for k, v in d["noise_factors"].items()}, int(d["train"]),
                      list(d.get("choice") or []), steps, [str(p["name"]) for p in params],
                      np.array([float(p["estimate"]) for p in params]), np.array([float(p["sigma"]) for p in params]),
                      d.get("dataset"), dict(d.get("extra") or {}))
        except (KeyError, TypeError, ValueError) as exc:
            raise FgcalError(f"{where}: malformed {DRIFT_FORMAT} file ({type(exc).__name__}: {exc})") from None
        bad = [s.pose for s in steps if not (math.isfinite(s.error_mm) and s.error_mm >= 0)]
        if bad:
            raise FgcalError(f"{where}: pose {bad[0]}: error_mm must be a finite non-negative number")
        if not 0 <= out.train <= len(steps):
            raise FgcalError(f"{where}: train {out.train} is not between 0 and the {len(steps)} steps")
        return out


def save_drift_result(result: DriftResult, path) -> None:
    """Write ``result`` as JSON, atomically."""
    from fgcal.util.yamlio import atomic_write_text

    atomic_write_text(Path(path), json.dumps(result.to_dict(), indent=1) + "\n")


def load_drift_result(path) -> DriftResult:
    """Read a file of :func:`save_drift_result`; a one-line :class:`FgcalError` naming it when it is not one."""
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except OSError as exc:
        raise FgcalError(f"{path}: cannot read ({exc.strerror})") from None
    except ValueError as exc:
        raise FgcalError(f"{path}: not JSON ({exc})") from None
    return DriftResult.from_dict(d, str(path))
