"""Running an online engine over a dataset: checkpoints, following a growing dataset, display.

The engine's state is checkpointed (JSON, atomically) after every pose, so a run that crashes or
is interrupted resumes where it stopped and ends with the same result as an uninterrupted one:
a filter's state is stored as it is; iSAM2 (whose graph cannot be pickled) is rebuilt by
replaying the accepted poses in the same order.
"""
from __future__ import annotations

import json
import logging
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fgcal._version import __version__
from fgcal.errors import FgcalError
from fgcal.estimation.options import CalibrationOptions
from fgcal.estimation.result import CalibrationResult, ParameterEstimate
from fgcal.estimation.setup_params import SetupParameters
from fgcal.measurements.dataset import Dataset
from fgcal.online.checkpoint import CHECKPOINT_FORMAT, INPUT_NAMES, SNAPSHOT_EVERY, read_checkpoint, read_snapshot
from fgcal.online.engines import make_engine, pose_records, prefit
from fgcal.online.records import record_from_json, record_to_json
from fgcal.robots.model import ParameterSet, RobotModel
from fgcal.robots.robot_file import model_to_dict
from fgcal.util.yamlio import atomic_write_text

__all__ = ["SNAPSHOT_EVERY", "SYNC_INTERVAL", "OnlineRun"]

log = logging.getLogger(__name__)

# Seconds between two flushes of the journal to the disk: an fsync per pose cost a third of the
# EKF's step; what only the page cache holds survives the process, not a power loss.
SYNC_INTERVAL = 0.5


@dataclass
class OnlineRun:
    """One engine fed with a dataset's poses in order, with a checkpoint file.

    The checkpoint is an append-only journal (one JSON line per pose, written to the file before
    the next pose is taken, so that a crash or an interrupt of the process loses nothing; flushed
    to the disk with ``fsync`` at once for a streamed pose (its record is nowhere else), else at
    most every :data:`SYNC_INTERVAL` seconds while poses come, before each snapshot, when the run
    ends and when it waits for a followed dataset: a power loss may cost the poses of the last
    interval, which a resume then takes again) under an exclusive lock,
    plus, for the filters, a snapshot of the state every :data:`SNAPSHOT_EVERY` poses
    (``CHECKPOINT.snapshot``, written atomically). Resuming restores the snapshot and replays the
    poses journalled after it (iSAM2, whose graph cannot be stored, replays all accepted poses):
    the result is the uninterrupted run's.

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
    restart: bool = False
    last_estimate: tuple | None = None  # (theta, covariance) after the last accepted pose

    def __post_init__(self):
        self.engine = make_engine(self.engine_kind, self.ds, self.model, self.options, **self.engine_kw)
        self._fd = None
        self._synced = time.monotonic()  # when the journal was last flushed to the disk
        self._unsynced = False
        self._done = {p["pose"] for p in self.processed}
        self._is_angle = self.engine.params.is_angle
        self._file_units = None
        if self.checkpoint is not None:
            self.checkpoint = Path(self.checkpoint)
            self._open()

    # ------------------------------------------------------------- checkpoints
    @property
    def snapshot_path(self) -> Path:
        return Path(f"{self.checkpoint}.snapshot")

    def _dataset_key(self):
        return str(Path(self.ds.path).resolve()) if self.ds.path else None

    def _open(self) -> None:
        import fcntl

        ck = self.checkpoint
        assert ck is not None  # opened only with a checkpoint
        if self.ds.path is not None:
            folder = Path(self.ds.path).resolve()
            target = ck.resolve()
            if target.parent == folder and (target.name in INPUT_NAMES or target.suffix in (".csv", ".yaml")):
                raise FgcalError(f"{ck}: is an input file of the dataset; choose another --checkpoint")
        if ck.exists() and ck.stat().st_size:
            with open(ck, "rb") as fh:
                head = fh.readline()
            if b"fgcal-online-checkpoint/" not in head:
                raise FgcalError(f"{ck}: exists and is not an fgcal online checkpoint; it is not overwritten")
        try:
            self._fd = os.open(ck, os.O_RDWR | os.O_CREAT | os.O_APPEND, 0o666)
        except OSError as exc:
            raise FgcalError(f"{ck}: cannot open the checkpoint ({exc.strerror})") from None
        try:
            fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(self._fd)
            self._fd = None
            raise FgcalError(f"{ck}: in use by another fgcal online session") from None
        if self.restart:
            os.ftruncate(self._fd, 0)
            self.snapshot_path.unlink(missing_ok=True)
        if os.fstat(self._fd).st_size == 0:
            self._append({"format": CHECKPOINT_FORMAT, "engine": self.engine_kind, "dataset": self._dataset_key()})

    def close(self) -> None:
        """Release the checkpoint (its lock); the state stays on disk for a resume."""
        if self._fd is not None:
            if self._unsynced:  # (no clock here: close may run at interpreter exit, from __del__)
                os.fsync(self._fd)
                self._unsynced = False
            os.close(self._fd)
            self._fd = None

    def __del__(self):
        self.close()

    def _append(self, record: dict) -> None:
        os.write(self._fd, (json.dumps(record) + "\n").encode("utf-8"))
        self._unsynced = True
        if time.monotonic() - self._synced >= SYNC_INTERVAL:
            self.sync()

    def sync(self) -> None:
        """Flush what the journal has been given to the disk (``fsync``), if anything is pending."""
        if self._fd is not None and self._unsynced:
            os.fsync(self._fd)
            self._unsynced = False
        self._synced = time.monotonic()

    def _snapshot(self) -> None:
        if self.engine.snapshots:
            self.sync()  # the journal on the disk holds at least the poses the snapshot counts
            atomic_write_text(self.snapshot_path, json.dumps({"n": len(self.processed), "state": self.engine.state()}) + "\n")

    def save(self, journal: dict | None = None) -> None:
        """Journal the last pose (with the engine's ``journal`` of it, and the record when it came
        from a stream) and every :data:`SNAPSHOT_EVERY` poses a snapshot of a filter's state."""
        if self._fd is None:
            return
        entry = dict(self.processed[-1])
        entry.update(journal or {})
        if entry["accepted"]:
            entry["history"] = self.history[-1]
        streamed = entry["pose"] in self.streamed
        if streamed:
            entry["record"] = record_to_json(self.streamed[entry["pose"]])
        self._append(entry)
        if streamed:  # a streamed pose is nowhere else: on the disk before the next is taken
            self.sync()
        if len(self.processed) % SNAPSHOT_EVERY == 0:
            self._snapshot()

    def resume(self) -> int:
        """Restore from the checkpoint if there is one; returns the number of poses restored.

        A filter restores its last snapshot with the book-keeping of the poses journalled before
        it and replays the poses after it; iSAM2 adds every journalled pose again as it was taken
        (linear in the poses: no screening, no snapshot)."""
        if self._fd is None:
            return 0
        d = read_checkpoint(self.checkpoint)
        head = d["header"]
        if head.get("format") != CHECKPOINT_FORMAT or head.get("engine") != self.engine_kind:
            raise FgcalError(f"{self.checkpoint}: a checkpoint of another engine or format "
                             f"({head.get('engine')!r}, {head.get('format')!r}); remove it or use --restart")
        here = self._dataset_key()
        if head.get("dataset") != here:
            raise FgcalError(f"{self.checkpoint}: written for {head.get('dataset')}, not {here}; use --restart")
        entries = d["entries"]
        if not entries:
            return 0
        self.streamed = {int(e["pose"]): record_from_json(e["record"]) for e in entries if "record" in e}
        wanted = {e["pose"] for e in entries}
        records = {r.pose: r for r in pose_records(self.ds, poses=wanted, model=self.model)}
        prefit(list(records.values()), self.ds.tooling, self.ds.noise.cmm_sigma)
        records.update(self.streamed)
        missing = [e["pose"] for e in entries if e["pose"] not in records]
        if missing:
            raise FgcalError(f"{self.checkpoint}: pose(s) {missing[:5]} are no longer in the dataset; use --restart")
        journal = [(records[e["pose"]], e) for e in entries]
        start = 0
        if not self.engine.snapshots:
            self.engine.restore(None, journal)
            start = len(entries)
        elif self.snapshot_path.exists():
            snap = read_snapshot(self.snapshot_path)
            if snap["n"] <= len(entries):
                self.engine.restore(snap["state"], journal[:snap["n"]])
                start = snap["n"]
        for rec, e in journal[start:]:  # replay what the snapshot does not hold, in order
            report = self.engine.update(rec)
            if report.accepted != e["accepted"]:
                raise FgcalError(f"{self.checkpoint}: replaying pose {e['pose']} gave another outcome "
                                 f"({report.reason}); use --restart")
        self._is_angle = self.engine.params.is_angle  # a snapshot may bring its own parameters
        self.processed = [{k: e[k] for k in ("pose", "accepted", "reason")} for e in entries]
        self._done = {e["pose"] for e in entries}
        self.history = [e["history"] for e in entries if e["accepted"]]
        if self.engine.n_accepted:
            self.last_estimate = self.engine.estimate()
            self._file_units = None
        return len(self.processed)

    # ------------------------------------------------------------- feeding
    def pending(self, ds: Dataset | None = None):
        ds = ds or self.ds
        records = pose_records(ds, poses=[int(p) for p in ds.pose_ids if int(p) not in self._done], model=self.model)
        prefit(records, ds.tooling, ds.noise.cmm_sigma)  # every sphere fit at once, vectorised
        return records

    def feed(self, rec, streamed: bool = False) -> dict:
        if streamed:
            if rec.pose in self._done:
                return {"pose": rec.pose, "accepted": False, "reason": "already processed (ignored)"}
            self.streamed[rec.pose] = rec
        report = self.engine.update(rec)
        entry = {"pose": rec.pose, "accepted": report.accepted, "reason": report.reason}
        self.processed.append(entry)
        self._done.add(rec.pose)
        if report.accepted:
            self.last_estimate = self.engine.estimate()
            self._file_units = None
            est, sig = self.estimate_file_units()
            self.history.append({"pose": rec.pose, "n": self.engine.n_accepted, "estimate": est.tolist(),
                                 "sigma": sig.tolist()})
        self.save(report.journal)
        return entry

    def estimate(self):
        """``(theta, covariance)`` now (kept from the last accepted pose: no second evaluation)."""
        if self.last_estimate is None:
            self.last_estimate = self.engine.estimate()
            self._file_units = None
        return self.last_estimate

    def estimate_file_units(self):
        """``(estimate (P,), sigma (P,))`` now, in file units (mm, deg); computed once a pose."""
        if self._file_units is None:
            theta, cov = self.estimate()
            self._file_units = (np.where(self._is_angle, np.degrees(theta), theta),
                                np.where(self._is_angle, np.degrees(1.0), 1.0) * np.sqrt(np.diag(cov)))
        return self._file_units

    def result(self) -> CalibrationResult:
        self.sync()
        self.engine.finish()
        theta, cov = self.engine.estimate()
        params = self.engine.params
        slots = params.full(theta, self.engine.held)
        held = self.engine.held_info()  # as the batch holds them (fgcal.online.base._Engine._smooth)
        gone = {h["name"] for h in held}
        keep = [i for i, n in enumerate(params.names) if n not in gone]
        x, cov_all, layout = self.engine.estimate_all()
        kept: ParameterSet | SetupParameters = ParameterSet(self.model, tuple(params.names[i] for i in keep))
        if layout is not None:  # the set-up blocks' free entries follow, as the batch names them
            keep += list(range(len(params), len(x)))
            kept = SetupParameters(kept, layout)
        theta, cov = x[keep], cov_all[np.ix_(keep, keep)]
        params = kept
        cov_file = params.covariance_to_file_units(cov)
        cov_file = 0.5 * (cov_file + cov_file.T)  # symmetric but for rounding
        sigma = np.sqrt(np.diag(cov_file))
        accepted = [p["pose"] for p in self.processed if p["accepted"]]
        # The final smoothing judges every pose again (one refused against an early, poor estimate,
        # such as a ballbar's before its pivot is known, may be taken): its poses are the result's.
        smoothed = getattr(self.engine, "final_pose_ids", None)
        if smoothed:
            accepted = list(smoothed)
        return CalibrationResult(
            robot=self.model.name, n_poses=len(accepted),
            parameters=[ParameterEstimate(n, u, float(a), float(b), float(s)) for n, u, a, b, s in
                        zip(params.names, params.units, params.to_file_units(params.nominal()),
                            params.to_file_units(theta), sigma)],
            covariance=cov_file, slots={n: float(v) for n, v in zip(self.model.slot_names,  # the model's own names
                                                                  self.model.slots_to_file_units(slots))},
            held=held, iterations=len(self.processed), converged=True, pose_ids=accepted,
            options={"engine": self.engine_kind, "prior": "weak",
                     "rejected": [p for p in self.processed if not p["accepted"] and p["pose"] not in set(accepted)],
                     "refused_while_running": [p["pose"] for p in self.processed if not p["accepted"]]},
            dataset=str(self.ds.path) if self.ds.path else None, fgcal_version=__version__,
            robot_model=model_to_dict(self.model), setup=self.engine.setup_info())
