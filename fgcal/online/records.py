"""One pose's measurements as the online engines take them, and back to a dataset or to JSON."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fgcal.errors import FgcalError
from fgcal.measurements.dataset import Dataset, DistanceObservations, PointObservations, PoseObservations
from fgcal.measurements.types import BY_LEVEL, kinematic_types
from fgcal.robots.transforms import matrix_to_quaternion, pose_matrices

__all__ = [
    "PoseData",
    "generic_types",
    "pose_records",
    "record_from_json",
    "record_to_json",
    "records_dataset",
    "setup_types",
]

BUILT_IN = ("centres", "poses", "distances")  # the kinematic levels PoseData holds in fields of their own


def setup_types() -> list:
    """The registered measurement types that depend on set-up blocks (``uses_setup``)."""
    return [k for k in kinematic_types() if getattr(k, "uses_setup", False)]


def generic_types() -> list:
    """The registered kinematic types taken through the measurement protocol alone (not a built-in
    level, no set-up blocks): a pose carries their rows in :attr:`PoseData.generic`."""
    return [k for k in kinematic_types() if not getattr(k, "uses_setup", False) and k.level not in BUILT_IN]


def _values(obs) -> np.ndarray:
    """The observations' values (M, k) as the type's ``observations`` takes them: its row arrays
    (``ROW_SHAPES``) side by side, in their order."""
    n = len(obs)
    cols = [np.asarray(getattr(obs, name), dtype=float).reshape(n, -1) for name in type(obs).ROW_SHAPES]
    return np.hstack(cols) if cols else np.zeros((n, 0))


@dataclass
class PoseData:
    """Everything measured at one pose (file order): joints (rad) and the levels present."""

    pose: int
    q: np.ndarray
    probes: list[tuple[str, np.ndarray]] = field(default_factory=list)  # (ball, points (n, 3))
    centres: list[tuple[str, np.ndarray]] = field(default_factory=list)  # (ball, xyz (3,))
    T: np.ndarray | None = None
    distances: list[tuple[str, float]] = field(default_factory=list)  # (ball, ballbar length mm)
    # (level, ball, fixture): the ball at a set-up block (a measurement type with ``uses_setup``)
    contacts: list[tuple[str, str, str]] = field(default_factory=list)
    # (level, ball, block, values (k,)): a measurement of a set-up type that carries values, as the
    # type's ``block_observations`` takes them (a centre (3,) mm measured from a station, its frame)
    block_rows: list[tuple[str, str, str, np.ndarray]] = field(default_factory=list)
    # (level, ball or "", values (k,)): a measurement of a type of :func:`generic_types`, its values as
    # the type's ``observations`` takes them
    generic: list[tuple[str, str, np.ndarray]] = field(default_factory=list)
    # probe index -> (its points, plain SphereFit, its mirror image (3,), narrow cap), from :func:`prefit`
    fits: dict | None = field(default=None, repr=False, compare=False)

    def measured(self) -> bool:
        return bool(self.probes or self.centres or self.T is not None or self.distances or self.contacts
                    or self.generic or self.block_rows)


def _rows_by_pose(obs, pose_ids):
    """Row indices of ``obs`` per pose id, in file order: one sort, not one scan per pose."""
    if obs is None:
        return {}
    order = np.argsort(obs.pose, kind="stable")
    sorted_pose = obs.pose[order]
    lo = np.searchsorted(sorted_pose, pose_ids, side="left")
    hi = np.searchsorted(sorted_pose, pose_ids, side="right")
    return {int(p): order[a:z] for p, a, z in zip(pose_ids, lo, hi)}


READ_LEVELS = ("probes", "centres", "poses", "distances")  # the built-in levels pose_records reads


def carries_values(kind) -> bool:
    """Whether a set-up type's rows carry measured values (a station's centres) besides the block
    they depend on (a contact: only the fixture); such rows are kept in :attr:`PoseData.block_rows`."""
    return hasattr(kind, "block_observations")


def online_setup(kind) -> bool:
    """Whether the online engines take a set-up type: contacts to fixture points or planes (the
    block alone), or a type whose rows carry values and whose blocks start from a fit of them
    (:func:`carries_values`: a station's centres, a camera's pixels)."""
    return getattr(kind, "fixture_type", None) in ("point", "plane") or carries_values(kind)


def row_labels(kind, obs) -> np.ndarray:
    """What a set-up type's row keeps as its ball (M,): the ball, or the type's own label (a pixel's point)."""
    return kind.row_labels(obs) if hasattr(kind, "row_labels") else obs.ball


def row_values(kind, obs) -> np.ndarray:
    """A set-up type's measured values (M, k): the type's own (a pixel's u, v) or its row arrays."""
    return np.asarray(kind.row_values(obs), dtype=float) if hasattr(kind, "row_values") else _values(obs)


def block_observations(kind, pose, labels, blocks, values, setup):
    """The type's ``block_observations`` of rows (``setup``: the dataset's SetupSpec, for a type
    that needs the specs of its blocks: a camera's pixels)."""
    if getattr(kind, "block_specs", False):
        return kind.block_observations(pose, labels, blocks, values, specs=dict(setup.fixtures))
    return kind.block_observations(pose, labels, blocks, values)


def read_levels() -> tuple:
    """What :func:`pose_records` reads: the built-in levels, the registered set-up types the online
    engines take (:func:`online_setup`: fixture points, planes, stations) and every other
    registered type (taken through the measurement protocol, :func:`generic_types`)."""
    return (READ_LEVELS + tuple(k.level for k in setup_types() if online_setup(k))
            + tuple(k.level for k in generic_types()))


def pose_records(ds: Dataset, levels=None, poses=None, model=None) -> list[PoseData]:
    """The dataset's poses in ``joints.csv`` order with their measurements (``levels`` to choose).

    ``poses``: only these pose ids (the others are not read). Linear in the dataset's size.
    ``model`` converts the readings (prismatic joints are mm); all revolute without it.
    """
    levels = ds.levels() if levels is None else list(levels)
    unsupported = [lv for lv in levels if lv in BY_LEVEL and getattr(BY_LEVEL[lv], "uses_setup", False)
                   and not online_setup(BY_LEVEL[lv])]
    if unsupported:
        raise FgcalError(f"{ds.path or 'dataset'}: the online engines do not take {', '.join(unsupported)} yet: "
                         "use fgcal calibrate")
    ids = np.asarray(ds.pose_ids, dtype=int)
    keep = np.ones(len(ids), bool) if poses is None else np.isin(ids, np.fromiter(poses, dtype=int))
    ids = ids[keep]
    joints = (model.joints_to_internal(ds.joints_deg) if model is not None else ds.joints_rad)[keep]
    probes = _rows_by_pose(ds.probes, ids) if "probes" in levels else {}
    centres = _rows_by_pose(ds.centres, ids) if "centres" in levels else {}
    pose_rows = _rows_by_pose(ds.poses, ids) if "poses" in levels else {}
    distance_rows = _rows_by_pose(ds.distances, ids) if "distances" in levels else {}
    setup_rows = {k.level: _rows_by_pose(getattr(ds, k.level), ids) for k in setup_types() if k.level in levels}
    generic_rows: dict[str, tuple] = {}
    for k in generic_types():
        obs = getattr(ds, k.level, None) if k.level in levels else None
        if obs is not None:
            balls = obs.ball if hasattr(obs, "ball") else np.full(len(obs), "")
            generic_rows[k.level] = (_rows_by_pose(obs, ids), balls, _values(obs))
    out = []
    for pid, q in zip(ids.tolist(), joints):
        rec = PoseData(pid, q)
        if probes and ds.probes is not None:
            rows = probes[pid]
            balls = ds.probes.ball[rows]
            for b in dict.fromkeys(balls.tolist()):
                rec.probes.append((b, ds.probes.xyz[rows[balls == b]]))
        if centres and ds.centres is not None:
            rec.centres += [(str(ds.centres.ball[i]), ds.centres.xyz[i]) for i in centres[pid]]
        if pose_rows and len(pose_rows[pid]) and ds.poses is not None:
            i = pose_rows[pid][0]
            rec.T = pose_matrices(ds.poses.xyz[i], ds.poses.quat[i])
        if distance_rows and ds.distances is not None:
            rec.distances += [(str(ds.distances.ball[i]), float(ds.distances.length[i])) for i in distance_rows[pid]]
        for level, rows in setup_rows.items():
            obs = getattr(ds, level)
            blocks = BY_LEVEL[level].blocks_of(obs)
            if carries_values(BY_LEVEL[level]):
                labels, values = row_labels(BY_LEVEL[level], obs), row_values(BY_LEVEL[level], obs)
                rec.block_rows += [(level, str(labels[i]), str(blocks[i]), values[i]) for i in rows[pid]]
            else:
                rec.contacts += [(level, str(obs.ball[i]), str(blocks[i])) for i in rows[pid]]
        for level, (rows, balls, values) in generic_rows.items():
            rec.generic += [(level, str(balls[i]), values[i]) for i in rows[pid]]
        out.append(rec)
    return out


def records_dataset(meta: Dataset, records: list[PoseData], model=None) -> Dataset:
    """A dataset (robot, tool and noise of ``meta``) holding the poses ``records``."""
    probed = [(r.pose, b, pts) for r in records for b, pts in r.probes if len(pts)]  # (pose, ball, points (k, 3))
    centres = [(r.pose, b, c) for r in records for b, c in r.centres]
    poses = [(r.pose, r.T) for r in records if r.T is not None]
    distances = [(r.pose, b, v) for r in records for b, v in r.distances]
    q = np.array([r.q for r in records]).reshape(len(records), -1)
    setup_levels = {}
    for kind in setup_types():
        if carries_values(kind):
            vrows = [(r.pose, b, f, v) for r in records for lv, b, f, v in r.block_rows if lv == kind.level]
            if vrows:
                setup_levels[kind.level] = block_observations(
                    kind, np.array([p for p, _, _, _ in vrows], dtype=int), np.array([b for _, b, _, _ in vrows]),
                    np.array([f for _, _, f, _ in vrows]), np.array([v for _, _, _, v in vrows], dtype=float),
                    meta.setup)
            continue
        contact_rows = [(r.pose, b, f) for r in records for lv, b, f in r.contacts if lv == kind.level]
        if contact_rows:
            setup_levels[kind.level] = kind.observations(np.array([p for p, _, _ in contact_rows], dtype=int),
                                                         np.array([b for _, b, _ in contact_rows]),
                                                         np.array([f for _, _, f in contact_rows]))
    for kind in generic_types():  # rebuilt through the type's own observations
        type_rows = [(r.pose, b, v) for r in records for lv, b, v in r.generic if lv == kind.level]
        if type_rows:
            setup_levels[kind.level] = kind.observations(
                np.array([p for p, _, _ in type_rows], dtype=int), np.array([b for _, b, _ in type_rows]),
                np.array([v for _, _, v in type_rows], dtype=float).reshape(len(type_rows), -1))

    def points(rows):
        if not rows:
            return None
        return PointObservations(np.array([p for p, _, _ in rows], dtype=int), np.array([b for _, b, _ in rows], dtype=str),
                                 np.array([x for _, _, x in rows]).reshape(-1, 3))

    out = Dataset(robot=meta.robot, tooling=meta.tooling, noise=meta.noise, provenance=dict(meta.provenance),
                  pose_ids=np.array([r.pose for r in records], dtype=int),
                  joints_deg=model.joints_to_file_units(q) if model is not None else np.degrees(q),
                  probes=_probe_points(probed), centres=points(centres),
                  poses=PoseObservations(np.array([p for p, _ in poses], dtype=int), np.array([T[:3, 3] for _, T in poses]),
                                         matrix_to_quaternion(np.array([T[:3, :3] for _, T in poses])))
                  if poses else None,
                  distances=DistanceObservations(np.array([p for p, _, _ in distances], dtype=int),
                                                 np.array([b for _, b, _ in distances], dtype=str),
                                                 np.array([v for _, _, v in distances], dtype=float))
                  if distances else None,
                  path=meta.path, chain=meta.chain, setup=meta.setup, world_station=meta.world_station,
                  stations=_stations(meta, records))
    for level, obs in setup_levels.items():
        setattr(out, level, obs)
    return out


def _probe_points(probed) -> PointObservations | None:
    """The probe points of ``probed`` ((pose, ball, points (k, 3)) per probed ball, k > 0) as one
    table, a row per point in that order; None without any."""
    if not probed:
        return None
    counts = [len(pts) for _, _, pts in probed]
    return PointObservations(np.repeat(np.array([p for p, _, _ in probed], dtype=int), counts),
                             np.repeat(np.array([b for _, b, _ in probed], dtype=str), counts),
                             np.concatenate([np.asarray(pts, dtype=float).reshape(-1, 3) for _, _, pts in probed]))


def _stations(meta: Dataset, records: list[PoseData]):
    """The station of each of ``records`` (N,): that of a pose measured from a station, else the
    world's; None when ``meta`` has no stations."""
    if meta.world_station is None:
        return None
    of = {} if meta.stations is None else dict(zip(np.asarray(meta.pose_ids).tolist(), meta.stations.tolist()))
    for r in records:
        for _, _, block, _ in r.block_rows:
            if meta.setup.kind_of(block) == "station":
                of[r.pose] = block
    return np.array([of.get(r.pose, meta.world_station) for r in records], dtype=str)


def _variant(rec: PoseData, taken: dict) -> PoseData:
    """The pose as taken (``taken["drop"]``: one probe point left out)."""
    if not taken.get("drop"):
        return rec
    j, k = taken["drop"]
    out = PoseData(rec.pose, rec.q, list(rec.probes), list(rec.centres), rec.T, list(rec.distances),
                   list(rec.contacts), list(rec.block_rows), list(rec.generic),
                   None if rec.fits is None else dict(rec.fits))
    ball, pts = rec.probes[j]
    out.probes[j] = (ball, np.delete(pts, k, axis=0))
    return out


def record_to_json(rec: PoseData) -> dict:
    out = {"pose": rec.pose, "q": rec.q.tolist(), "probes": [[b, p.tolist()] for b, p in rec.probes],
           "centres": [[b, c.tolist()] for b, c in rec.centres], "T": None if rec.T is None else rec.T.tolist(),
           "distances": [[b, float(v)] for b, v in rec.distances],
           "contacts": [[lv, b, f] for lv, b, f in rec.contacts]}
    if rec.block_rows:  # (level, ball, block, values) of the set-up types that carry values
        out["block_rows"] = [[lv, b, f, np.asarray(v, dtype=float).tolist()] for lv, b, f, v in rec.block_rows]
    if rec.generic:  # (level, ball, values) of the types taken through the protocol
        out["generic"] = [[lv, b, np.asarray(v, dtype=float).tolist()] for lv, b, v in rec.generic]
    return out


def record_from_json(d: dict) -> PoseData:
    return PoseData(int(d["pose"]), np.array(d["q"], dtype=float),
                    [(b, np.array(p, dtype=float)) for b, p in d["probes"]],
                    [(b, np.array(c, dtype=float)) for b, c in d["centres"]],
                    None if d["T"] is None else np.array(d["T"], dtype=float),
                    [(b, float(v)) for b, v in d.get("distances", [])],
                    [(str(lv), str(b), str(f)) for lv, b, f in d.get("contacts", [])],
                    [(str(lv), str(b), str(f), np.array(v, dtype=float)) for lv, b, f, v in d.get("block_rows", [])],
                    [(str(lv), str(b), np.array(v, dtype=float)) for lv, b, v in d.get("generic", [])])
