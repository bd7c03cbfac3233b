"""What ``fgcal online`` shows after each pose, and following a growing dataset."""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from fgcal.errors import DatasetError
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
        order = np.argsort(-rel)[: self.rows]
        n = run.engine.n_accepted
        where = f"{len(run.processed)}/{total}" if total else str(len(run.processed))
        status = "accepted" if entry["accepted"] else f"REJECTED: {entry['reason']}"
        worst = int(np.argmax(rel))
        head = (f"pose {entry['pose']} ({where}) {status}; {n} poses in the estimate; largest sigma "
                f"{params.names[worst]} {sig[worst]:.3g} {self._units[worst]} ({rel[worst]:.2%} of its prior)")
        if not self.tty:
            print(head, file=self.stream, flush=True)
            return
        lines = [head, f"  {'most uncertain':14s} {'estimate':>14s} {'sigma':>10s}  of prior"]
        lines += [f"  {params.names[i]:14s} {est[i]:14.6f} {sig[i]:10.3g}  {rel[i]:7.2%} {self._units[i]}"
                  for i in order]
        if self._drawn:
            self.stream.write(f"\x1b[{self._drawn}F\x1b[J")
        self.stream.write("\n".join(lines) + "\n")
        self.stream.flush()
        self._drawn = len(lines)


def follow(run: OnlineRun, display: Display, interval: float = 1.0, settle: float = 2.0, stop=None) -> None:
    """Keep reading the dataset for appended poses until interrupted (or ``stop()`` is true).

    A pose is taken when a later pose exists in ``joints.csv`` or the files have not changed for
    ``settle`` seconds (so a pose whose probe points are still being written is not cut short).
    A file caught half-written is read again at the next poll.
    """
    if run.ds.path is None:
        raise ValueError("following a dataset needs its folder (the dataset was made in memory)")
    path = Path(run.ds.path)
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
            run.ds = ds
            run.engine.ds = ds
        ds = run.ds
        pending = run.pending(ds)
        settled = time.monotonic() - last_change >= settle
        for rec in pending:
            is_last = rec.pose == int(ds.pose_ids[-1])
            if is_last and not settled:
                break
            display.show(run.feed(rec))
        run.sync()  # on the disk before the wait
        time.sleep(interval)
