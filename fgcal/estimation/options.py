"""How to calibrate: the options of :func:`fgcal.estimation.calibrate.calibrate` and their defaults."""
from __future__ import annotations

from dataclasses import dataclass

from fgcal.estimation.joint_errors import JointErrorSpec
from fgcal.estimation.noise import NoiseMode, OutlierMode
from fgcal.robots.deviations import Deviations

__all__ = ["MIN_SIGMA", "TYPICAL_DEVIATIONS", "WEAK_PRIOR", "CalibrationOptions"]

# Weak prior: ten times the typical deviations of DESIGN.md (mm, deg).
WEAK_PRIOR = Deviations(length=5.0, angle=0.5, base_length=50.0, base_angle=5.0)
# The typical deviations of a real arm from its nominal (DESIGN.md): the prior of a parameter that is
# identifiable at the solution but was not at the nominal start.
TYPICAL_DEVIATIONS = Deviations()
MIN_SIGMA = 1e-6  # exact data (sigma 0) still has floating-point noise


@dataclass(frozen=True)
class CalibrationOptions:
    """How to calibrate.

    Attributes
    ----------
    levels : tuple of str or None
        Measurement levels to use (``probes``, ``centres``, ``poses``); all present by default.
    robust : {None, "huber", "cauchy"}
        Robust loss on the measurement factors; ``robust_k`` its threshold in sigmas.
    prior : {"none", "weak"}
        ``weak``: a prior of ten times the typical deviation on every parameter
        (:data:`WEAK_PRIOR`), which keeps an ill-posed solve finite.
    joint_noise : bool
        Model the joint readings' rounding and repeatability with joint variables.
    kinematic_sigma : float
        Unmodelled error (mm) between a ball-centre variable and the forward kinematics.
    noise : NoiseMode
        ``estimated`` (default): each level's noise (joint readings included) is estimated from the
        residuals where the redundancy allows, and the covariance is at that noise; ``declared``:
        dataset.yaml's values only.
    outliers : OutlierMode
        ``exclude`` (default): gross errors are found by data snooping, excluded and named.
    estimate_noise : bool
        Kept for old callers: True forces ``noise="estimated"``.
    engine : {"batch", "gtsam"}
        ``batch``: fgcal's Levenberg-Marquardt with one batched Schur complement per step;
        ``gtsam``: GTSAM's own Levenberg-Marquardt on :func:`to_gtsam` (slower: every custom
        factor is a Python callback). The covariance is computed the same way for both.
    extra, exclude : tuple of str
        Slots to add to, or remove from, the identifiable parameters.
    noise_scale : dict or None
        Fixed factors on each level's declared noise (``{"poses": 12.0}``), for example the
        ones a previous ``estimate_noise`` run found.
    joint_errors : JointErrorSpec or None
        A block of non-geometric joint errors (compliance, error map) estimated with the geometry
        (:mod:`fgcal.estimation.joint_errors`); ``None``: the geometric model.
    """

    levels: tuple | None = None
    robust: str | None = None
    robust_k: float | None = None
    prior: str = "none"
    joint_noise: bool = True
    kinematic_sigma: float = 1e-4
    noise: NoiseMode = NoiseMode.ESTIMATED
    outliers: OutlierMode = OutlierMode.EXCLUDE
    estimate_noise: bool = False
    extra: tuple = ()
    exclude: tuple = ()
    max_iterations: int = 100
    tolerance: float = 1e-12
    noise_scale: dict | None = None
    joint_errors: JointErrorSpec | None = None
    engine: str = "batch"
