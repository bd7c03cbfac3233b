"""Running an online engine over a dataset: checkpoints, following a growing dataset, display.

The engine's state is checkpointed (JSON, atomically) after every pose, so a run that crashes or
is interrupted resumes where it stopped and ends with the same result as an uninterrupted one:
a filter's state is stored as it is; iSAM2 (whose graph cannot be pickled) is rebuilt by
replaying the accepted poses in the same order.
"""
from __future__ import annotations

import json
import logging
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import __version__
from .calibrate import CalibrationOptions
from .dataset import Dataset
from .dataset_io import load_dataset
from .errors import DatasetError, FgcalError
from .model import SLOT_NAMES, RobotModel, slots_to_file_units
from .online import PoseData, make_engine, pose_records
from .result import CalibrationResult, ParameterEstimate
from .robot_file import model_to_dict
from .yamlio import atomic_write_text

__all__ = ["OnlineRun", "CHECKPOINT_FORMAT", "read_stream", "STREAM_FORMAT"]

STREAM_FORMAT = """\
One record a line, comma-separated (lines starting with # and blank lines are ignored):
  joints,POSE,q1,q2,q3,q4,q5,q6      joint readings (deg); starts pose POSE
  probe,POSE,BALL,x,y,z              a probe point (mm, world)
  centre,POSE,BALL,x,y,z             a ball centre (mm, world)
  pose,POSE,x,y,z,qw,qx,qy,qz        a measured tool pose (mm, unit quaternion)
  end,POSE                           POSE is complete (so is it when the next pose's joints come)"""


def _record_to_json(rec: PoseData) -> dict:
    return {"pose": rec.pose, "q": rec.q.tolist(), "probes": [[b, p.tolist()] for b, p in rec.probes],
            "centres": [[b, c.tolist()] for b, c in rec.centres], "T": None if rec.T is None else rec.T.tolist()}


def _record_from_json(d: dict) -> PoseData:
    return PoseData(int(d["pose"]), np.array(d["q"], dtype=float),
                    [(b, np.array(p, dtype=float)) for b, p in d["probes"]],
                    [(b, np.array(c, dtype=float)) for b, c in d["centres"]],
                    None if d["T"] is None else np.array(d["T"], dtype=float))


def read_stream(lines, balls, warn=None):
    """Pose records from a stream of lines (:data:`STREAM_FORMAT`), each as soon as it is complete.

    A malformed line is reported through ``warn(message)`` with its line number and skipped; the
    stream goes on (an operator's typo should not end a measuring session).
    """
    from .transforms import pose_matrices

    warn = warn or (lambda m: print(m, file=sys.stderr))
    current: PoseData | None = None
    widths = {"joints": 8, "probe": 6, "centre": 6, "pose": 9, "end": 2}
    for n, raw in enumerate(lines, start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        f = [c.strip() for c in line.split(",")]
        tag = f[0]
        try:
            if tag not in widths:
                raise ValueError(f"unknown record {tag!r} (joints, probe, centre, pose, end)")
            if len(f) != widths[tag]:
                raise ValueError(f"{tag} takes {widths[tag] - 1} fields, got {len(f) - 1}")
            pose = int(f[1])
            if tag != "joints" and (current is None or current.pose != pose):
                raise ValueError(f"{tag} for pose {pose} before its joints line")
            if tag in ("probe", "centre") and f[2] not in balls:
                raise ValueError(f"unknown ball {f[2]!r} (dataset.yaml has {', '.join(balls)})")
            values = [float(v) for v in f[3 if tag in ("probe", "centre") else 2:]]
            if not all(np.isfinite(values)):
                raise ValueError("a number is not finite")
        except ValueError as exc:
            warn(f"stdin: line {n} skipped: {exc}")
            continue
        if tag == "joints":
            if current is not None:
                yield current
            current = PoseData(pose, np.radians(values))
        elif tag == "probe":
            pts = dict(current.probes)
            pts[f[2]] = np.vstack([pts.get(f[2], np.zeros((0, 3))), values])
            current.probes = list(pts.items())
        elif tag == "centre":
            current.centres.append((f[2], np.array(values)))
        elif tag == "pose":
            q = np.array(values[3:])
            if abs(np.linalg.norm(q) - 1) > 1e-3:
                warn(f"stdin: line {n} skipped: quaternion norm {np.linalg.norm(q):.6g}, expected 1")
                continue
            current.T = pose_matrices(values[:3], q)
        else:  # end
            yield current
            current = None
    if current is not None:
        yield current

log = logging.getLogger(__name__)
CHECKPOINT_FORMAT = "fgcal-online-checkpoint/1"


@dataclass
class OnlineRun:
    """One engine fed with a dataset's poses in order, with a checkpoint file.

    Attributes
    ----------
    history : list of dict
        After each accepted pose: ``{"pose", "n", "estimate" (file units), "sigma"}``.
    """

    ds: Dataset
    model: RobotModel
    engine_kind: str
    checkpoint: Path | None = None
    options: CalibrationOptions = field(default_factory=CalibrationOptions)
    processed: list[dict] = field(default_factory=list)
    history: list[dict] = field(default_factory=list)
    engine_kw: dict = field(default_factory=dict)
    streamed: dict = field(default_factory=dict)  # pose -> PoseData received from a stream

    def __post_init__(self):
        self.engine = make_engine(self.engine_kind, self.ds, self.model, self.options, **self.engine_kw)

    # ------------------------------------------------------------- checkpoints
    def _state(self) -> dict:
        d = {"format": CHECKPOINT_FORMAT, "engine": self.engine_kind,
             "dataset": str(Path(self.ds.path).resolve()) if self.ds.path else None,
             "processed": self.processed, "history": self.history,
             "streamed": [_record_to_json(r) for r in self.streamed.values()]}
        if hasattr(self.engine, "state"):
            d["state"] = self.engine.state()
        return d

    def save(self) -> None:
        if self.checkpoint is not None:
            atomic_write_text(self.checkpoint, json.dumps(self._state()) + "\n")

    def resume(self) -> int:
        """Restore from the checkpoint if there is one; returns the number of poses restored."""
        if self.checkpoint is None or not self.checkpoint.exists():
            return 0
        try:
            d = json.loads(self.checkpoint.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise FgcalError(f"{self.checkpoint}: unreadable checkpoint ({exc}); remove it or use --restart") from None
        if d.get("format") != CHECKPOINT_FORMAT or d.get("engine") != self.engine_kind:
            raise FgcalError(f"{self.checkpoint}: a checkpoint of another engine or format "
                             f"({d.get('engine')!r}); remove it or use --restart")
        here = str(Path(self.ds.path).resolve()) if self.ds.path else None
        if d.get("dataset") != here:
            raise FgcalError(f"{self.checkpoint}: written for {d.get('dataset')}, not {here}; use --restart")
        self.streamed = {int(r["pose"]): _record_from_json(r) for r in d.get("streamed", [])}
        records = {r.pose: r for r in pose_records(self.ds)}
        records.update(self.streamed)
        missing = [p["pose"] for p in d["processed"] if p["pose"] not in records]
        if missing:
            raise FgcalError(f"{self.checkpoint}: pose(s) {missing[:5]} are no longer in the dataset; use --restart")
        if "state" in d and hasattr(self.engine, "restore"):
            self.engine.restore(d["state"], sum(p["accepted"] for p in d["processed"]))
        else:  # iSAM2: replay the accepted poses, in order
            for p in d["processed"]:
                if p["accepted"]:
                    report = self.engine.update(records[p["pose"]])
                    if not report.accepted:
                        raise FgcalError(f"{self.checkpoint}: replaying pose {p['pose']} failed ({report.reason})")
        self.processed = list(d["processed"])
        self.history = list(d.get("history", []))
        return len(self.processed)

    # ------------------------------------------------------------- feeding
    def pending(self, ds: Dataset | None = None):
        done = {p["pose"] for p in self.processed}
        return [r for r in pose_records(ds or self.ds) if r.pose not in done]

    def feed(self, rec, streamed: bool = False) -> dict:
        if streamed:
            if rec.pose in {p["pose"] for p in self.processed}:
                return {"pose": rec.pose, "accepted": False, "reason": "already processed (ignored)"}
            self.streamed[rec.pose] = rec
        report = self.engine.update(rec)
        entry = {"pose": rec.pose, "accepted": report.accepted, "reason": report.reason}
        self.processed.append(entry)
        if report.accepted:
            theta, cov = self.engine.estimate()
            params = self.engine.params
            self.history.append({"pose": rec.pose, "n": self.engine.n_accepted,
                                 "estimate": params.to_file_units(theta).tolist(),
                                 "sigma": np.sqrt(np.diag(params.covariance_to_file_units(cov))).tolist()})
        self.save()
        return entry

    def result(self) -> CalibrationResult:
        self.engine.finish()
        theta, cov = self.engine.estimate()
        params = self.engine.params
        slots = params.full(theta, self.engine.held)
        cov_file = params.covariance_to_file_units(cov)
        sigma = np.sqrt(np.diag(cov_file))
        accepted = [p["pose"] for p in self.processed if p["accepted"]]
        return CalibrationResult(
            robot=self.model.name, n_poses=len(accepted),
            parameters=[ParameterEstimate(n, u, float(a), float(b), float(s)) for n, u, a, b, s in
                        zip(params.names, params.units, params.to_file_units(params.nominal()),
                            params.to_file_units(theta), sigma)],
            covariance=cov_file, slots={n: float(v) for n, v in zip(SLOT_NAMES, slots_to_file_units(slots))},
            iterations=len(self.processed), converged=True, pose_ids=accepted,
            options={"engine": self.engine_kind, "prior": "weak",
                     "rejected": [p for p in self.processed if not p["accepted"]]},
            dataset=str(self.ds.path) if self.ds.path else None, fgcal_version=__version__,
            robot_model=model_to_dict(self.model))


class Display:
    """After each pose: a redrawn table on a terminal, one plain line otherwise."""

    def __init__(self, run: OnlineRun, stream=None, rows: int = 6):
        self.run = run
        self.stream = stream or sys.stdout
        self.tty = self.stream.isatty()
        self.rows = rows
        self._drawn = 0

    def show(self, entry: dict, total: int | None = None) -> None:
        run = self.run
        params = run.engine.params
        theta, cov = run.engine.estimate()
        est = params.to_file_units(theta)
        sig = np.sqrt(np.diag(params.covariance_to_file_units(cov)))
        prior = params.to_file_units(run.engine.prior_sigma)
        rel = sig / prior  # 1: the data have said nothing yet; small: well determined
        order = np.argsort(-rel)[: self.rows]
        n = run.engine.n_accepted
        where = f"{len(run.processed)}/{total}" if total else str(len(run.processed))
        status = "accepted" if entry["accepted"] else f"REJECTED: {entry['reason']}"
        worst = int(np.argmax(rel))
        head = (f"pose {entry['pose']} ({where}) {status}; {n} poses in the estimate; largest sigma "
                f"{params.names[worst]} {sig[worst]:.3g} {params.units[worst]} ({rel[worst]:.2%} of its prior)")
        if not self.tty:
            print(head, file=self.stream, flush=True)
            return
        lines = [head, f"  {'most uncertain':14s} {'estimate':>14s} {'sigma':>10s}  of prior"]
        lines += [f"  {params.names[i]:14s} {est[i]:14.6f} {sig[i]:10.3g}  {rel[i]:7.2%} {params.units[i]}"
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
    path = Path(run.ds.path)
    last_change = time.monotonic()
    last_sig = None
    while stop is None or not stop():
        sig = tuple((f.name, f.stat().st_mtime_ns, f.stat().st_size) for f in sorted(path.glob("*.csv")))
        if sig != last_sig:
            last_sig, last_change = sig, time.monotonic()
        try:
            ds = load_dataset(path)
        except DatasetError as exc:
            log.info("waiting: %s", exc)
            time.sleep(interval)
            continue
        run.ds = ds
        run.engine.ds = ds
        pending = run.pending(ds)
        settled = time.monotonic() - last_change >= settle
        for rec in pending:
            is_last = rec.pose == int(ds.pose_ids[-1])
            if is_last and not settled:
                break
            display.show(run.feed(rec))
        time.sleep(interval)
