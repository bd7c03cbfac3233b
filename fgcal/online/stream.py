"""Poses from a stream of text records (``fgcal online --stdin``)."""
from __future__ import annotations

import sys

import numpy as np

from fgcal.errors import DatasetError
from fgcal.io.skipped import bounded
from fgcal.measurements.cells import MAX_ID
from fgcal.measurements.distance import DISTANCE
from fgcal.measurements.point import POINT
from fgcal.measurements.pose import POSE
from fgcal.online.records import PoseData, setup_types

__all__ = ["STREAM_FORMAT", "read_stream"]

STREAM_FORMAT = """\
One record a line, comma-separated (lines starting with # and blank lines are ignored):
  joints,POSE,q1,...,qn              joint readings (deg; mm for prismatic joints); starts pose POSE
  probe,POSE,BALL,x,y,z              a probe point (mm, world)
  centre,POSE,BALL,x,y,z             a ball centre (mm, world)
  centre,POSE,BALL,x,y,z,STATION     a ball centre measured from STATION (mm, in its frame; a
                                     station of dataset.yaml's stations: other than the first)
  pose,POSE,x,y,z,qw,qx,qy,qz        a measured tool pose (mm, unit quaternion)
  distance,POSE,BALL,length          a ballbar length from the pivot (world origin) to BALL (mm)
  contact,POSE,BALL,FIXTURE          BALL seated at fixture point FIXTURE, or touching plane FIXTURE
                                     (a fixture of dataset.yaml's fixtures:)
  pixels,POSE,CAMERA,POINT,u,v       target point POINT seen by CAMERA at pixel (u, v) (px; a camera
                                     of dataset.yaml's cameras:, a point of one of its targets:)
  end,POSE                           POSE is complete (so is it when the next pose's joints come)"""

# A record's values are read by its measurement type's own parser, the one the dataset's files are
# read with: a value a file may not hold (a negative ballbar length, a quaternion not of norm 1,
# a point beyond the absurd-size bound) is refused on the stream too.
_PARSED = {"probe": (POINT, ("ball", "x", "y", "z")), "centre": (POINT, ("ball", "x", "y", "z")),
           "pose": (POSE, ("x", "y", "z", "qw", "qx", "qy", "qz")), "distance": (DISTANCE, ("ball", "length"))}


def _parsed(tag: str, fields: list, balls) -> np.ndarray:
    kind, names = _PARSED[tag]
    record = dict(zip(names, fields[2:], strict=True))
    try:
        return kind.parse("stdin", record, balls)[1]
    except DatasetError as exc:
        raise ValueError(str(exc).removeprefix("stdin: ")) from None


def read_stream(lines, balls, warn=None, model=None, setup=None):
    """Pose records from a stream of lines (:data:`STREAM_FORMAT`), each as soon as it is complete.

    A malformed line is reported through ``warn(message)`` with its line number and skipped; the
    stream goes on (an operator's typo should not end a measuring session). ``model`` gives the
    number of joints and their units (six revolute joints without it). ``setup`` (the dataset's
    :class:`~fgcal.measurements.setup.SetupSpec`) names the fixtures a contact may touch; the
    contact's level is that of the measurement type of the fixture's kind.
    """
    from fgcal.robots.transforms import pose_matrices

    warn = warn or (lambda m: print(f"warning: {m}", file=sys.stderr))  # the stream goes on: a warning line
    current: PoseData | None = None
    n_joints = 6 if model is None else model.n_joints
    widths = {"joints": n_joints + 2, "probe": 6, "centre": 6, "pose": 9, "distance": 4, "contact": 4, "pixels": 6,
              "end": 2}
    by_kind = {getattr(k, "fixture_type", None): k.level for k in setup_types()}
    stations = [n for n, f in getattr(setup, "fixtures", {}).items() if f.type == "station"]
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
                raise ValueError(f"unknown record {tag!r} (joints, probe, centre, pose, distance, contact, pixels, "
                                 "end)")
            station = f.pop() if tag == "centre" and len(f) == widths[tag] + 1 else None
            if len(f) != widths[tag]:
                raise ValueError(f"{tag} takes {widths[tag] - 1} fields"
                                 f"{' (and a station)' if tag == 'centre' else ''}, got {len(f) - 1}")
            if station is not None and (station not in stations or "station" not in by_kind):
                raise ValueError(f"unknown station {station!r} (dataset.yaml's stations after the first: "
                                 f"{', '.join(stations[:6]) or 'none'}; a centre from the first takes no station)")
            pose = int(f[1])
            if not 0 <= pose <= MAX_ID:
                raise ValueError(f"pose id {f[1][:30]} out of range (0 to 2^62)")
            if tag != "joints" and (current is None or current.pose != pose):
                raise ValueError(f"{tag} for pose {pose} before its joints line")
            if tag in ("probe", "centre", "distance", "contact") and f[2] not in balls:
                raise ValueError(f"unknown ball {f[2]!r} (dataset.yaml has {', '.join(balls)})")
            if tag == "contact":
                kind = None if setup is None else setup.kind_of(f[3])
                if kind not in by_kind:
                    names = ", ".join(list(getattr(setup, "fixtures", {}))[:6]) or "none"
                    raise ValueError(f"unknown fixture {f[3]!r} (dataset.yaml's fixtures: {names})")
                current.contacts.append((by_kind[kind], f[2], f[3]))
                continue
            if tag == "pixels":
                _check_corner(f[2], f[3], setup, "camera" in by_kind)
            if tag in _PARSED:
                values = _parsed(tag, f, balls).tolist()
            else:
                values = [float(v) for v in f[4 if tag == "pixels" else 2:]]
                if not all(np.isfinite(values)):
                    raise ValueError("a number is not finite")
        except ValueError as exc:
            warn(f"stdin: line {n} skipped: {bounded(str(exc))}")
            continue
        if tag == "joints":
            if current is not None:
                yield current
            current = PoseData(pose, np.radians(values) if model is None else model.joints_to_internal(values))
        elif tag == "probe":
            pts = dict(current.probes)
            pts[f[2]] = np.vstack([pts.get(f[2], np.zeros((0, 3))), values])
            current.probes = list(pts.items())
        elif tag == "centre" and station is not None:
            current.block_rows.append((by_kind["station"], f[2], station, np.array(values)))
        elif tag == "centre":
            current.centres.append((f[2], np.array(values)))
        elif tag == "distance":
            current.distances.append((f[2], float(values[0])))
        elif tag == "pixels":
            current.block_rows.append((by_kind["camera"], f[3], f[2], np.array(values)))
        elif tag == "pose":
            current.T = pose_matrices(values[:3], np.array(values[3:]))
        else:  # end
            yield current
            current = None
    if current is not None:
        yield current


def _check_corner(camera: str, point: str, setup, registered: bool) -> None:
    """Raise ValueError unless ``camera`` is one of ``setup``'s cameras and ``point`` a point of one of its targets."""
    fixtures = getattr(setup, "fixtures", {})
    cams = [n for n, f in fixtures.items() if f.type == "camera"]
    if camera not in cams or not registered:
        raise ValueError(f"unknown camera {camera!r} (dataset.yaml's cameras: {', '.join(cams[:6]) or 'none'})")
    if not any(f.type == "target" and point in f.points for f in fixtures.values()):
        raise ValueError(f"point {point!r} is a point of no target in dataset.yaml's targets:")
