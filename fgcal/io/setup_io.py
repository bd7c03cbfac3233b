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
