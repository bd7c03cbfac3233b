"""Writing a dataset directory (DESIGN.md section 3): all files into a temporary directory that
then replaces the target, so a dataset on disk is never half written; each table streamed from
its arrays in batches (memory of a batch, not of the table).
"""
from __future__ import annotations

import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from fgcal.errors import FgcalError
from fgcal.io.dataset_tables import POINT_COLUMNS, joint_columns
from fgcal.io.setup_io import cameras_dict, stations_dict
from fgcal.measurements.dataset import FORMAT, Dataset
from fgcal.measurements.point import POINT
from fgcal.measurements.setup import SetupSpec
from fgcal.measurements.types import kinematic_types
from fgcal.util.yamlio import atomic_write_chunks, atomic_write_text, dump_yaml, make_dir

__all__ = ["save_dataset", "write_csv"]

def _fmt(v: float | np.floating) -> str:
    from fgcal.util.numbers import format_number

    return format_number(float(v))


_WRITE_ROWS = 20_000  # rows formatted and written at a time: memory of a batch, not of the table


def write_csv(path, header, rows) -> None:
    """Write a CSV file atomically; floats with full (round-trip) precision. ``rows`` is consumed as it
    is written (in batches of :data:`_WRITE_ROWS`), so a generator keeps the memory bounded."""
    def chunks():
        yield (",".join(map(_csv_text, header)) + "\n").encode("utf-8")
        batch: list[str] = []
        for row in rows:
            batch.append(",".join(_fmt(v) if isinstance(v, (float, np.floating)) else _csv_text(v) for v in row))
            if len(batch) == _WRITE_ROWS:
                yield ("\n".join(batch) + "\n").encode("utf-8")
                batch = []
        if batch:
            yield ("\n".join(batch) + "\n").encode("utf-8")

    atomic_write_chunks(path, chunks())


def _csv_text(v) -> str:
    """A text field, quoted as RFC 4180 does when it holds a separator, a quote or a line break."""
    s = str(v)
    return '"' + s.replace('"', '""') + '"' if any(c in s for c in ',"\r\n') else s


def _write_into(ds: Dataset, directory: Path) -> None:
    meta = {
        "format": FORMAT,
        "robot": ds.robot,
        **({"chain": dict(ds.chain)} if ds.chain else {}),
        "tool": {"radius": float(ds.tooling.radius),
                 "balls": {k: [float(c) for c in v] for k, v in ds.tooling.balls.items()}},
        "noise": ds.noise.items(),
        "provenance": ds.provenance,
        **SetupSpec({n: f for n, f in ds.setup.fixtures.items() if f.type not in ("station", "camera", "target")},
                    ds.setup.distances).to_dict(),
        **stations_dict(ds),
        **cameras_dict(ds),
    }
    atomic_write_text(directory / "dataset.yaml", dump_yaml(meta))
    if ds.stations is None:
        write_csv(directory / "joints.csv", joint_columns(ds.joints_deg.shape[1]),
                  ([int(p), *map(float, q)] for p, q in zip(ds.pose_ids, ds.joints_deg)))
    else:
        write_csv(directory / "joints.csv", joint_columns(ds.joints_deg.shape[1]) + ["station"],
                  ([int(p), *map(float, q), st] for p, q, st in zip(ds.pose_ids, ds.joints_deg, ds.stations)))
    if ds.probes is not None:
        write_csv(directory / "probes.csv", POINT_COLUMNS, POINT.rows(ds.probes))
    files: dict = {}
    for kind in kinematic_types():
        obs = getattr(ds, kind.level, None)
        if obs is not None:
            files.setdefault(kind.file, (kind.columns, []))[1].append((kind, obs))
    for name, (columns, parts) in files.items():
        if len(parts) == 1:  # one type: its rows streamed in file order (no list of every row)
            kind, obs = parts[0]
            order = np.argsort(obs.line, kind="stable")
            in_order = obs if np.all(order == np.arange(len(order))) else obs.subset(order)
            write_csv(directory / name, columns, kind.rows(in_order))
        else:  # types sharing a file (contacts) write its rows in file order
            rows = [lr for kind, obs in parts for lr in zip(obs.line.tolist(), kind.rows(obs))]
            write_csv(directory / name, columns, (r for _, r in sorted(rows, key=lambda lr: lr[0])))
    if ds.truth is not None:
        truth: dict[str, Any] = {"parameters": {k: float(v) for k, v in ds.truth.items()}}
        if ds.truth_outliers:
            truth["outliers"] = [[int(p), str(b), int(i)] for p, b, i in ds.truth_outliers]
        atomic_write_text(directory / "truth.yaml", dump_yaml(truth))


def save_dataset(ds: Dataset, directory, overwrite: bool = False, extra_files=None) -> Path:
    """Write ``ds`` as a dataset directory, all at once (a temporary directory is renamed).

    ``extra_files`` maps further file names to their text (for example ``quality.csv``).

    Raises
    ------
    FgcalError
        If ``directory`` exists and ``overwrite`` is false.
    """
    directory = Path(directory)
    if directory.exists() and not overwrite:
        raise FgcalError(f"{directory}: already exists (use --force to replace it)")
    directory.parent.mkdir(parents=True, exist_ok=True)
    tmp = make_dir(directory)
    try:
        _write_into(ds, tmp)
        for name, text in (extra_files or {}).items():
            atomic_write_text(tmp / name, text)
        if not overwrite:  # rename(2) onto an existing folder with files fails: another run that wrote
            try:           # it meanwhile is not replaced (the check above is minutes before)
                tmp.rename(directory)
            except OSError:
                raise FgcalError(f"{directory}: already exists (written meanwhile by another run; use --force "
                                 "to replace it)") from None
        elif directory.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{directory.name}.old.", dir=directory.parent))
            old.rmdir()
            directory.rename(old)
            tmp.rename(directory)
            shutil.rmtree(old, ignore_errors=True)
        else:
            tmp.rename(directory)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return directory
