"""Before the solve: the rows a measurement type refuses (a camera's corners behind it, at a
grazing angle or off the image: :meth:`fgcal.measurements.pixels.Pixels.admit`), named in the
result, and whether the poses give as many equations as there are parameters. No I/O here."""
from __future__ import annotations

import copy

import numpy as np

from fgcal.errors import FgcalError
from fgcal.measurements.dataset import Dataset
from fgcal.measurements.types import BY_LEVEL
from fgcal.robots.model import RobotModel

__all__ = ["admit_rows", "check_equations"]


def admit_rows(ds: Dataset, model: RobotModel, levels) -> tuple[Dataset, list]:
    """``ds`` without the rows its types refuse at the nominal geometry, and the refused rows
    (``{"level", "pose", ..., "reason"}``); ``ds`` itself when nothing is refused."""
    refused: list = []
    for lv in levels:
        kind = BY_LEVEL.get(lv)
        obs = getattr(ds, lv, None)
        if kind is None or obs is None or not hasattr(kind, "admit"):
            continue
        q = model.joints_to_internal(ds.joints_deg[ds.row_of(obs.pose)])
        keep, out = kind.admit(obs, model.forward(model.nominal, q))
        if out:
            ds = copy.copy(ds)
            setattr(ds, lv, obs.subset(keep))
            refused += [{"level": lv, **r} for r in out]
    return ds, refused


def check_equations(ds: Dataset, levels, n_parameters: int) -> None:
    """Refuse a dataset whose poses give fewer equations than there are parameters."""
    pose_ids = np.asarray(ds.pose_ids)
    order = np.argsort(pose_ids)

    def rows(obs_pose):  # the dataset row of each observation's pose (-1: not a pose of ds)
        k = np.minimum(np.searchsorted(pose_ids[order], obs_pose), len(order) - 1)
        return np.where(pose_ids[order][k] == obs_pose, order[k], -1)

    full = np.zeros(len(pose_ids), dtype=bool)
    dof = 0
    ball_rows, ball_names = [], []  # (pose row, ball) of each ball-placing observation
    for lv in levels:
        obs = getattr(ds, lv)
        r = rows(np.asarray(obs.pose))
        width = BY_LEVEL[lv].width if lv in BY_LEVEL else 3  # a probed ball places a point
        if width >= 6:
            full[r[r >= 0]] = True
        elif width == 3:
            ball_rows.append(r[r >= 0])
            ball_names.append(np.asarray(obs.ball).astype(str)[r >= 0])
        else:
            dof += width * int(np.sum(r >= 0))
    balls = np.zeros(len(pose_ids), dtype=int)  # distinct balls per pose
    if ball_rows:
        names, ball = np.unique(np.concatenate(ball_names), return_inverse=True)
        k = max(len(names), 1)
        pairs = np.unique(np.concatenate(ball_rows) * k + ball.ravel())
        balls = np.bincount(pairs // k, minlength=len(pose_ids))
    # Degrees of freedom per pose: full pose 6, three balls or more 6, two balls 5, one ball 3.
    dof += int(np.sum(np.where(full, 6, np.array([0, 3, 5, 6])[np.minimum(balls, 3)])))
    if dof < n_parameters:
        raise FgcalError(f"{ds.path or 'dataset'}: {ds.n_poses} poses give {dof} equations but the "
                         f"{n_parameters} parameters need at least {n_parameters} "
                         f"(at least {int(np.ceil(n_parameters / 6))} full poses; more to average the noise)")
