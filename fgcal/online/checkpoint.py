"""The online checkpoint: an append-only journal (one JSON line a pose) and its file conventions."""
from __future__ import annotations

import json
from pathlib import Path

from fgcal.errors import FgcalError

__all__ = ["CHECKPOINT_FORMAT", "INPUT_NAMES", "SNAPSHOT_EVERY", "default_checkpoint", "read_checkpoint"]

CHECKPOINT_FORMAT = "fgcal-online-checkpoint/3"
SNAPSHOT_EVERY = 100  # poses between snapshots of a filter's state (the journal has every pose)
INPUT_NAMES = ("dataset.yaml", "truth.yaml", "joints.csv", "probes.csv", "centres.csv", "poses.csv", "distances.csv",
               "contacts.csv")


def default_checkpoint(dataset, engine: str, out=None) -> Path:
    """The checkpoint of a run: next to its output when there is one, else in the current folder,
    named after the dataset (and a digest of its full path) and the engine."""
    import hashlib

    ds = Path(dataset).resolve()
    if out is not None:
        return Path(f"{out}.{engine}.checkpoint")
    digest = hashlib.sha1(str(ds).encode()).hexdigest()[:8]
    return Path(f"fgcal-online-{ds.name}-{digest}-{engine}.checkpoint")


def read_checkpoint(path) -> dict:
    """The header and the journal entries of a checkpoint: ``{"header", "entries"}`` (a torn last
    line, from a crash in mid-write, is left out)."""
    lines = Path(path).read_bytes().split(b"\n")
    entries = []
    for k, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            entries.append(json.loads(line))
        except ValueError:
            if k >= len(lines) - 2:  # the last line, cut short: the pose was not committed
                break
            raise FgcalError(f"{path}: line {k + 1} of the checkpoint is not readable; use --restart") from None
    if not entries or not str(entries[0].get("format", "")).startswith("fgcal-online-checkpoint/"):
        raise FgcalError(f"{path}: not an fgcal online checkpoint")
    return {"header": entries[0], "entries": entries[1:]}
