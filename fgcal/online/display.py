"""What ``fgcal online`` shows after each pose, and following a growing dataset."""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from fgcal.errors import DatasetError, FgcalError
from fgcal.io.dataset_io import load_dataset
from fgcal.online.run import OnlineRun

__all__ = ["Display", "follow"]


class Display:
    """After each pose: a redrawn table on a terminal, one plain line otherwise."""

    def __init__(self, run: OnlineRun, stream=None, rows: int = 6):
        self.run = run
        self.stream = stream or sys.stdout
        self.tty = self.stream.isatty()
        self.rows = rows
        self._drawn = 0
        params = run.engine.params
        self._prior = params.to_file_units(run.engine.prior_sigma)
        self._units = params.units

    def show(self, entry: dict, total: int | None = None) -> None:
        run = self.run
        params = run.engine.params
        est, sig = run.estimate_file_units()
        rel = sig / self._prior  # 1: the data have said nothing yet; small: well determined
        n = run.engine.n_accepted
        where = f"{len(run.processed)}/{total}" if total else str(len(run.processed))
        status = "accepted" if entry["accepted"] else f"REJECTED: {entry['reason']}"
        worst = int(np.argmax(rel))
        head = (f"pose {entry['pose']} ({where}) {status}; {n} poses in the estimate; largest sigma "
                f"{params.names[worst]} {sig[worst]:.3g} {self._units[worst]} ({rel[worst]:.2%} of its prior)")
        if not self.tty:
            print(head, file=self.stream, flush=True)
            return
        order = np.argsort(-rel)[: self.rows]
        lines = [head, f"  {'most uncertain':14s} {'estimate':>14s} {'sigma':>10s}  of prior"]
        lines += [f"  {params.names[i]:14s} {est[i]:14.6f} {sig[i]:10.3g}  {rel[i]:7.2%} {self._units[i]}"
                  for i in order]
        if self._drawn:
            self.stream.write(f"\x1b[{self._drawn}F\x1b[J")
        self.stream.write("\n".join(lines) + "\n")
        self.stream.flush()
        self._drawn = len(lines)


def _fingerprints(ds, poses) -> dict:
    """Per pose of ``poses`` in ``ds``: its joint readings and its number of rows at each level."""
    row = {int(p): i for i, p in enumerate(ds.pose_ids.tolist())}
    counts = {}
    for level in ds.levels():
        ids, n = np.unique(getattr(ds, level).pose, return_counts=True)
        counts[level] = dict(zip(ids.tolist(), n.tolist()))
    return {p: (tuple(ds.joints_deg[row[p]].tolist()), tuple((lv, c.get(p, 0)) for lv, c in counts.items()))
            for p in poses if p in row}


def _rewritten(path, taken: dict, ds) -> None:
    """Refuse a dataset in which a pose already taken is gone or changed (a file truncated,
    rotated or rewritten under ``--follow``): the estimate holds the old readings."""
    now = _fingerprints(ds, taken)
    gone = [p for p in taken if p not in now]
    changed = [p for p in taken if p in now and now[p] != taken[p]]
    if gone or changed:
        what = (f"pose(s) {', '.join(map(str, gone[:5]))} already taken are gone" if gone else
                f"the rows of pose(s) {', '.join(map(str, changed[:5]))} already taken changed")
        raise FgcalError(f"{path}: {what} ({len(gone) + len(changed)} pose(s): a file truncated, rotated or "
                         "rewritten while following; the estimate holds the old rows); run again with --restart "
                         "to start over")


def follow(run: OnlineRun, display: Display, interval: float = 1.0, settle: float = 2.0, stop=None) -> None:
    """Keep reading the dataset for appended poses until interrupted (or ``stop()`` is true).

    A pose is taken when a later pose exists in ``joints.csv`` or the files have not changed for
    ``settle`` seconds (so a pose whose probe points are still being written is not cut short).
    A file caught half-written is read again at the next poll. The dataset may only grow: a pose
    already taken that is gone or whose rows changed (a file truncated, rotated or rewritten) ends
    the run with an error.
    """
    if run.ds.path is None:
        raise ValueError("following a dataset needs its folder (the dataset was made in memory)")
    path = Path(run.ds.path)
    taken = _fingerprints(run.ds, [p["pose"] for p in run.processed])
    last_change = time.monotonic()
    last_sig = None
    last_error = loaded_sig = None
    while stop is None or not stop():
        sig = tuple((f.name, f.stat().st_mtime_ns, f.stat().st_size) for f in sorted(path.glob("*.csv")))
        if sig != last_sig:
            last_sig, last_change = sig, time.monotonic()
        if sig != loaded_sig:  # read the files again only when they have changed
            try:
                ds = load_dataset(path)
            except DatasetError as exc:
                if str(exc) != last_error:  # said once (without -v), not at every poll
                    print(f"waiting: {exc}", file=sys.stderr, flush=True)
                    last_error = str(exc)
                time.sleep(interval)
                continue
            loaded_sig, last_error = sig, None
            _rewritten(path, taken, ds)
            run.ds = ds
            run.engine.ds = ds
        ds = run.ds
        pending = run.pending(ds)
        settled = time.monotonic() - last_change >= settle
        for rec in pending:
            is_last = rec.pose == int(ds.pose_ids[-1])
            if is_last and not settled:
                break
            taken.update(_fingerprints(ds, [rec.pose]))
            display.show(run.feed(rec))
        run.sync()  # on the disk before the wait
        time.sleep(interval)
