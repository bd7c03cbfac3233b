"""What the library functions share: pose selections, parameter names, datasets given as paths, size limits."""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from fgcal.errors import FgcalError

__all__ = [
    "MAX_BATCH_ROWS",
    "MAX_POSES",
    "as_dataset",
    "as_result",
    "measurement_rows",
    "parameter_names",
    "parse_pose_selection",
    "select_poses",
]

MAX_POSES = 200_000  # simulated poses or design candidates: beyond this, memory runs out
MAX_BATCH_ROWS = 250_000  # measurement rows of one batch graph (calibrate, check) within about 1 GB


def parse_pose_selection(text: str | None, available) -> np.ndarray:
    """Pose ids from ``odd``, ``even``, ``first:N``, ``last:N`` or ranges like ``1-21,30``.

    Parameters
    ----------
    text : str or None
        The selection; None selects every pose.
    available : array_like of int, shape (N,)
        The dataset's pose ids.

    Returns
    -------
    ndarray of int, shape (K,)
        The chosen ids, sorted.
    """
    available = np.asarray(available, dtype=int)
    if text is None:
        return available
    text = text.strip()
    if text in ("odd", "even"):
        parity = available[available % 2 == (1 if text == "odd" else 0)]
        if not len(parity):
            raise FgcalError(f"--select {text}: the dataset has no {text} pose ids")
        return parity
    for prefix in ("first:", "last:"):
        if text.startswith(prefix):
            try:
                n = int(text[len(prefix):])
            except ValueError:
                raise FgcalError(f"--select {text!r}: expected {prefix}N") from None
            if n < 1:
                raise FgcalError(f"--select {text!r}: N must be at least 1")
            if n > len(available):
                raise FgcalError(f"--select {text!r}: the dataset has only {len(available)} poses")
            return available[:n] if prefix == "first:" else available[-n:]
    chosen: list[int] = []
    for part in text.split(","):
        part = part.strip()
        try:
            a, b = part.split("-", 1) if "-" in part[1:] and not part.startswith("-") else (part, part)
            lo, hi = int(a), int(b)
        except ValueError:
            raise FgcalError(f"--select {text!r}: expected odd, even, first:N, last:N or ranges like 1-21,30") from None
        if hi < lo:
            raise FgcalError(f"--select: range {lo}-{hi} is empty (write it as {hi}-{lo})")
        if hi - lo >= len(available):
            raise FgcalError(f"--select: range {lo}-{hi} spans more ids than the {len(available)} poses of the dataset")
        chosen.extend(range(lo, hi + 1))
    missing = sorted(set(chosen) - set(available.tolist()))
    if missing:
        raise FgcalError(f"--select: pose(s) {', '.join(map(str, missing[:10]))} not in the dataset")
    if not chosen:
        raise FgcalError(f"--select {text!r}: selects no pose")
    return np.array(sorted(set(chosen)), dtype=int)


def select_poses(ds, poses: str | Sequence[int] | None):
    """``ds`` restricted to ``poses`` (a selection as :func:`parse_pose_selection` reads, or pose ids)."""
    if poses is None:
        return ds
    if isinstance(poses, str):
        ids = parse_pose_selection(poses, ds.pose_ids)
    else:
        ids = np.asarray(list(poses), dtype=int)
        missing = sorted(set(ids.tolist()) - set(ds.pose_ids.tolist()))
        if missing or not len(ids):
            raise FgcalError(f"poses: {', '.join(map(str, missing[:10])) or 'none'} not in the dataset"
                             if missing else "poses: selects no pose")
    return ds if len(ids) == ds.n_poses else ds.select(ids)


def parameter_names(model, names: str | Sequence[str] | None, option: str) -> tuple[str, ...]:
    """The parameter names of ``option`` (comma-separated text or a sequence), each checked against ``model``.

    ``--exclude`` names must be among the parameters estimated by default; ``--extra`` names
    must be geometric slots of the model.
    """
    from fgcal.robots.model import SLOT_NAMES

    if not names:
        return ()
    items = names.split(",") if isinstance(names, str) else list(names)
    out = tuple(n.strip() for n in items if n.strip())
    if not out:
        raise FgcalError(f"{option} {names!r}: no parameter name")
    known = list(getattr(model, "slot_names", SLOT_NAMES))
    pool = model.identifiable_names() if option == "--exclude" else known
    bad = [n for n in out if n not in pool]
    if bad:
        what = ("not among the estimated parameters" if option == "--exclude" and all(n in known for n in bad)
                else "unknown parameter name(s)")
        raise FgcalError(f"{option}: {', '.join(b[:30] for b in bad[:5])}: {what}; "
                         f"{'estimated' if option == '--exclude' else 'known'}: {', '.join(pool)}")
    if option == "--exclude" and set(pool) <= set(out):
        raise FgcalError(f"--exclude: all {len(pool)} estimated parameters excluded; nothing is left to calibrate")
    return out


def measurement_rows(ds) -> int:
    """Measurement rows of ``ds`` over all its levels."""
    return sum(len(getattr(ds, lv)) for lv in ds.levels())


def as_dataset(dataset):
    """A :class:`~fgcal.measurements.dataset.Dataset` from itself or its directory."""
    from fgcal.io.dataset_io import load_dataset

    return load_dataset(dataset) if isinstance(dataset, str | Path) else dataset


def as_result(result):
    """A :class:`~fgcal.estimation.result.CalibrationResult` from itself or its file."""
    from fgcal.estimation.result import load_result

    return load_result(result) if isinstance(result, str | Path) else result
