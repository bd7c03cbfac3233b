"""Running a study: local processes or a Dask cluster, one CSV row per trial, resume, plots.

Trials are shipped to the workers as small frozen dataclasses; every graph is built inside the
worker (graphs of custom factors cannot be pickled). Each finished trial rewrites ``trials.csv``
atomically, so an interrupted study resumes without redoing finished trials.
"""
from __future__ import annotations

import csv
import io
import logging
import math
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

from fgcal.errors import FgcalError
from fgcal.studies.study import RESULT_COLUMNS, Trial, run_trial
from fgcal.util.yamlio import atomic_write_bytes, atomic_write_text

__all__ = ["Progress", "read_rows", "run_study", "study_figures"]

log = logging.getLogger(__name__)


def read_rows(path) -> list[dict]:
    """Rows of a ``trials.csv`` (numbers as floats); an empty list when it does not exist."""
    from fgcal.util.yamlio import read_text_file

    path = Path(path)
    if not os.path.lexists(path):
        return []
    try:
        rows = list(csv.DictReader(io.StringIO(read_text_file(path, FgcalError), newline="")))
    except csv.Error as exc:
        raise FgcalError(f"{path}: not a trials.csv of fgcal ({exc})") from None
    if rows and not {"study", "trial"} <= set(rows[0]):
        raise FgcalError(f"{path}: not a trials.csv of fgcal (no study and trial columns)")
    out = []
    for r in rows:
        d = dict(r)
        for k in RESULT_COLUMNS:
            if k in ("study", "robot", "plan", "design"):
                continue
            if k not in d:  # a column added since the file was written
                d[k] = float("nan")
                continue
            try:
                d[k] = float(d[k]) if d.get(k) not in (None, "") else float("nan")
            except ValueError:
                raise FgcalError(f"{path}: column {k} is not a number: {str(d[k])[:20]!r}") from None
        try:
            d["trial"] = int(d["trial"])
        except (TypeError, ValueError):
            raise FgcalError(f"{path}: column trial is not an integer: {str(d['trial'])[:20]!r}") from None
        out.append(d)
    return out


def _write_rows(path, rows) -> None:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=RESULT_COLUMNS, lineterminator="\n")
    w.writeheader()
    for r in sorted(rows, key=lambda r: (r["study"], r["trial"])):
        w.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in r.items()})
    atomic_write_text(path, buf.getvalue())


class Progress:
    """A progress bar on a terminal; a line every tenth of the way otherwise."""

    def __init__(self, total: int, stream=None):
        self.total = total
        self.done = 0
        self.t0 = time.perf_counter()
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()
        self._last_decile = -1

    def step(self) -> None:
        self.done += 1
        rate = self.done / max(time.perf_counter() - self.t0, 1e-9)
        if self.tty:
            filled = int(30 * self.done / self.total)
            self.stream.write(f"\r[{'#' * filled}{'.' * (30 - filled)}] {self.done}/{self.total} trials, "
                              f"{rate:.2f}/s")
            if self.done == self.total:
                self.stream.write("\n")
        else:
            decile = int(10 * self.done / self.total)
            if decile != self._last_decile or self.done == self.total:
                self._last_decile = decile
                self.stream.write(f"{self.done}/{self.total} trials ({rate:.2f}/s)\n")
        self.stream.flush()


SETTINGS = ("seed", "n_poses", "plan", "robot", "design", "cmm_sigma", "joint_resolution", "repeatability")


def _show(v) -> str:
    return f"{v:g}" if isinstance(v, (int, float)) else str(v)[:20]


def _check_settings(csv_path: Path, rows: list[dict], trials: list[Trial]) -> None:
    """Refuse to resume when a finished trial was run with other settings than this run's."""
    by_key = {(t.study, t.trial): t for t in trials}
    for r in rows:
        t = by_key.get((r["study"], r["trial"]))
        if t is None:
            continue
        diff = []
        for k in SETTINGS:
            mine, theirs = getattr(t, k), r.get(k)
            if isinstance(mine, str):
                same = str(theirs if theirs is not None else "") == mine
            else:
                try:
                    same = theirs is not None and math.isclose(float(theirs), float(mine), rel_tol=1e-9, abs_tol=1e-12)
                except (TypeError, ValueError):
                    same = False
            if not same:
                diff.append(f"{k} {_show(theirs)} there, {_show(mine)} now")
        if diff:
            raise FgcalError(f"{csv_path}: trial {r['trial']} of study {r['study']} was run with other settings "
                             f"({'; '.join(diff[:3])}); refusing to resume: give another --out or remove "
                             f"{csv_path.parent}")


def _worker_context(todo: list[Trial]):
    """How to start local workers: forked from this process where that is safe, else spawned.

    A spawned worker imports fgcal's calibration path and reads the robot model again (about a
    second of CPU each, as much as ten trials); a fork inherits them. Fork only on Linux and from
    a process with no other threads (a fork copies no threads, and any lock one held stays held).
    """
    import threading

    if sys.platform.startswith("linux") and threading.active_count() == 1:
        from fgcal.studies.study import prepare_process

        prepare_process({t.robot for t in todo})
        return get_context("fork")
    return get_context("spawn")


def run_study(trials: list[Trial], out_dir, workers: int | None = None, scheduler: str | None = None,
              progress: bool = True, runner=run_trial) -> list[dict]:
    """Run the trials not yet in ``out_dir/trials.csv``; returns all rows (old and new).

    ``scheduler``: a Dask distributed scheduler address (``tcp://host:port``); otherwise local
    processes (``workers``, default: the number of CPUs; 1 runs in this process).
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    csv_path = out_dir / "trials.csv"
    all_rows = read_rows(csv_path)
    _check_settings(csv_path, all_rows, trials)
    wanted = {(t.study, t.trial) for t in trials}
    rows = [r for r in all_rows if (r["study"], r["trial"]) in wanted]
    if len(rows) < len(all_rows):
        log.warning("%s: %d trial(s) of other runs kept in the file but left out of this summary", csv_path,
                    len(all_rows) - len(rows))
    done = {(r["study"], r["trial"]) for r in rows}
    todo = [t for t in trials if (t.study, t.trial) not in done]
    if done:
        log.info("%s: %d trial(s) already done, %d to run", csv_path, len(trials) - len(todo), len(todo))
    bar = Progress(len(todo)) if progress and todo else None

    def finished(row):
        rows.append(row)
        all_rows.append(row)
        _write_rows(csv_path, all_rows)
        if bar:
            bar.step()

    if not todo:
        return rows
    if scheduler:
        try:
            from distributed import Client
            from distributed import as_completed as dask_completed
        except ImportError:
            raise FgcalError("--scheduler needs Dask: pip install 'dask[distributed]' (or fgcal's [study] extra)") \
                from None
        try:
            client = Client(scheduler, timeout="10s")
        except OSError as exc:
            raise FgcalError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
        try:
            futures = client.map(runner, todo, pure=False)
            for fut in dask_completed(futures):
                finished(fut.result())
        finally:
            client.close()
    elif (workers or os.cpu_count() or 1) == 1:
        for t in todo:
            finished(runner(t))
    else:
        with ProcessPoolExecutor(max_workers=workers or os.cpu_count(), mp_context=_worker_context(todo)) as pool:
            submitted = [pool.submit(runner, t) for t in todo]
            for fut in as_completed(submitted):
                finished(fut.result())
    return rows


def _group(rows, key):
    out = {}
    for r in rows:
        out.setdefault(r[key], []).append(r)
    return dict(sorted(out.items()))


def study_figures(study: str, rows: list[dict]) -> dict:
    """The study's figures, ``{name: matplotlib Figure}``."""
    from matplotlib.figure import Figure

    rows = [r for r in rows if r["study"] == study]
    figs: dict[str, Any] = {}
    if not rows:
        return figs
    if study in ("fig8-9", "experiment") or study.startswith("sweep"):
        key = {"fig8-9": "n_poses", "experiment": "n_poses", "sweep-cmm": "cmm_sigma",
               "sweep-joint": "joint_resolution", "sweep-repeatability": "repeatability"}.get(study, "n_poses")
        groups = _group(rows, key)
        quantities = [("position_rms_mm", "position error RMS (mm)", "position"),
                      ("orientation_rms_deg", "orientation error RMS (deg)", "orientation")]
        if study == "experiment":
            quantities = [("measured_position_rms_mm", "position RMS vs measured (mm)", "position"),
                          ("measured_orientation_rms_deg", "orientation RMS vs measured (deg)", "orientation")]
        for col, label, name in quantities:
            fig = Figure(figsize=(6.4, 4.2), layout="constrained")
            ax = fig.add_subplot()
            xs = list(groups)
            for x, rs in groups.items():
                ax.plot([x] * len(rs), [r[col] for r in rs], "o", color="0.6", ms=3)
            ax.plot(xs, [np.mean([r[col] for r in rs]) for rs in groups.values()], "k-o", label="mean of trials")
            if study == "experiment":
                ax.plot(xs, [np.mean([r[col.replace("measured_", "")] for r in rs]) for rs in groups.values()],
                        "b--s", label="against the truth")
            ax.set_xlabel({"n_poses": "number of observations"}.get(key, key.replace("_", " ")))
            if study.startswith("sweep") and min(xs) > 0:
                ax.set_xscale("log")
            ax.set_ylabel(label)
            ax.set_yscale("log")
            ax.legend(fontsize=8)
            ax.set_title({"fig8-9": f"Simulated {name} error (the paper's Fig. {8 if name == 'position' else 9})",
                          "experiment": f"Experiment: {name} error at 21 verification poses"}.get(
                              study, f"{study}: {name} error"))
            figs[f"{study}_{name}"] = fig
    if study == "design":
        groups = _group(rows, "design")
        order = [k for k in ("random", "O1", "O2", "O3", "O4", "O5", "pred") if k in groups]
        fig = Figure(figsize=(6.4, 4.2), layout="constrained")
        ax = fig.add_subplot()
        for x, name in enumerate(order):
            vals = [r["position_rms_mm"] for r in groups[name]]
            ax.plot(np.full(len(vals), x) + np.linspace(-0.15, 0.15, len(vals)), vals, "o", ms=3,
                    color="0.6" if name == "random" else "tab:blue")
            ax.plot([x - 0.25, x + 0.25], [np.mean([r["predicted_position_rms_mm"] for r in groups[name]])] * 2,
                    "r-", lw=2, label="predicted" if x == 0 else None)
        if "random" in groups:
            ax.axhline(np.percentile([r["position_rms_mm"] for r in groups["random"]], 25), color="k", ls=":",
                       label="25th percentile of random sets")
        ax.set_xticks(range(len(order)), ["random sets" if k == "random" else f"designed ({k})" for k in order],
                      rotation=20, fontsize=8)
        ax.set_ylabel("position error RMS at new poses (mm)")
        ax.legend(fontsize=8)
        ax.set_title("Which poses to measure: designed plans against random sets")
        figs["design"] = fig
    if study == "fig13":
        values = np.array([r["position_rms_mm"] for r in sorted(rows, key=lambda r: r["trial"])])
        fig = Figure(figsize=(6.4, 4.2), layout="constrained")
        ax = fig.add_subplot()
        ax.plot(np.arange(1, len(values) + 1), values, "o", ms=3)
        ax.set_xlabel("calibration (random set of observations)")
        ax.set_ylabel("position error RMS (mm)")
        spread = values.max() / values.min()
        ax.set_title(f"Position error for {len(values)} random sets (the paper's Fig. 13): "
                     f"max/min {spread:.1f}")
        figs["fig13"] = fig
    return figs


def write_figures(figs: dict, out_dir) -> list[Path]:
    paths = []
    for name, fig in figs.items():
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=110)
        path = Path(out_dir) / f"{name}.png"
        atomic_write_bytes(path, buf.getvalue())
        paths.append(path)
    return paths


def summary(study: str, rows: list[dict]) -> str:
    rows = [r for r in rows if r["study"] == study]
    if not rows:
        return f"{study}: no trials"
    pos = np.array([r["position_rms_mm"] for r in rows])
    lines = [f"{study}: {len(rows)} trials; position RMS at verification poses: median {np.median(pos):.4g} mm, "
             f"10-90% {np.percentile(pos, 10):.4g}-{np.percentile(pos, 90):.4g} mm, max/min {pos.max() / pos.min():.2g}"]
    if study == "design":
        from scipy.stats import spearmanr

        groups = _group(rows, "design")
        rand = groups.get("random", [])
        realised = [r["position_rms_mm"] for r in rand]
        p25 = np.percentile(realised, 25) if rand else float("nan")
        lines.append(f"  random 12-pose sets: realised median {np.median(realised):.4g} mm, 25th percentile {p25:.4g}")
        for name, rs in groups.items():
            if name == "random":
                continue
            real = np.mean([r["position_rms_mm"] for r in rs])
            pred = np.mean([r["predicted_position_rms_mm"] for r in rs])
            lines.append(f"  designed by {name:4s}: realised {real:.4g} mm over {len(rs)} truths "
                         f"({'below' if real < p25 else 'NOT below'} the 25th percentile), predicted {pred:.4g} "
                         f"({100 * (pred - real) / real:+.0f}%)")
        if len(rand) > 3:
            lines.append("  how well each index predicts a random set's accuracy (Spearman rank correlation with "
                         "the realised error; -1 or +1 is perfect):")
            for col in ("predicted_position_rms_mm", "O1", "O2", "O3", "O4", "O5"):
                rho = spearmanr([r[col] for r in rand], realised).correlation
                lines.append(f"    {'pred' if col.startswith('pred') else col:5s} {rho:+.2f}")
    if study == "experiment":
        for n, rs in _group(rows, "n_poses").items():
            m = [r["measured_position_rms_mm"] for r in rs]
            lines.append(f"  {int(n)} poses: {np.mean(m):.3g} mm RMS against the measurements, "
                         f"{np.mean([r['position_rms_mm'] for r in rs]):.3g} mm against the truth")
    return "\n".join(lines)
