"""``dataset.yaml``'s set-up sections (DESIGN.md 8.2, 8.3): ``fixtures:``, ``constraints:`` and
``stations:``, read with one-line errors naming the file and the entry, and written back.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fgcal.errors import DatasetError
from fgcal.measurements.dataset import Dataset
from fgcal.measurements.setup import DistanceConstraint, FixtureSpec, SetupSpec
from fgcal.util.yamlio import short_repr

__all__ = ["read_fixtures", "read_stations", "stations_dict"]


def read_fixtures(path: Path, data: dict, num) -> SetupSpec:
    """``fixtures:`` and ``constraints:`` of ``dataset.yaml`` (DESIGN.md 8.2)."""
    raw = data.get("fixtures") or {}
    if not isinstance(raw, dict):
        raise DatasetError(f"{path}: fixtures must be a mapping {{NAME: {{type: point|plane, ...}}}}")
    fixtures = {}
    for name, f in raw.items():
        where = f"{path}: fixtures.{short_repr(name)}"
        if not isinstance(name, str) or not name or "," in name or name != name.strip():
            raise DatasetError(f"{where}: a fixture name must be non-empty text without commas or edge spaces")
        if not isinstance(f, dict) or f.get("type") not in ("point", "plane"):
            raise DatasetError(f"{where}: must be a mapping with type: point or type: plane")
        allowed = {"type", "sigma", "fixed"} | ({"position"} if f["type"] == "point" else {"normal", "offset"})
        unknown = set(f) - allowed
        if unknown:
            raise DatasetError(f"{where}: unknown key(s) {', '.join(sorted(map(str, unknown)))[:80]} "
                               f"(a {f['type']} takes {', '.join(sorted(allowed))})")
        value = None
        if f["type"] == "point" and "position" in f:
            if not isinstance(f["position"], list) or len(f["position"]) != 3:
                raise DatasetError(f"{where}: position must be [x, y, z] (mm)")
            value = np.array([num(v, f"fixtures.{name}.position") for v in f["position"]])
        if f["type"] == "plane" and ("normal" in f or "offset" in f):
            if not isinstance(f.get("normal"), list) or len(f["normal"]) != 3 or "offset" not in f:
                raise DatasetError(f"{where}: a known plane needs normal: [nx, ny, nz] and offset: D (mm)")
            n = np.array([num(v, f"fixtures.{name}.normal") for v in f["normal"]])
            if np.max(np.abs(n)) < 1e-9:
                raise DatasetError(f"{where}: normal must not be zero")
            n = n / np.max(np.abs(n))  # no overflow or underflow in the norm (1e300, 1e-200)
            value = np.concatenate([n / np.linalg.norm(n), [num(f["offset"], f"fixtures.{name}.offset")]])
        sigma = None if f.get("sigma") is None else num(f["sigma"], f"fixtures.{name}.sigma", 0.0)
        fixed = f.get("fixed", False)
        if not isinstance(fixed, bool):
            raise DatasetError(f"{where}: fixed must be true or false")
        if (fixed or sigma is not None) and value is None:
            raise DatasetError(f"{where}: {'fixed' if fixed else 'sigma'} needs the fixture's "
                               f"{'position' if f['type'] == 'point' else 'normal and offset'}")
        if sigma is not None and sigma <= 0 and not fixed:
            raise DatasetError(f"{where}: sigma must be positive (or fixed: true for a known fixture)")
        fixtures[name] = FixtureSpec(name, f["type"], value, sigma, fixed)
    cons = data.get("constraints") or {}
    if not isinstance(cons, dict) or set(cons) - {"distances"}:
        raise DatasetError(f"{path}: constraints must be a mapping with distances: [[A, B, mm, sigma], ...]")
    distances: list = []
    pairs: dict[frozenset, int] = {}
    items = cons.get("distances") or []
    if not isinstance(items, list):
        raise DatasetError(f"{path}: constraints.distances must be a list of [A, B, mm, sigma]")
    for i, item in enumerate(items):
        where = f"{path}: constraints.distances[{i}]"
        if not isinstance(item, list) or len(item) != 4:
            raise DatasetError(f"{where}: must be [fixture A, fixture B, distance (mm), sigma (mm)]")
        a, b = item[0], item[1]
        for x in (a, b):
            if not isinstance(x, str) or fixtures.get(x) is None or fixtures[x].type != "point":
                raise DatasetError(f"{where}: {short_repr(x)} is not a point fixture of fixtures:")
        if a == b:
            raise DatasetError(f"{where}: a distance needs two different fixtures")
        pair = frozenset((a, b))
        if pair in pairs:
            raise DatasetError(f"{where}: the distance between {a} and {b} is given already "
                               f"(constraints.distances[{pairs[pair]}]); give each pair once")
        pairs[pair] = i
        dist, sig = num(item[2], f"{where} distance", 0.0), num(item[3], f"{where} sigma", 0.0)
        if dist <= 0 or sig <= 0:
            raise DatasetError(f"{where}: the distance and its sigma must be positive (mm)")
        distances.append(DistanceConstraint(a, b, dist, sig))
    return SetupSpec(fixtures, tuple(distances))


def read_stations(path: Path, data: dict, num) -> tuple[str | None, dict]:
    """``stations:`` of ``dataset.yaml``: the world's name and the other stations' blocks.

    A list of names, or a mapping ``NAME: {pose: [phi, theta, psi, px, py, pz] (deg, mm),
    sigma: MM, fixed: BOOL}`` (all optional); the first is the world frame."""
    raw = data.get("stations")
    if raw is None:
        return None, {}
    if isinstance(raw, list):
        raw = {n: {} for n in raw}
    if not isinstance(raw, dict) or len(raw) < 1:
        raise DatasetError(f"{path}: stations must be a list of names or a mapping NAME: {{pose: [...]}}")
    names = list(raw)
    if len(set(map(str, names))) != len(names) or not all(isinstance(n, str) and n and "," not in n for n in names):
        raise DatasetError(f"{path}: stations: names must be distinct, non-empty and without commas")
    blocks = {}
    for name in names[1:]:
        spec = raw[name] or {}
        where = f"{path}: stations.{short_repr(name)}"
        if not isinstance(spec, dict) or set(spec) - {"pose", "sigma", "fixed"}:
            raise DatasetError(f"{where}: a station takes pose: [phi, theta, psi, px, py, pz], sigma, fixed")
        value = None
        if "pose" in spec:
            if not isinstance(spec["pose"], list) or len(spec["pose"]) != 6:
                raise DatasetError(f"{where}: pose must be [phi, theta, psi, px, py, pz] (deg, mm)")
            v = np.array([num(x, f"stations.{name}.pose") for x in spec["pose"]])
            value = np.concatenate([np.radians(v[:3]), v[3:]])
        sigma = None if spec.get("sigma") is None else num(spec["sigma"], f"stations.{name}.sigma", 0.0)
        fixed = spec.get("fixed", False)
        if not isinstance(fixed, bool) or ((fixed or sigma is not None) and value is None):
            raise DatasetError(f"{where}: fixed (true/false) and sigma need the station's pose")
        blocks[name] = FixtureSpec(name, "station", value, sigma, fixed)
    return names[0], blocks


def stations_dict(ds: Dataset) -> dict:
    if ds.world_station is None:
        return {}
    out: dict[str, dict[str, object]] = {ds.world_station: {}}
    for n, f in ds.setup.fixtures.items():
        if f.type == "station":
            spec: dict[str, object] = {}
            if f.value is not None:
                spec["pose"] = [float(v) for v in np.degrees(f.value[:3])] + [float(v) for v in f.value[3:]]
            if f.sigma is not None:
                spec["sigma"] = float(f.sigma)
            if f.fixed:
                spec["fixed"] = True
            out[n] = spec
    return {"stations": out}


CAMERA_KEYS = {"mount", "width", "height", "intrinsics", "estimate", "pixel_sigma", "mount_pose", "sigma", "fixed"}
TARGET_KEYS = {"mount", "points", "grid", "mount_pose", "sigma", "fixed"}


def _mount_pose(where, spec, num, what):
    """``mount_pose: [x, y, z, phi, theta, psi]`` (mm, deg) as entries (mm, rad), or None."""
    if spec.get("mount_pose") is None:
        return None
    v = spec["mount_pose"]
    if not isinstance(v, list) or len(v) != 6:
        raise DatasetError(f"{where}: mount_pose must be [x, y, z, phi, theta, psi] (mm, deg)")
    e = np.array([num(x, f"{what}.mount_pose") for x in v])
    return np.concatenate([e[:3], np.radians(e[3:])])


def _block_name(path, section, name):
    where = f"{path}: {section}.{short_repr(name)}"
    if not isinstance(name, str) or not name or "," in name or name != name.strip() or "." in name:
        raise DatasetError(f"{where}: a name must be non-empty text without commas, dots or edge spaces")
    return where


def read_cameras(path: Path, data: dict, num, default_sigma: float | None) -> dict:
    """``cameras:`` of ``dataset.yaml`` (DESIGN.md 8.4): name -> :class:`~fgcal.measurements.camera.CameraSpec`."""
    from fgcal.measurements.camera import INTRINSICS, CameraSpec

    raw = data.get("cameras") or {}
    if not isinstance(raw, dict):
        raise DatasetError(f"{path}: cameras must be a mapping {{NAME: {{mount: world|tool, width, height, ...}}}}")
    out = {}
    for name, c in raw.items():
        where = _block_name(path, "cameras", name)
        if not isinstance(c, dict):
            raise DatasetError(f"{where}: must be a mapping with mount, width, height, intrinsics")
        unknown = set(c) - CAMERA_KEYS
        if unknown:
            raise DatasetError(f"{where}: unknown key(s) {', '.join(sorted(map(str, unknown)))[:80]} "
                               f"(a camera takes {', '.join(sorted(CAMERA_KEYS))})")
        if c.get("mount") not in ("world", "tool"):
            raise DatasetError(f"{where}: mount must be world (eye-to-hand) or tool (eye-in-hand)")
        size = []
        for key in ("width", "height"):
            v = c.get(key)
            if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
                raise DatasetError(f"{where}: {key} must be a positive whole number of pixels")
            size.append(v)
        intr = c.get("intrinsics")
        if not isinstance(intr, dict) or set(intr) - set(INTRINSICS) or not {"fx", "fy", "cx", "cy"} <= set(intr):
            raise DatasetError(f"{where}: intrinsics must be a mapping with fx, fy, cx, cy (px) and optionally "
                               "k1, k2, p1, p2, k3")
        k = np.array([num(intr.get(n, 0.0), f"cameras.{name}.intrinsics.{n}") for n in INTRINSICS])
        if k[0] <= 0 or k[1] <= 0:
            raise DatasetError(f"{where}: fx and fy must be positive (px)")
        est = c.get("estimate") or []
        if isinstance(est, str) or not isinstance(est, list) or any(e not in INTRINSICS for e in est):
            raise DatasetError(f"{where}: estimate must be a list of intrinsics among {', '.join(INTRINSICS)}")
        sig = c.get("pixel_sigma", default_sigma)
        sig = 0.5 if sig is None else num(sig, f"cameras.{name}.pixel_sigma", 0.0)
        if sig <= 0:
            raise DatasetError(f"{where}: pixel_sigma must be positive (px)")
        pose = _mount_pose(where, c, num, f"cameras.{name}")
        prior = None if c.get("sigma") is None else num(c["sigma"], f"cameras.{name}.sigma", 0.0)
        fixed = c.get("fixed", False)
        if not isinstance(fixed, bool) or ((fixed or prior is not None) and pose is None):
            raise DatasetError(f"{where}: fixed (true/false) and sigma need the camera's mount_pose")
        if prior is not None and prior <= 0 and not fixed:
            raise DatasetError(f"{where}: sigma must be positive (or fixed: true for a known mount)")
        value = np.concatenate([pose, k]) if (fixed or prior is not None) else None
        out[name] = CameraSpec(name, "camera", value, prior, fixed, mount=c["mount"], width=size[0], height=size[1],
                               intrinsics=k, estimate=tuple(e for e in INTRINSICS if e in est), pixel_sigma=sig,
                               start_pose=pose)
    return out


def read_targets(path: Path, data: dict, num) -> dict:
    """``targets:`` of ``dataset.yaml`` (DESIGN.md 8.4): name -> :class:`~fgcal.measurements.camera.TargetSpec`;
    a ``grid: {rows, cols, square}`` has the points ``r{i}c{j}`` at ``(j square, i square, 0)``."""
    from fgcal.measurements.camera import TargetSpec

    raw = data.get("targets") or {}
    if not isinstance(raw, dict):
        raise DatasetError(f"{path}: targets must be a mapping {{NAME: {{mount: tool|world, points or grid}}}}")
    out: dict = {}
    owner: dict = {}
    for name, t in raw.items():
        where = _block_name(path, "targets", name)
        if not isinstance(t, dict) or set(t) - TARGET_KEYS:
            raise DatasetError(f"{where}: a target takes {', '.join(sorted(TARGET_KEYS))}")
        if t.get("mount") not in ("tool", "world"):
            raise DatasetError(f"{where}: mount must be tool (eye-to-hand) or world (eye-in-hand)")
        if ("points" in t) == ("grid" in t):
            raise DatasetError(f"{where}: give points: {{NAME: [x, y, z]}} or grid: {{rows, cols, square}}, "
                               "one of them")
        points = {}
        if "grid" in t:
            g = t["grid"]
            whole = isinstance(g, dict) and all(isinstance(g.get(k), int) and not isinstance(g.get(k), bool)
                                                and g[k] > 0 for k in ("rows", "cols"))
            if not isinstance(g, dict) or set(g) != {"rows", "cols", "square"} or not whole:
                raise DatasetError(f"{where}: grid must be {{rows: N, cols: M, square: MM}} (whole rows and cols)")
            sq = num(g["square"], f"targets.{name}.grid.square", 0.0)
            points = {f"r{i}c{j}": np.array([j * sq, i * sq, 0.0]) for i in range(g["rows"]) for j in range(g["cols"])}
        else:
            if not isinstance(t["points"], dict) or not t["points"]:
                raise DatasetError(f"{where}: points must be a mapping {{NAME: [x, y, z]}} (mm)")
            for p, xyz in t["points"].items():
                if not isinstance(xyz, list) or len(xyz) != 3:
                    raise DatasetError(f"{where}: points.{short_repr(p)} must be [x, y, z] (mm)")
                points[str(p)] = np.array([num(v, f"targets.{name}.points.{p}") for v in xyz])
        for p in points:
            if p in owner:
                raise DatasetError(f"{where}: point {p} is a point of target {owner[p]} too; name points once")
            owner[p] = name
        pose = _mount_pose(where, t, num, f"targets.{name}")
        prior = None if t.get("sigma") is None else num(t["sigma"], f"targets.{name}.sigma", 0.0)
        fixed = t.get("fixed", False)
        if not isinstance(fixed, bool) or ((fixed or prior is not None) and pose is None):
            raise DatasetError(f"{where}: fixed (true/false) and sigma need the target's mount_pose")
        if prior is not None and prior <= 0 and not fixed:
            raise DatasetError(f"{where}: sigma must be positive (or fixed: true for a known pose)")
        value = pose if (fixed or prior is not None) else None
        out[name] = TargetSpec(name, "target", value, prior, fixed, mount=t["mount"], points=points, start_pose=pose)
    return out


def cameras_dict(ds: Dataset) -> dict:
    """``cameras:`` and ``targets:`` of ``ds`` as ``dataset.yaml`` writes them."""
    out: dict = {}
    for section, kind in (("cameras", "camera"), ("targets", "target")):
        items = {n: {k: v for k, v in f.to_dict().items() if k != "type"}
                 for n, f in ds.setup.fixtures.items() if f.type == kind}
        if items:
            out[section] = items
    return out


def read_pixels(path: Path, known_poses: set, specs: dict, records):
    """``pixels.csv`` (``pose,camera,point,u,v``) as :class:`~fgcal.measurements.pixels.PixelObservations`;
    ``records`` yields ``(line, header, cells)`` and ``pose_id(text, where, known)`` is read by the caller."""
    from fgcal.measurements.pixels import PixelObservations

    cams = {n for n, f in specs.items() if f.type == "camera"}
    points = {p for f in specs.values() if f.type == "target" for p in f.points}
    pose: list = []
    cam: list = []
    point: list = []
    uv: list = []
    lines: list = []
    seen: dict = {}
    for line, pid, record in records:
        where = f"{path}: line {line}"
        c, p = record["camera"], record["point"]
        if c not in cams:
            raise DatasetError(f"{where}: camera {short_repr(c)} is not in dataset.yaml's cameras: "
                               f"({', '.join(sorted(cams))[:80] or 'none'})")
        if p not in points:
            raise DatasetError(f"{where}: point {short_repr(p)} is a point of no target in dataset.yaml's targets:")
        try:
            u, v = float(record["u"]), float(record["v"])
        except ValueError:
            raise DatasetError(f"{where}: u and v must be numbers (px)") from None
        if not (np.isfinite(u) and np.isfinite(v)):
            raise DatasetError(f"{where}: u and v must be finite (px)")
        key = (pid, c, p)
        if key in seen:
            raise DatasetError(f"{where}: point {p} in camera {c} at pose {pid} is given already (line {seen[key]})")
        seen[key] = line
        pose.append(pid)
        cam.append(c)
        point.append(p)
        uv.append((u, v))
        lines.append(line)
    if not pose:
        return None
    return PixelObservations.build(np.array(pose, dtype=int), cam, point, np.array(uv, dtype=float), specs,
                                   np.array(lines, dtype=int))
