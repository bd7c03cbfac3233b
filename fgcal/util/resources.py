"""Where the bundled data files (robot models, sample datasets) live.

In the repository they are the top-level ``datasets/`` folder; an installed fgcal (a wheel,
``pip install .`` or a git URL) carries the same files as its package data ``fgcal/_data``
(``pyproject.toml`` maps one onto the other). ``$FGCAL_DATASETS`` overrides both. Nothing is
imported: the folder is only looked up on disk.
"""
from __future__ import annotations

import os
from pathlib import Path

__all__ = ["builtin_robot_names", "builtin_robot_path", "datasets_dir", "default_dataset_dir"]

_PACKAGE = Path(__file__).resolve().parents[1]  # the fgcal package folder


def datasets_dir() -> Path:
    """The bundled data folder.

    ``$FGCAL_DATASETS`` when set; else the package's ``_data`` folder of an installed fgcal; else
    the ``datasets/`` folder beside the package in a checkout (editable installs, ``PYTHONPATH``).
    """
    env = os.environ.get("FGCAL_DATASETS")
    if env:
        return Path(env)
    installed = _PACKAGE / "_data"
    if (installed / "robots").is_dir():
        return installed
    return _PACKAGE.parent / "datasets"


def builtin_robot_names() -> list[str]:
    return sorted(p.stem for p in (datasets_dir() / "robots").glob("*.yaml"))


def builtin_robot_path(name: str) -> Path:
    return datasets_dir() / "robots" / f"{name}.yaml"


def default_dataset_dir() -> Path:
    """The bundled default dataset: a simulated PUMA 560 measured as in the paper."""
    return datasets_dir() / "puma560-paper"
