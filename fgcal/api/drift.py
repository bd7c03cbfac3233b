"""``fgcal online --model``: following a drifting robot, one pose ahead (:mod:`fgcal.online.drift`)."""
from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from fgcal.errors import FgcalError
from fgcal.estimation.joint_errors import JointErrorSpec, ModelKind, compliance_joints
from fgcal.online.drift import DRIFT_SCALES, NOISE_FACTORS, DriftLevels, choose_drift, follow_drift
from fgcal.online.drift_result import DriftResult, summary

__all__ = ["BASE_DRIFT", "follow"]

log = logging.getLogger(__name__)

# The drift per pose the automatic choice scales (DRIFT_SCALES, the geometry's and the block's apart):
# a micrometre and 0.36 arc-seconds of geometry, 1 µrad of each map coefficient, 0.1 µrad/Nm of each compliance.
BASE_DRIFT = DriftLevels(length_mm=1e-3, angle_deg=1e-4, map_urad=1.0, compliance_urad_per_nm=0.1)


def _spec(ds, robot, model: str, harmonics: int, map_sigma_urad: float, joint_errors) -> JointErrorSpec | None:
    """The joint-error block: that of a result file (``joint_errors``), else compliances of the
    joints whose gravity torque varies over these poses and ``harmonics`` map terms per joint."""
    kind = ModelKind(model)
    if kind is ModelKind.GEOMETRIC:
        return None
    if isinstance(joint_errors, JointErrorSpec):
        return joint_errors if kind is ModelKind.COMPLIANCE_MAP else JointErrorSpec(joint_errors.compliance,
                                                                                    payload=joint_errors.payload)
    if joint_errors is not None:
        from fgcal.estimation.result import load_result

        res = load_result(joint_errors) if isinstance(joint_errors, str | Path) else joint_errors
        info = getattr(res, "joint_errors", None) or {}
        if not info.get("spec"):
            raise FgcalError(f"{joint_errors}: the result has no joint-error block (calibrate it with --model)")
        spec = JointErrorSpec.from_dict(info["spec"])
        return spec if kind is ModelKind.COMPLIANCE_MAP else JointErrorSpec(spec.compliance, payload=spec.payload)
    from fgcal.robots.gravity import gravity_torques, model_inertials

    inertials = model_inertials(robot)
    if inertials is None:
        raise FgcalError(f"robot model {robot.name}: --model {model} needs its links' masses and centres of mass "
                         "(an 'inertials:' block in the model file)")
    q = robot.joints_to_internal(ds.joints_deg)
    revolute = np.asarray(robot.joint_is_angle, dtype=bool)
    joints = tuple(j for j in compliance_joints(gravity_torques(robot.nominal, q, inertials, chain=robot.chain))
                   if revolute[j - 1])
    if kind is ModelKind.COMPLIANCE:
        return JointErrorSpec(compliance=joints)
    map_joints = () if revolute.all() else tuple(int(j) + 1 for j in np.nonzero(revolute)[0])
    return JointErrorSpec(compliance=joints, harmonics=harmonics, map_joints=map_joints,
                          map_sigma=map_sigma_urad * 1e-6)


def follow(dataset, *, model: str = "compliance+map", harmonics: int = 30, map_sigma_urad: float = 300.0,
           joint_errors=None, drift: Sequence[float] | None = None, map_drift_urad: float | None = None,
           train: float = 0.6, noise_factor: float | None = None, baseline=None, robot=None) -> DriftResult:
    """Follow the robot of ``dataset`` through its poses in file (time) order, one pose ahead.

    Each pose is predicted from the state after the poses before it (geometry and joint-error
    block, each a random walk), then taken. The drift and the noise factor are chosen by the
    one-step-ahead likelihood of the first ``train`` share of the poses unless given; the
    summary covers the poses after them.

    Parameters
    ----------
    dataset : path or Dataset
        Tool poses (``poses.csv``) or ball centres (``centres.csv``).
    model : {"geometric", "compliance", "compliance+map"}
    harmonics : int
        Map harmonics per joint (``compliance+map`` without ``joint_errors``).
    map_sigma_urad : float
        Prior standard deviation of each map coefficient (µrad).
    joint_errors : path, CalibrationResult or JointErrorSpec, optional
        A result of ``fgcal calibrate --model`` (its block: compliances, harmonics, prior), or a block.
    drift : (mm, deg), optional
        Random-walk step per pose of the geometry; with ``map_drift_urad`` (µrad per pose of each
        map coefficient; compliances 0.1 of it in µrad/Nm). Chosen on the training poses when None.
    train : float
        Share of the poses (the first) the drift is chosen on, in (0, 1); the summary is of the rest.
    noise_factor : float, optional
        The declared noise's variance factor; chosen with the drift when None.
    baseline : path or CalibrationResult, optional
        A batch result: its errors at the same later poses are stored beside (``extra["baseline"]``).
    robot : RobotModel, optional
        The robot (default: the dataset's, from its files).

    Returns
    -------
    DriftResult
    """
    from fgcal.io.dataset_io import dataset_model, load_dataset

    if model not in [k.value for k in ModelKind]:
        raise FgcalError(f"--model {model!r}: one of {', '.join(k.value for k in ModelKind)}")
    if not 0.0 < train < 1.0:
        raise FgcalError(f"--train {train!r}: a share of the poses between 0 and 1 (exclusive)")
    ds = load_dataset(dataset) if isinstance(dataset, str | Path) else dataset
    robot = dataset_model(ds) if robot is None else robot
    spec = _spec(ds, robot, model, harmonics, map_sigma_urad, joint_errors)
    n = ds.n_poses
    n_train = int(train * n)
    if n_train < 4 or n - n_train < 1:
        raise FgcalError(f"{ds.path or 'dataset'}: {n} poses: --train {train} leaves {n_train} to choose the drift "
                         "on (at least 4) and the rest to follow")
    choice: list = []
    if drift is None:
        base = BASE_DRIFT if map_drift_urad is None else DriftLevels(
            BASE_DRIFT.length_mm, BASE_DRIFT.angle_deg, map_drift_urad, 0.1 * map_drift_urad)
        noise = NOISE_FACTORS if noise_factor is None else (noise_factor,)
        levels, noise_factor, choice = choose_drift(ds, robot, spec, n_train, base, DRIFT_SCALES, noise)
    else:
        mm, deg = drift
        map_urad = 0.0 if map_drift_urad is None else map_drift_urad
        levels = DriftLevels(mm, deg, map_urad, 0.1 * map_urad)
        if noise_factor is None:
            _, noise_factor, choice = choose_drift(ds, robot, spec, n_train, levels, (1.0,), NOISE_FACTORS)
    f = follow_drift(ds, robot, spec, levels, noise_factor)
    result = DriftResult.of(f, model, spec.to_dict() if spec is not None else {}, n_train, choice,
                            str(ds.path) if ds.path else None)
    result.extra["noise_factor"] = float(noise_factor)
    if baseline is not None:
        result.extra["baseline"] = _baseline(baseline, ds, robot, [s.pose for s in result.steps[n_train:]])
    return result


def _baseline(baseline, ds, robot, poses) -> dict:
    """A batch result's position errors (mm) at ``poses``: ``{"summary", "errors", "result"}``."""
    from fgcal.estimation.result import load_result
    from fgcal.estimation.verification import verify

    res = load_result(baseline) if isinstance(baseline, str | Path) else baseline
    v = verify(res, ds.select(np.array(poses, dtype=int)), robot)
    errors = [float(e) for e in v.after.position_mm]
    return {"summary": summary(errors), "errors": errors, "result": str(baseline) if isinstance(baseline, str | Path)
            else None}
