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
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fgcal import __version__
from fgcal.estimation.calibrate import CalibrationOptions
from fgcal.measurements.dataset import Dataset
from fgcal.io.dataset_io import load_dataset
from fgcal.errors import DatasetError, FgcalError
from fgcal.robots.model import SLOT_NAMES, RobotModel, slots_to_file_units
from fgcal.online.engines import PoseData, make_engine, pose_records
from fgcal.estimation.result import CalibrationResult, ParameterEstimate
from fgcal.robots.robot_file import model_to_dict
from fgcal.io.yamlio import atomic_write_text

__all__ = ["OnlineRun", "CHECKPOINT_FORMAT", "read_stream", "STREAM_FORMAT", "read_checkpoint", "default_checkpoint"]

STREAM_FORMAT = """\
One record a line, comma-separated (lines starting with # and blank lines are ignored):
  joints,POSE,q1,...,qn              joint readings (deg; mm for prismatic joints); starts pose POSE
  probe,POSE,BALL,x,y,z              a probe point (mm, world)
  centre,POSE,BALL,x,y,z             a ball centre (mm, world)
  pose,POSE,x,y,z,qw,qx,qy,qz        a measured tool pose (mm, unit quaternion)
  distance,POSE,BALL,length          a ballbar length from the pivot (world origin) to BALL (mm)
  end,POSE                           POSE is complete (so is it when the next pose's joints come)"""


def _record_to_json(rec: PoseData) -> dict:
    return {"pose": rec.pose, "q": rec.q.tolist(), "probes": [[b, p.tolist()] for b, p in rec.probes],
            "centres": [[b, c.tolist()] for b, c in rec.centres], "T": None if rec.T is None else rec.T.tolist(),
            "distances": [[b, float(v)] for b, v in rec.distances]}


def _record_from_json(d: dict) -> PoseData:
    return PoseData(int(d["pose"]), np.array(d["q"], dtype=float),
                    [(b, np.array(p, dtype=float)) for b, p in d["probes"]],
                    [(b, np.array(c, dtype=float)) for b, c in d["centres"]],
                    None if d["T"] is None else np.array(d["T"], dtype=float),
                    [(b, float(v)) for b, v in d.get("distances", [])])


def read_stream(lines, balls, warn=None, model=None):
    """Pose records from a stream of lines (:data:`STREAM_FORMAT`), each as soon as it is complete.

    A malformed line is reported through ``warn(message)`` with its line number and skipped; the
    stream goes on (an operator's typo should not end a measuring session). ``model`` gives the
    number of joints and their units (six revolute joints without it).
    """
    from fgcal.robots.transforms import pose_matrices

    warn = warn or (lambda m: print(m, file=sys.stderr))
    current: PoseData | None = None
    n_joints = 6 if model is None else model.n_joints
    widths = {"joints": n_joints + 2, "probe": 6, "centre": 6, "pose": 9, "distance": 4, "end": 2}
    for n, raw in enumerate(lines, start=1):
        if isinstance(raw, bytes):
            try:
                raw = raw.decode("utf-8")
            except UnicodeDecodeError as exc:
                warn(f"stdin: line {n} skipped: not UTF-8 text (byte {raw[exc.start]:#04x} at column {exc.start + 1})")
                continue
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        f = [c.strip() for c in line.split(",")]
        tag = f[0]
        try:
            if tag not in widths:
                raise ValueError(f"unknown record {tag!r} (joints, probe, centre, pose, distance, end)")
            if len(f) != widths[tag]:
                raise ValueError(f"{tag} takes {widths[tag] - 1} fields, got {len(f) - 1}")
            pose = int(f[1])
            if tag != "joints" and (current is None or current.pose != pose):
                raise ValueError(f"{tag} for pose {pose} before its joints line")
            if tag in ("probe", "centre", "distance") and f[2] not in balls:
                raise ValueError(f"unknown ball {f[2]!r} (dataset.yaml has {', '.join(balls)})")
            values = [float(v) for v in f[3 if tag in ("probe", "centre", "distance") else 2:]]
            if not all(np.isfinite(values)):
                raise ValueError("a number is not finite")
        except ValueError as exc:
            warn(f"stdin: line {n} skipped: {exc}")
            continue
        if tag == "joints":
            if current is not None:
                yield current
            current = PoseData(pose, np.radians(values) if model is None else model.joints_to_internal(values))
        elif tag == "probe":
            pts = dict(current.probes)
            pts[f[2]] = np.vstack([pts.get(f[2], np.zeros((0, 3))), values])
            current.probes = list(pts.items())
        elif tag == "centre":
            current.centres.append((f[2], np.array(values)))
        elif tag == "distance":
            current.distances.append((f[2], float(values[0])))
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
CHECKPOINT_FORMAT = "fgcal-online-checkpoint/2"
SNAPSHOT_EVERY = 100  # poses between snapshots of a filter's state (the journal has every pose)
INPUT_NAMES = ("dataset.yaml", "truth.yaml", "joints.csv", "probes.csv", "centres.csv", "poses.csv", "distances.csv")


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


@dataclass
class OnlineRun:
    """One engine fed with a dataset's poses in order, with a checkpoint file.

    The checkpoint is an append-only journal (one JSON line per pose, flushed to disk with
    ``fsync`` before the next pose is taken: constant time per pose) under an exclusive lock,
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
            os.close(self._fd)
            self._fd = None

    def __del__(self):
        self.close()

    def _append(self, record: dict) -> None:
        os.write(self._fd, (json.dumps(record) + "\n").encode("utf-8"))
        os.fsync(self._fd)

    def _snapshot(self) -> None:
        if hasattr(self.engine, "state"):
            atomic_write_text(self.snapshot_path, json.dumps({"n": len(self.processed), "state": self.engine.state(),
                                                              "n_accepted": self.engine.n_accepted}) + "\n")

    def save(self) -> None:
        """Journal the last pose (and every :data:`SNAPSHOT_EVERY` poses a snapshot of the state)."""
        if self._fd is None:
            return
        entry = dict(self.processed[-1])
        if entry["accepted"]:
            entry["history"] = self.history[-1]
        if entry["pose"] in self.streamed:
            entry["record"] = _record_to_json(self.streamed[entry["pose"]])
        self._append(entry)
        if len(self.processed) % SNAPSHOT_EVERY == 0:
            self._snapshot()

    def resume(self) -> int:
        """Restore from the checkpoint if there is one; returns the number of poses restored."""
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
        self.streamed = {int(e["pose"]): _record_from_json(e["record"]) for e in entries if "record" in e}
        wanted = {e["pose"] for e in entries}
        records = {r.pose: r for r in pose_records(self.ds, poses=wanted, model=self.model)}
        records.update(self.streamed)
        missing = [e["pose"] for e in entries if e["pose"] not in records]
        if missing:
            raise FgcalError(f"{self.checkpoint}: pose(s) {missing[:5]} are no longer in the dataset; use --restart")
        start = 0
        if hasattr(self.engine, "restore") and self.snapshot_path.exists():
            snap = json.loads(self.snapshot_path.read_text(encoding="utf-8"))
            if snap["n"] <= len(entries):
                self.engine.restore(snap["state"], snap["n_accepted"])
                start = snap["n"]
        for e in entries[start:]:  # replay what the snapshot does not hold, in order
            if e["accepted"]:
                report = self.engine.update(records[e["pose"]])
                if not report.accepted:
                    raise FgcalError(f"{self.checkpoint}: replaying pose {e['pose']} failed ({report.reason})")
        self.processed = [{k: e[k] for k in ("pose", "accepted", "reason")} for e in entries]
        self.history = [e["history"] for e in entries if e["accepted"]]
        if self.engine.n_accepted:
            self.last_estimate = self.engine.estimate()
        return len(self.processed)

    # ------------------------------------------------------------- feeding
    def pending(self, ds: Dataset | None = None):
        done = {p["pose"] for p in self.processed}
        ds = ds or self.ds
        return pose_records(ds, poses=[int(p) for p in ds.pose_ids if int(p) not in done], model=self.model)

    def feed(self, rec, streamed: bool = False) -> dict:
        if streamed:
            if rec.pose in {p["pose"] for p in self.processed}:
                return {"pose": rec.pose, "accepted": False, "reason": "already processed (ignored)"}
            self.streamed[rec.pose] = rec
        report = self.engine.update(rec)
        entry = {"pose": rec.pose, "accepted": report.accepted, "reason": report.reason}
        self.processed.append(entry)
        if report.accepted:
            theta, cov = self.last_estimate = self.engine.estimate()
            params = self.engine.params
            self.history.append({"pose": rec.pose, "n": self.engine.n_accepted,
                                 "estimate": params.to_file_units(theta).tolist(),
                                 "sigma": np.sqrt(np.diag(params.covariance_to_file_units(cov))).tolist()})
        self.save()
        return entry

    def estimate(self):
        """``(theta, covariance)`` now (kept from the last accepted pose: no second evaluation)."""
        if self.last_estimate is None:
            self.last_estimate = self.engine.estimate()
        return self.last_estimate

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
        theta, cov = run.estimate()
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
        time.sleep(interval)
