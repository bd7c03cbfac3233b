"""The online checkpoint: an append-only journal (one JSON line a pose) and its file conventions."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from fgcal.errors import FgcalError
from fgcal.util.numbers import finite_number

__all__ = [
    "CHECKPOINT_FORMAT",
    "INPUT_NAMES",
    "MAX_POSE_ID",
    "SNAPSHOT_EVERY",
    "default_checkpoint",
    "read_checkpoint",
    "read_snapshot",
]

MAX_POSE_ID = 2**62  # pose ids are 64-bit in every engine (gtsam keys, numpy arrays): larger ones are refused

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
    if not entries or not isinstance(entries[0], dict) \
            or not str(entries[0].get("format", "")).startswith("fgcal-online-checkpoint/"):
        raise FgcalError(f"{path}: not an fgcal online checkpoint")
    for k, e in enumerate(entries[1:], start=2):
        problem = _entry_problem(e)
        if problem:
            raise FgcalError(f"{path}: entry {k} of the checkpoint: {problem}; use --restart")
    return {"header": entries[0], "entries": entries[1:]}


def _finite_numbers(v, n: int | None = None) -> bool:
    return isinstance(v, list) and (n is None or len(v) == n) and all(map(finite_number, v))


def _entry_problem(e) -> str:
    """What is wrong with one journal entry ("" when nothing): the keys every engine reads."""
    if not isinstance(e, dict):
        return "not a mapping"
    pose = e.get("pose")
    if not isinstance(pose, int) or isinstance(pose, bool) or not 0 <= pose <= MAX_POSE_ID:
        return f"pose {str(pose)[:30]!r} is not a pose id (an integer from 0 to 2^62)"
    if not isinstance(e.get("accepted"), bool) or not isinstance(e.get("reason", ""), str):
        return f"pose {pose}: no accepted: true|false or reason"
    if "f" in e and not _finite_numbers([e["f"]]):
        return f"pose {pose}: f is not a finite number"
    if e["accepted"]:
        h = e.get("history")
        if not isinstance(h, dict) or not _finite_numbers(h.get("estimate")) \
                or not _finite_numbers(h.get("sigma"), len(h.get("estimate") or [])):
            return f"pose {pose}: history is not an estimate and sigmas of finite numbers"
    if "record" in e:
        from fgcal.online.records import record_from_json

        try:
            rec = record_from_json(e["record"])
        except (KeyError, TypeError, ValueError, IndexError, AttributeError):
            return f"pose {pose}: the streamed record is malformed"
        if rec.pose != pose or not np.all(np.isfinite(rec.q)):
            return f"pose {pose}: the streamed record is not of this pose or not finite"
    return ""


def read_snapshot(path) -> dict:
    """A filter's snapshot ``{"n", "state"}``, checked (finite state, square covariance of its size)."""
    try:
        snap = json.loads(Path(path).read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError, RecursionError):
        raise FgcalError(f"{path}: the snapshot of the checkpoint is not readable; use --restart") from None
    state = snap.get("state") if isinstance(snap, dict) else None
    n = snap.get("n") if isinstance(snap, dict) else None
    ok = False
    if isinstance(n, int) and not isinstance(n, bool) and n >= 0 and isinstance(state, dict) \
            and _finite_numbers(state.get("x")):
        k = len(state["x"])
        P = state.get("P")
        names = state.get("names")
        ok = isinstance(P, list) and len(P) == k and all(_finite_numbers(r, k) for r in P) \
            and (not isinstance(names, list) or all(isinstance(s, str) for s in names)) \
            and isinstance(state.get("setup", {}), dict)
    if not ok:
        raise FgcalError(f"{path}: the snapshot of the checkpoint is malformed (a count n, a finite state x and "
                         "its square covariance P); use --restart")
    return snap
