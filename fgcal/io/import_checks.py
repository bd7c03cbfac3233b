"""Is an imported table plausible for the robot it names? The fit of the nominal base and tool, judged.

A nominal arm, its base and tool fitted to the measurements, misses them by millimetres (its real
geometry differs from the nominal by that much) and by a fraction of a degree. A misfit of
centimetres or degrees is a mistake of the import, not of the robot: a length unit (metres read as
millimetres, inches), a joint unit (radians read as degrees), an Euler convention or a quaternion
order. Each has a signature in the data that :func:`check_fit` looks for, so that the refusal says
which option to change. No I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgcal.robots.model import RobotModel
from fgcal.robots.transforms import so3_log

__all__ = ["MAX_POSITION_RMS_MM", "MAX_REACH_FRACTION", "MAX_ROTATION_RMS_DEG", "FitCheck", "check_fit"]

MAX_POSITION_RMS_MM = 20.0  # a nominal arm misses by a few mm: 20 mm is a mistake at any size ...
MAX_REACH_FRACTION = 0.02  # ... or 2% of the measured workspace's extent, where that is larger
MAX_ROTATION_RMS_DEG = 2.0  # a nominal arm's orientation is off by tenths of a degree
_UNIT_RATIOS = {1000.0: "metres read as millimetres: add --length-unit m",
                0.001: "millimetres read as metres: use --length-unit mm",
                25.4: "inches read as millimetres: convert the positions to mm",
                1 / 25.4: "millimetres read as inches"}


@dataclass(frozen=True)
class FitCheck:
    """The nominal model's fit to imported measurements, and what looks wrong about it.

    Attributes
    ----------
    position_rms_mm : float
        RMS distance (mm) of the fitted model's tool points from the measured ones.
    rotation_rms_deg : float or None
        RMS angle (deg) between fitted and measured tool orientations (None for points).
    position_limit_mm : float
        The misfit beyond which the import is refused (mm).
    problems : tuple of str
        One sentence per finding, each naming the option that would fix it; empty when plausible.
    """

    position_rms_mm: float
    rotation_rms_deg: float | None
    position_limit_mm: float
    problems: tuple[str, ...]

    @property
    def ok(self) -> bool:
        return not self.problems


def _spread(points: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((points - points.mean(axis=0)) ** 2, axis=1))))


def check_fit(model: RobotModel, slots, q, xyz_mm, R=None) -> FitCheck:
    """Judge the fit of ``model`` with slot vector ``slots`` (S,) (base and tool fitted).

    Parameters
    ----------
    q : array_like, shape (N, n)
        Joint readings as imported (rad; mm for prismatic joints).
    xyz_mm : array_like, shape (N, 3)
        Measured positions as imported (mm).
    R : array_like, shape (N, 3, 3), optional
        Measured orientations, for pose data.
    """
    q = np.asarray(q, dtype=float)
    xyz = np.asarray(xyz_mm, dtype=float).reshape(-1, 3)
    T = model.forward(np.asarray(slots, dtype=float), q)
    if R is None:  # a point: the tool frame sits at it with the flange's orientation
        T = T @ np.linalg.inv(model.tool_offset_matrix)
    predicted = T[:, :3, 3]
    rms = float(np.sqrt(np.mean(np.sum((predicted - xyz) ** 2, axis=1))))
    rot = None
    if R is not None:
        angles = np.linalg.norm(so3_log(T[:, :3, :3] @ np.swapaxes(np.asarray(R, dtype=float), 1, 2)), axis=1)
        rot = float(np.degrees(np.sqrt(np.mean(angles**2))))
    limit = max(MAX_POSITION_RMS_MM, MAX_REACH_FRACTION * 2.0 * _spread(predicted))
    problems = []
    if rms > limit:
        problems.append(f"the nominal {model.name} misses the measured positions by {rms:.4g} mm RMS after its base "
                        f"and tool are fitted (a nominal arm: a few mm; the limit {limit:.3g} mm)")
        problems += _causes(model, q, xyz, predicted)
    if rot is not None and rot > MAX_ROTATION_RMS_DEG:
        problems.append(f"the measured orientations misfit by {rot:.3g} deg RMS (a nominal arm: tenths of a degree; "
                        f"the limit {MAX_ROTATION_RMS_DEG:g} deg): check --euler-convention, --quaternion-order "
                        "and --rotation-unit")
    return FitCheck(rms, rot, limit, tuple(problems))


def _causes(model: RobotModel, q, xyz, predicted) -> list[str]:
    """The signatures of the usual mistakes behind a large position misfit."""
    out = []
    measured, modelled = _spread(xyz), _spread(predicted)
    if measured > 0 and modelled > 0:
        ratio = measured / modelled
        for unit_ratio, cause in _UNIT_RATIOS.items():
            if abs(np.log(ratio / unit_ratio)) < np.log(1.5):
                out.append(f"the measured points spread {measured:.4g} mm, the robot's {modelled:.4g} mm "
                           f"({ratio:.3g} times): {cause}")
    revolute = model.joint_is_angle
    if revolute.any():
        span = np.ptp(q[:, revolute], axis=0).max()
        if span < np.radians(12.0):
            out.append(f"the revolute joints move over {np.degrees(span):.3g} deg at most: radians read as degrees? "
                       "(--joint-unit rad)")
        elif np.abs(q[:, revolute]).max() > 4 * np.pi:
            out.append(f"a revolute joint reads {np.abs(q[:, revolute]).max():.4g} rad: degrees read as radians? "
                       "(--joint-unit deg)")
    return out
