"""GTSAM factors of fgcal's measurement model.

:mod:`factors.errors` holds the pure, vectorised error functions with analytic Jacobians (used
directly by fgcal's batched solver); :mod:`factors.gtsam_factors` wraps each as a GTSAM factor:

* probe point on the sphere around a ball-centre variable,
* one pose's balls (its probe points and ball centres) in one factor (:mod:`factors.pose_balls`),
* ball centre (variable or measured) at the forward kinematics times the ball's offset,
* measured tool pose against the forward kinematics,
* a ballbar length from the world origin (its pivot) to a tool ball,
* joint readings as priors on joint variables, and a prior on the parameters;
* :func:`~factors.gtsam_factors.kinematic_factor`: any error of (theta, q) with its Jacobians as a factor
  (fgcal's measurement types build theirs with it).
"""
from .errors import (
    ball_centre_error,
    distance_error,
    joint_error,
    pose_ball_centres_error,
    pose_error,
    probe_error,
    slots_of,
)

_POSE_BALLS_NAMES = ("PoseBallRows", "pose_balls_factor")
_GTSAM_NAMES = ("PoseKinematics", "ball_centre_factor", "ball_centres_factor", "centre_key", "distance_factor", "joint_key", "joint_prior",
                "kinematic_factor", "noise_model", "parameter_prior", "pose_centres_factor", "pose_factor",
                "pose_probes_factor", "probe_factor", "probes_factor", "theta_key")


def __getattr__(name):
    # The GTSAM wrappers load gtsam (~1 s): only when one of them is first used.
    if name in _GTSAM_NAMES:
        from . import gtsam_factors

        return getattr(gtsam_factors, name)
    if name in _POSE_BALLS_NAMES:
        from . import pose_balls

        return getattr(pose_balls, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "PoseBallRows",
    "PoseKinematics",
    "ball_centre_error",
    "ball_centre_factor",
    "ball_centres_factor",
    "centre_key",
    "distance_error",
    "distance_factor",
    "joint_error",
    "joint_key",
    "joint_prior",
    "kinematic_factor",
    "noise_model",
    "parameter_prior",
    "pose_ball_centres_error",
    "pose_balls_factor",
    "pose_centres_factor",
    "pose_error",
    "pose_factor",
    "pose_probes_factor",
    "probe_error",
    "probe_factor",
    "probes_factor",
    "slots_of",
    "theta_key",
]
