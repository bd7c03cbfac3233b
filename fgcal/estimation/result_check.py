"""One validation of a loaded calibration result, used by :func:`~fgcal.estimation.result.load_result`.

Every command that reads a result (``verify``, ``report``, ``export``, ``compensate``) reads it
through ``load_result``, so the checks here hold for all of them: finite values, finite
non-negative sigmas, a symmetric positive semi-definite covariance whose diagonal is the
sigmas squared, and parameter names that the result's robot model (with its set-up blocks and
joint-error blocks) has.
"""
from __future__ import annotations

import re

import numpy as np

from fgcal.errors import FgcalError
from fgcal.util.numbers import finite_number

__all__ = ["PSD_TOLERANCE", "validate_result"]

PSD_TOLERANCE = 1e-9  # smallest eigenvalue allowed, relative to the largest (round-off of a PSD matrix)
SIGMA_TOLERANCE = 1e-6  # relative agreement of a sigma with the square root of its covariance entry
_JOINT_ERROR = re.compile(r"^(?:j(\d+)\.compliance|map\.j(\d+)\.(?:sin|cos)(\d+))$")


def _is_setup_parameter(name: str, blocks: set) -> bool:
    """``KIND.NAME.COMPONENT`` of a built-in or registered block kind, or of a block the result's
    ``setup`` names (a kind registered by the user's code, which this process may not have)."""
    from fgcal.estimation.setup_params import is_setup_name

    block = name.partition(".")[2].rpartition(".")[0]
    return is_setup_name(name) or (bool(block) and block in blocks)


def _short(name) -> str:
    text = str(name)
    return text[:60] + ("..." if len(text) > 60 else "")


def _number(v) -> bool:
    return finite_number(v)


def _check_parameters(result) -> None:
    seen: set = set()
    for p in result.parameters:
        if not isinstance(p.name, str) or not p.name:
            raise FgcalError(f"parameter name {_short(p.name)!r}: must be text")
        if p.name in seen:
            raise FgcalError(f"parameter {_short(p.name)}: listed twice")
        seen.add(p.name)
        for field in ("nominal", "estimate"):
            if not _number(getattr(p, field)):
                raise FgcalError(f"parameter {_short(p.name)}: {field} {_short(getattr(p, field))!r} is not a "
                                 "finite number")
        if not _number(p.sigma) or p.sigma < 0:
            raise FgcalError(f"parameter {_short(p.name)}: sigma {_short(p.sigma)!r} is not a finite number >= 0")


def _check_covariance(result) -> None:
    cov = np.asarray(result.covariance, dtype=float)
    n = len(result.parameters)
    if cov.shape != (n, n):
        raise FgcalError(f"covariance: shape {cov.shape}, expected ({n}, {n}) for {n} parameters")
    if n == 0:
        return
    if not np.all(np.isfinite(cov)):
        raise FgcalError("covariance: not all entries are finite numbers")
    scale = float(np.max(np.abs(cov))) or 1.0
    if np.max(np.abs(cov - cov.T)) > 1e-9 * scale:
        raise FgcalError("covariance: not symmetric")
    diag = np.diag(cov)
    sigma = np.array([p.sigma for p in result.parameters], dtype=float)
    off = np.abs(np.sqrt(np.clip(diag, 0, None)) - sigma) > SIGMA_TOLERANCE * np.maximum(sigma, 1e-12) + 1e-12
    if np.any(off):
        k = int(np.flatnonzero(off)[0])
        raise FgcalError(f"parameter {_short(result.parameters[k].name)}: sigma {sigma[k]:.6g} disagrees with the "
                         f"covariance (its variance {diag[k]:.6g})")
    eig = np.linalg.eigvalsh((cov + cov.T) / 2)
    if eig[0] < -PSD_TOLERANCE * max(float(eig[-1]), 0.0) - 1e-300:
        raise FgcalError(f"covariance: not positive semi-definite (eigenvalue {eig[0]:.3g}, largest "
                         f"{eig[-1]:.3g})")


def _check_names(result) -> None:
    model = result.model()
    slots = set(model.slot_names) if result.robot_model else set(result.slots)
    n = model.n_joints
    blocks = set(((result.setup or {}).get("fixtures") or {}).keys()) if isinstance(result.setup, dict) else set()
    for p in result.parameters:
        name = p.name
        if name in slots or _is_setup_parameter(name, blocks):  # set-up names: checked with result.setup
            continue
        m = _JOINT_ERROR.match(name)
        if m and 1 <= int(m.group(1) or m.group(2)) <= n and (m.group(3) is None or int(m.group(3)) >= 1):
            continue
        raise FgcalError(f"parameter {_short(name)}: not a parameter of the robot model {_short(model.name)} "
                         f"({n} joints; slots like {', '.join(list(model.slot_names)[:3])}, ...)")
    for h in result.held:
        name = h.get("name") if isinstance(h, dict) else h
        if not isinstance(name, str):
            raise FgcalError(f"held: {_short(h)!r} is not a parameter name (or {{name: ..., value: ...}})")


def _check_levels(result) -> None:
    for key, lv in result.levels.items():
        for field in ("sigma", "rms"):
            v = getattr(lv, field)
            if v is not None and (not _number(v) or v < 0):  # None: a level without a sigma (a prior)
                raise FgcalError(f"levels.{_short(key)}.{field}: {_short(v)!r} is not a finite number >= 0")
    for key, nz in result.noise.items():
        for field in ("declared", "used", "estimated"):
            v = getattr(nz, field, None)
            if v is not None and (not _number(v) or v < 0):
                raise FgcalError(f"noise.{_short(key)}.{field}: {_short(v)!r} is not a finite number >= 0")
    if not isinstance(result.n_poses, int) or result.n_poses < 0:
        raise FgcalError(f"n_poses: {_short(result.n_poses)!r} is not a count")
    if result.n_poses == 0:  # only the prior: nothing was calibrated (an online run that took no pose)
        raise FgcalError("n_poses: 0, a result from no pose (only the prior) is not a calibration")


def validate_result(result) -> None:
    """Check a loaded result for values nothing downstream could use.

    Raises
    ------
    FgcalError
        One line naming the field or parameter and what is wrong (the caller adds the file).
    """
    _check_parameters(result)
    _check_covariance(result)
    _check_levels(result)
    _check_names(result)
