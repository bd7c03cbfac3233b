"""Is the calibration good enough? Accuracy statistics, per-pose flags, tolerance and predictions.

Pure functions of a :class:`~fgcal.estimation.result.CalibrationResult` and a verification summary (the dict
of ``verify.json``); the report (:mod:`fgcal.report.document`) writes them. Units: mm and deg. No I/O.

The statistics follow ISO 9283 in spirit: the standard's pose accuracy AP is the distance from the
commanded pose to the barycentre of repeated visits. A verification visits each pose once, so the
error at a pose is its AP, and over the poses we give the mean, standard deviation, 95th
percentile and maximum of that distance, and the mean error vector (the systematic part).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from fgcal.estimation.result import CalibrationResult

__all__ = [
    "OUTLIER_Z",
    "AccuracyStats",
    "HeldCost",
    "PoseFlags",
    "ToleranceVerdict",
    "accuracy_stats",
    "flag_poses",
    "held_parameter_cost",
    "predicted_position_sigma",
    "round_to_sigma",
    "tolerance_verdict",
    "verification_joints",
]

OUTLIER_Z = 3.5  # robust z-score (median, 1.4826 MAD) above which a pose's error is an outlier
MAD_TO_SIGMA = 1.4826


@dataclass
class AccuracyStats:
    """Position error statistics over poses (mm); ``bias_xyz`` is the mean error vector."""

    n: int
    mean: float
    std: float
    rms: float
    p95: float
    max: float
    bias_xyz: tuple[float, float, float] | None = None

    @property
    def bias(self) -> float | None:
        return None if self.bias_xyz is None else float(np.linalg.norm(self.bias_xyz))


def accuracy_stats(errors_mm, error_xyz_mm=None) -> AccuracyStats:
    """Statistics of position errors ``errors_mm`` (K,), and the bias of ``error_xyz_mm`` (K, 3)."""
    e = np.asarray(errors_mm, dtype=float)
    e = e[np.isfinite(e)]
    if not e.size:
        nan = float("nan")
        return AccuracyStats(0, nan, nan, nan, nan, nan)
    bias = None
    if error_xyz_mm is not None and len(error_xyz_mm):
        bx, by, bz = (float(v) for v in np.mean(np.asarray(error_xyz_mm, dtype=float), axis=0))
        bias = (bx, by, bz)
    return AccuracyStats(int(e.size), float(e.mean()), float(e.std(ddof=1)) if e.size > 1 else 0.0,
                         float(np.sqrt(np.mean(e**2))), float(np.percentile(e, 95)), float(e.max()), bias)


@dataclass
class PoseFlags:
    """One verification pose: its errors (mm) and what is wrong with it."""

    pose: int
    error_mm: float
    nominal_mm: float
    flags: list[str] = field(default_factory=list)


def flag_poses(verification: dict, tolerance_mm: float | None = None, outlier_z: float = OUTLIER_Z) -> list[PoseFlags]:
    """Every verification pose with its flags: beyond the tolerance, an outlier, worse than nominal.

    An outlier's calibrated error lies more than ``outlier_z`` robust standard deviations (1.4826
    times the median absolute deviation) above the median error.
    """
    poses = verification.get("poses") or []
    err = np.array([p["position_mm"] for p in poses], dtype=float)
    if not err.size:
        return []
    med = float(np.median(err))
    spread = MAD_TO_SIGMA * float(np.median(np.abs(err - med)))
    out = []
    for p, e in zip(poses, err):
        flags = []
        if tolerance_mm is not None and e > tolerance_mm:
            flags.append(f"beyond the tolerance ({tolerance_mm:g} mm)")
        if spread > 0 and (e - med) / spread > outlier_z:
            flags.append(f"outlier ({(e - med) / spread:.0f} robust sigma above the median)")
        if e > p["before_position_mm"]:
            flags.append("worse than the nominal model")
        out.append(PoseFlags(int(p["pose"]), float(e), float(p["before_position_mm"]), flags))
    return out


@dataclass
class ToleranceVerdict:
    """Pass or fail of the calibrated position error at the verification poses."""

    tolerance_mm: float
    passed: bool
    n_poses: int
    n_beyond: int
    max_mm: float
    p95_mm: float
    beyond: list[int] = field(default_factory=list)

    def sentence(self) -> str:
        if self.passed:
            return (f"PASS: the calibrated position error is within {self.tolerance_mm:g} mm at all {self.n_poses} "
                    f"verification poses (max {self.max_mm:.2g} mm, 95th percentile {self.p95_mm:.2g} mm).")
        named = ", ".join(str(p) for p in self.beyond[:12])
        if len(self.beyond) > 12:
            named += f" and {len(self.beyond) - 12} more"
        return (f"FAIL: {self.n_beyond} of {self.n_poses} verification poses are beyond {self.tolerance_mm:g} mm "
                f"(max {self.max_mm:.2g} mm, 95th percentile {self.p95_mm:.2g} mm), worst first: poses {named}.")


def tolerance_verdict(verification: dict, tolerance_mm: float) -> ToleranceVerdict:
    """Pass when every verification pose's calibrated position error is within ``tolerance_mm``."""
    poses = verification.get("poses") or []
    err = np.array([p["position_mm"] for p in poses], dtype=float)
    if not err.size:  # no per-pose list: judge by the summary's maximum
        mx = float(verification["position_mm"]["max"])
        return ToleranceVerdict(tolerance_mm, mx <= tolerance_mm, int(verification.get("n_poses", 0)),
                                int(mx > tolerance_mm), mx, float("nan"))
    order = np.argsort(-err)
    beyond = [int(poses[i]["pose"]) for i in order if err[i] > tolerance_mm]
    return ToleranceVerdict(tolerance_mm, not beyond, int(err.size), len(beyond), float(err.max()),
                            float(np.percentile(err, 95)), beyond)


def _position_jacobian(result: CalibrationResult, joints):
    """d(tool position)/d(slots) (K, 3, S) at ``joints`` (internal units), and the model's slot names."""
    from fgcal.robots.kinematics import jacobians

    model = result.model()
    J = jacobians(result.slot_vector(model), np.asarray(joints, dtype=float), chain=model.chain).pose_slots[:, :3, :]
    return J, list(model.slot_names)


def verification_joints(verification: dict | None) -> np.ndarray | None:
    """The joint readings (K, n) of a verification's poses in file units (deg; mm for prismatic joints),
    when ``verify.json`` has them; ``model.joints_to_internal`` turns them into joints."""
    poses = (verification or {}).get("poses") or []
    if not poses or any("joints_deg" not in p for p in poses):
        return None
    return np.array([p["joints_deg"] for p in poses], dtype=float)


def predicted_position_sigma(result: CalibrationResult, joints) -> np.ndarray:
    """Expected position error (mm, RMS length of the 3D error) from the parameters' covariance.

    ``sqrt(trace(J C J^T))`` at each of the poses ``joints`` (K, n; rad, mm), with ``J`` the tool
    position's Jacobian with respect to the identified parameters in file units.
    """
    J, names = _position_jacobian(result, joints)
    # The robot's own parameters: set-up unknowns (fixtures, stations) do not move the tool, and a
    # joint-error block's share is left out (its terms act on the joints, not on a slot).
    mine = [i for i, n in enumerate(result.names) if n in names]
    cols = [names.index(result.names[i]) for i in mine]
    scale = np.array([np.pi / 180 if result.parameters[i].unit == "deg" else 1.0 for i in mine])
    Jp = J[:, :, cols] * scale  # mm per file unit
    C = np.asarray(result.covariance, dtype=float)[np.ix_(mine, mine)]
    return np.sqrt(np.maximum(np.einsum("krp,krp->k", Jp @ C, Jp), 0.0))


@dataclass
class HeldCost:
    """What a parameter held at nominal leaves at the poses if it deviates by a typical amount."""

    name: str
    typical: float
    unit: str
    rms_mm: float
    max_mm: float

    def sentence(self) -> str:
        dev = f"a typical deviation of {self.name} ({self.typical:g} {self.unit})"
        if self.max_mm < 1e-3:
            return (f"{dev} costs nothing measurable: the identified parameters absorb it "
                    f"(at most {self.max_mm:.1g} mm).")
        return (f"{dev} would leave {self.rms_mm:.2g} mm RMS (max {self.max_mm:.2g} mm) that the identified "
                "parameters cannot absorb.")


def held_parameter_cost(result: CalibrationResult, joints) -> list[HeldCost]:
    """The error each held parameter leaves at ``joints`` (K, n; rad, mm) after the others are re-fitted.

    A held parameter's true value may differ from nominal by a typical manufacturing deviation
    (:class:`fgcal.robots.deviations.Deviations`). Its effect on the tool positions, minus the part a
    least-squares change of the identified parameters reproduces, is what calibration leaves.
    """
    from fgcal.robots.deviations import Deviations

    if not result.held:
        return []
    J, names = _position_jacobian(result, joints)
    k = J.shape[0]
    Ji = J[:, :, [names.index(n) for n in result.names if n in names]].reshape(3 * k, -1)
    out = []
    for h in result.held:
        n = h["name"]
        if n not in names or h.get("reason", "").startswith("the world frame"):
            continue  # the gauge (the world frame is the base's) costs nothing
        typical = float(Deviations().sigmas([n])[0])
        jh = J[:, :, names.index(n)].reshape(3 * k)
        if Ji.shape[1]:
            jh = jh - Ji @ np.linalg.lstsq(Ji, jh, rcond=None)[0]
        left = np.linalg.norm(jh.reshape(k, 3), axis=1) * typical
        is_angle = n.rsplit(".", 1)[1] in ("phi", "theta", "psi", "alpha", "beta")
        out.append(HeldCost(n, float(np.degrees(typical)) if is_angle else typical, "deg" if is_angle else "mm",
                            float(np.sqrt(np.mean(left**2))), float(left.max())))
    return out


def round_to_sigma(value: float, sigma: float | None, digits: int = 2) -> tuple[str, str]:
    """``value`` and ``sigma`` as text, ``sigma`` to ``digits`` significant digits, ``value`` to the same place.

    >>> round_to_sigma(431.80123, 0.01234)
    ('431.801', '0.012')
    """
    if sigma is None or not np.isfinite(sigma) or sigma <= 0:
        return f"{value:.6g}", "-"
    place = digits - 1 - math.floor(math.log10(sigma))  # decimals that keep `digits` of sigma
    if place > 0:
        v, s = f"{value:.{place}f}", f"{sigma:.{place}f}"
    else:
        q = 10.0 ** (-place)
        v, s = f"{round(value / q) * q:.0f}", f"{round(sigma / q) * q:.0f}"
    return (v[1:] if v.startswith("-") and not v.strip("-0.") else v), s
