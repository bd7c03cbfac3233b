"""Plausibility checks of a dataset against its robot: values that look like a unit mistake.

A file in degrees that holds radians, or millimetres that hold metres, reads without a format
error and calibrates to nonsense. These checks name such cases; they do not refuse the data
(a robot may legitimately move little). No I/O here.
"""
from __future__ import annotations

import numpy as np

from fgcal.measurements.dataset import Dataset

__all__ = ["unit_warnings", "unused_poses"]

TWO_PI = 2 * np.pi


def unit_warnings(ds: Dataset, model) -> list[str]:
    """Sentences naming values of ``ds`` that look like a unit mistake for ``model``."""
    out = []
    where = ds.path if ds.path is not None else "dataset"
    q = np.asarray(ds.joints_deg, dtype=float)
    angle = np.asarray(getattr(model, "joint_is_angle", np.ones(q.shape[1] if q.ndim == 2 else 0, bool)), bool)
    if q.size and len(q) >= 3 and q.shape[1] == len(angle) and angle.any():
        qa = q[:, angle]
        span = np.abs(qa).max()
        reach = np.abs(np.degrees(np.asarray(model.joint_limits, dtype=float)[angle])).max()
        if span <= TWO_PI + 1e-9 and np.ptp(qa, axis=0).max() > 0 and reach > 4 * TWO_PI:
            out.append(f"{where}/joints.csv: every joint reading lies within +-{TWO_PI:.4g} although the joint "
                       f"limits reach +-{reach:.0f} deg: the readings look like radians (the file holds degrees)")
    measured = []
    for level in ("probes", "centres", "poses"):
        obs = getattr(ds, level)
        if obs is not None and len(obs):
            measured.append((level, np.linalg.norm(obs.xyz, axis=1)))
    if measured and q.size:
        try:
            T = model.forward(model.nominal, model.joints_to_internal(q[: min(len(q), 200)]))
            nominal = float(np.median(np.linalg.norm(T[:, :3, 3], axis=1)))
        except Exception:
            return out
        for level, norms in measured:
            typical = float(np.median(norms))
            if nominal > 100 and typical < nominal / 50:
                out.append(f"{where}/{level}.csv: positions are {typical:.3g} from the origin (median) where the "
                           f"robot's tool is {nominal:.0f} mm away: they look like metres (the file holds mm)")
            elif nominal > 0 and typical > 1000 * max(nominal, 1.0):
                out.append(f"{where}/{level}.csv: positions are {typical:.3g} mm from the origin (median), far "
                           f"beyond the robot's reach ({nominal:.0f} mm): a unit mistake?")
    return out


def unused_poses(ds: Dataset, used_ids, levels) -> list[str]:
    """Sentences naming the poses of ``ds`` not in ``used_ids``, with the reason."""
    used = set(np.asarray(used_ids).tolist())
    missing = [int(p) for p in ds.pose_ids if int(p) not in used]
    if not missing:
        return []
    shown = ", ".join(map(str, missing[:20])) + (f" ... ({len(missing)} in all)" if len(missing) > 20 else "")
    return [f"{len(missing)} of {ds.n_poses} poses not used, no measurement at levels {', '.join(levels)}: "
            f"pose(s) {shown}"]
