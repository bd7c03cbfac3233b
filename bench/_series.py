"""The real UR10 series the benches read (Landgraf et al. 2021, Series B): where it is, and its
split in time order. Imported by a bench run as ``python bench/NAME.py``."""
from __future__ import annotations

from pathlib import Path

import numpy as np


def default_series() -> Path | None:
    """Series B's measurement file in ``shared/data/landgraf-ur10`` beside a folder above this one, or None."""
    for p in Path(__file__).resolve().parents:
        f = p / "shared" / "data" / "landgraf-ur10" / "Series_B" / "measurements_joint_configurations.csv"
        if f.exists():
            return f
    return None


def time_split(series, calib, share: float = 0.6) -> tuple[np.ndarray, np.ndarray]:
    """Training and later pose ids of ``calib`` (pose id = line in the file: time order): the first
    ``share`` train; a goal repeated across the cut stays on the training side."""
    ids = np.sort(calib.pose_ids)
    cut = ids[int(share * len(ids))]
    groups = dict(zip(series.line, series.groups()))
    train_groups = {groups[p] for p in ids if p < cut}
    later = np.array([p for p in ids if p >= cut and groups[p] not in train_groups])
    train = np.array([p for p in ids if p not in set(later.tolist())])
    return train, later
