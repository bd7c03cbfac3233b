"""Where the bundled data files (robot models, sample datasets) live."""
from __future__ import annotations

import os
from pathlib import Path

__all__ = ["datasets_dir", "builtin_robot_path", "builtin_robot_names", "default_dataset_dir"]


def datasets_dir() -> Path:
    """The ``datasets/`` folder of the checkout (or ``$FGCAL_DATASETS`` when set)."""
    env = os.environ.get("FGCAL_DATASETS")
    return Path(env) if env else Path(__file__).resolve().parent.parent / "datasets"


def builtin_robot_names() -> list[str]:
    return sorted(p.stem for p in (datasets_dir() / "robots").glob("*.yaml"))


def builtin_robot_path(name: str) -> Path:
    return datasets_dir() / "robots" / f"{name}.yaml"


def default_dataset_dir() -> Path:
    """The bundled default dataset: a simulated PUMA 560 measured as in the paper."""
    return datasets_dir() / "puma560-paper"
