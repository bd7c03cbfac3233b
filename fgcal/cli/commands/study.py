"""``fgcal study``: the command's body (its options are in :func:`fgcal.cli.parser.build_parser`)."""
from __future__ import annotations

import contextlib
import logging
import os
from pathlib import Path

from fgcal.cli.commands.checks import check_output_dir
from fgcal.errors import FgcalError

log = logging.getLogger("fgcal")


@contextlib.contextmanager
def _locked(out: Path):
    """Hold an exclusive lock on the folder ``out`` (created if need be) while a study writes into it."""
    import fcntl

    out.mkdir(parents=True, exist_ok=True)
    fd = os.open(out, os.O_RDONLY)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise FgcalError(f"--out {out}: in use by another fgcal study; wait for it or give another --out") \
                from None
        yield
    finally:
        os.close(fd)


def _cmd_study(args) -> int:
    from fgcal.studies.study import trials_for
    from fgcal.studies.study_run import run_study, study_figures, summary, write_figures

    trials = trials_for(args.name, robot=args.robot, trials=args.trials, poses=args.poses, seed=args.seed)
    out = check_output_dir(args.out or Path(f"study-{args.name}"))
    t0 = __import__("time").perf_counter()
    with _locked(out):  # two studies on one --out would interleave their trials
        rows = run_study(trials, out, workers=args.workers, scheduler=args.scheduler)
    elapsed = __import__("time").perf_counter() - t0
    paths = write_figures(study_figures(args.name, rows), out)
    print(summary(args.name, rows))
    print(f"{out / 'trials.csv'} ({len(rows)} rows; this run {elapsed:.1f} s); figures: "
          + ", ".join(p.name for p in paths))
    return 0
