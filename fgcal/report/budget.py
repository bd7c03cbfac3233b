"""The error budget at the verification poses, and the first verdict it gives.

What a calibrated model's error at other poses should be if the model were right: the parameters'
uncertainty (:func:`fgcal.report.accuracy.predicted_position_sigma`), the instrument's noise as
declared, and the joint readings' noise (their resolution and repeatability, as the calibration
used it) propagated through the kinematic Jacobian at those poses. The instrument's noise is the
declared one: an estimated "noise" absorbs what the model misses, and a budget of it would
explain every error away. An error well above the budget means that the model, not the noise,
limits the accuracy. No I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgcal.estimation.result import CalibrationResult

__all__ = ["BUDGET_FACTOR", "ErrorBudget", "budget_sentence", "error_budget"]

BUDGET_FACTOR = 2.0  # an RMS error above this multiple of the budget is not explained by it
POSITION_LEVELS = ("probes", "centres", "poses")  # variance components that are tool positions (mm)


@dataclass(frozen=True)
class ErrorBudget:
    """Expected RMS position error (mm, 3D) at the verification poses, by source.

    Attributes
    ----------
    parameters_mm : float or None
        From the parameters' covariance; None when it could not be computed.
    instrument_mm : float or None
        The instrument's declared noise of a position (sqrt(3) times its per-coordinate sigma).
    joints_mm : float or None
        The joint readings' noise through ``d(tool position)/d(joints)`` at the poses.
    """

    parameters_mm: float | None
    instrument_mm: float | None
    joints_mm: float | None

    @property
    def noise_mm(self) -> float:
        """The measurements' noise: instrument and joint readings together (mm)."""
        return float(np.hypot(self.instrument_mm or 0.0, self.joints_mm or 0.0))

    @property
    def total_mm(self) -> float:
        return float(np.hypot(self.parameters_mm or 0.0, self.noise_mm))


def instrument_noise(result: CalibrationResult) -> float | None:
    """The declared noise of a measured tool position (mm, 3D RMS): the finest position level's."""
    sig = [n.declared for k, n in result.noise.items() if k in POSITION_LEVELS and n.unit == "mm" and n.declared > 0]
    if not sig:  # a result without a noise table: its levels' sigmas
        sig = [s.sigma for k, s in result.levels.items() if k in POSITION_LEVELS and s.unit == "mm" and s.sigma]
    return float(min(sig) * np.sqrt(3)) if sig else None


def joint_readings_noise(result: CalibrationResult, joints) -> float | None:
    """The joint readings' noise as a tool position error (mm, RMS over the poses ``joints`` (K, n) internal).

    Each reading's sigma (the calibration's: declared, or estimated where the data allowed) times
    the tool position's Jacobian with respect to that joint.
    """
    n = result.noise.get("joints")
    if n is None or not n.used > 0 or joints is None or not len(joints):
        return None
    from fgcal.robots.kinematics import jacobians

    model = result.model()
    sigma = model.joints_to_internal(np.full((1, model.n_joints), float(n.used)))[0]  # deg (mm) -> rad (mm)
    Jq = jacobians(result.slot_vector(model), np.asarray(joints, dtype=float), chain=model.chain).pose_joints[:, :3, :]
    per_pose = np.sqrt(np.einsum("krj,j->k", Jq**2, sigma**2))
    return float(np.sqrt(np.mean(per_pose**2)))


def error_budget(result: CalibrationResult, joints, parameters_mm: float | None) -> ErrorBudget:
    """The budget at the verification poses ``joints`` (K, n; internal units, or None)."""
    return ErrorBudget(parameters_mm, instrument_noise(result), joint_readings_noise(result, joints))


def _mm(v, missing: str = "unknown") -> str:
    return missing if v is None else f"{v:.2g} mm"


def _has_map(result: CalibrationResult) -> bool:
    return bool((result.joint_errors or {}).get("map_terms"))


def budget_sentence(result: CalibrationResult, after_rms: float, budget: ErrorBudget) -> str:
    """The first verdict: whether the noise or the model limits the error ``after_rms`` (mm RMS)."""
    parts = (f"the parameters' uncertainty ({_mm(budget.parameters_mm)}), the instrument's declared noise "
             f"({_mm(budget.instrument_mm)}) and the joint readings' noise through the kinematics "
             f"({_mm(budget.joints_mm, 'none declared')})")
    total = budget.total_mm
    if total > 0 and after_rms > BUDGET_FACTOR * total:
        out = (f"The model, not the noise, limits the accuracy: the calibrated error ({after_rms:.2g} mm RMS) is "
               f"{after_rms / total:.2g} times what {parts} explain.")
        if _has_map(result):
            return out + (" The joint error map in this result does not capture it either (drift, temperature, "
                          "a changed set-up or load); more poses will not remove it.")
        return out + (" More poses will not remove it; a model beyond geometry may: calibrate with "
                      "--model compliance+map (gravity compliance and a per-joint error map, compared with the "
                      "simpler models by cross-validation).")
    if budget.parameters_mm is not None and budget.parameters_mm > budget.noise_mm:
        return (f"The parameters' uncertainty ({budget.parameters_mm:.2g} mm RMS at the verification poses) "
                f"dominates the measurements' noise ({budget.noise_mm:.2g} mm): more, or better spread, calibration "
                "poses (fgcal design) will lower the error.")
    return (f"The calibrated error ({after_rms:.2g} mm RMS) is what {parts} explain: it is near what these "
            "measurements can verify.")
