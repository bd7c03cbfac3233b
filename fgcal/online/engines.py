"""Online calibration: the estimate and its uncertainty after every pose.

Two kinds of engine over the measurement model of the batch solve:

* :class:`ISAM2Engine`: the same GTSAM factors (``factors`` package); each pose adds its joint
  variables and factors, and iSAM2 updates incrementally (QR factorisation, per-variable
  relinearisation thresholds, the parameters' set loose so that their factors are relinearised
  only when the parameters have moved). Probed balls enter as their fitted centres with the
  fit's full covariance (to first order what the probe points say about the centre).
* :class:`KalmanEngine`: a filterpy filter whose state is the parameter vector (random-walk
  process model, drift zero by default). Each pose's measurement is its ball centres (fitted to
  the probe points with the quality checks of ``fgcal measure``, or measured) and/or its pose;
  the joint readings' noise is folded into the measurement noise. ``ekf`` is an iterated EKF
  (a plain EKF was seen to diverge from the nominal start), ``ukf`` an unscented filter.

Both start from the nominal model with the weak prior of :data:`fgcal.estimation.calibrate.WEAK_PRIOR`
(before five poses the parameters are not determined by the data). A pose that fails the
quality checks, or whose innovation is implausible, is rejected with the reason and leaves the
state untouched. No I/O here.
"""
from __future__ import annotations

from fgcal.errors import FgcalError
from fgcal.estimation.options import CalibrationOptions
from fgcal.measurements.dataset import Dataset
from fgcal.online.base import weak_prior
from fgcal.online.centres import prefit
from fgcal.online.isam2 import ISAM2Engine
from fgcal.online.kalman import KalmanEngine
from fgcal.online.measurement import NoiseTracker, UpdateReport
from fgcal.online.records import PoseData, pose_records, records_dataset
from fgcal.robots.model import RobotModel

__all__ = [
    "ISAM2Engine",
    "KalmanEngine",
    "NoiseTracker",
    "PoseData",
    "UpdateReport",
    "make_engine",
    "pose_records",
    "prefit",
    "records_dataset",
    "weak_prior",
]


def make_engine(kind: str, ds: Dataset, model: RobotModel, options=CalibrationOptions(), **kw):
    if kind == "isam2":
        return ISAM2Engine(ds, model, options, **kw)
    if kind in ("ekf", "ukf"):
        return KalmanEngine(ds, model, options, kind=kind, **kw)
    raise FgcalError(f"unknown engine {kind!r} (isam2, ekf, ukf)")
