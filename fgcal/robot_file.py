"""Robot model files (``fgcal-robot/1``, YAML): reading, validating, writing.

A model file holds the nominal table in the paper's convention (lengths mm, angles deg)::

    format: fgcal-robot/1
    name: puma560
    base: {phi: 90, theta: 0, psi: 0, px: -400, py: -600, pz: 500}
    links:                  # 5 or 6 rows: Rz(q+theta) Tz(d) Tx(a) Rx(alpha) Ry(beta)
      - {theta: 0, d: 0, a: 0, alpha: 90}
      ...
    tool: {phi: 0, theta: 0, psi: 0, px: 0, py: 0, pz: 106.25}
    joint_limits: [[-160, 160], ...]                                  # deg
    tooling: {radius: 6.35, balls: {A: [60, 0, 0], ...}}             # optional
    volume: {min: [0, 0, 0], max: [1200, 1000, 800]}                  # optional, world mm
    paper_box: {min: [...], max: [...]}                               # optional, world mm

A sixth link row (standard DH tables have one) is folded into the tool, and link 1's theta and
d into the base, since the chain cannot tell them apart; the folded model has the same forward
kinematics.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .errors import ModelError
from .model import EULER_FIELDS, LINK_FIELDS, N_LINKS_IN_CHAIN, SLOT_NAMES, RobotModel, Tooling, slot
from .resources import builtin_robot_names, builtin_robot_path
from .transforms import euler_zyx_trans, rot, to_euler_zyx_trans
from .yamlio import atomic_write_text, dump_yaml, read_yaml

__all__ = ["load_model", "model_from_dict", "model_to_dict", "save_model", "FORMAT"]

FORMAT = "fgcal-robot/1"


def _number(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ModelError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def _vector(value, n: int, where: str) -> np.ndarray:
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise ModelError(f"{where}: expected a list of {n} numbers, got {value!r}")
    return np.array([_number(v, f"{where}[{i}]") for i, v in enumerate(value)])


def _mapping(value, allowed, where: str, required=()) -> dict:
    if not isinstance(value, dict):
        raise ModelError(f"{where}: expected a mapping, got {value!r}")
    unknown = set(value) - set(allowed)
    if unknown:
        raise ModelError(f"{where}: unknown key(s) {', '.join(sorted(map(str, unknown)))}; allowed: {', '.join(allowed)}")
    missing = [k for k in required if k not in value]
    if missing:
        raise ModelError(f"{where}: missing key(s) {', '.join(missing)}")
    return value


def _link_transform(row: dict) -> np.ndarray:
    """``Rz(theta) Tz(d) Tx(a) Rx(alpha) Ry(beta)`` (rad, mm) as (4, 4)."""
    T = np.eye(4)
    T[:3, :3] = rot(2, row["theta"]) @ rot(0, row["alpha"]) @ rot(1, row["beta"])
    T[:3, 3] = rot(2, row["theta"]) @ np.array([row["a"], 0.0, row["d"]])
    return T


def model_from_dict(data, source: str = "<model>") -> RobotModel:
    """Build a :class:`RobotModel` from a parsed model file; ``ModelError`` names ``source``."""
    top = ("format", "name", "description", "base", "links", "tool", "joint_limits", "tooling", "volume", "paper_box",
           "inertials")
    data = _mapping(data, top, source, required=("format", "base", "links", "tool", "joint_limits"))
    if data["format"] != FORMAT:
        raise ModelError(f"{source}: format {data['format']!r} is not known (expected {FORMAT!r})")
    name = str(data.get("name") or Path(source).stem)

    def euler(block: str) -> np.ndarray:
        m = _mapping(data[block], EULER_FIELDS, f"{source}: {block}")
        vals = [_number(m.get(f, 0.0), f"{source}: {block}.{f}") for f in EULER_FIELDS]
        return np.array([math.radians(v) if i < 3 else v for i, v in enumerate(vals)])

    base, tool = euler("base"), euler("tool")
    links = data["links"]
    if not isinstance(links, list) or len(links) not in (5, 6):
        raise ModelError(f"{source}: links: expected a list of 5 or 6 link rows")
    rows = []
    for i, link in enumerate(links):
        m = _mapping(link, LINK_FIELDS, f"{source}: links[{i}]")
        row = {f: _number(m.get(f, 0.0), f"{source}: links[{i}].{f}") for f in LINK_FIELDS}
        for f in ("theta", "alpha", "beta"):
            row[f] = math.radians(row[f])
        rows.append(row)

    # Link 1's theta and d act along the base z axis: fold them into the base.
    first = rows[0]
    if first["theta"] or first["d"]:
        A = euler_zyx_trans(*base) @ _link_transform({**first, "a": 0.0, "alpha": 0.0, "beta": 0.0})
        base = to_euler_zyx_trans(A)
        first["theta"] = first["d"] = 0.0
    # A sixth link row sits between Rz(q6) and the tool: fold it into the tool.
    last_row = None
    if len(rows) == 6:
        last_row = _link_transform(rows[-1])
        tool = to_euler_zyx_trans(_link_transform(rows.pop()) @ euler_zyx_trans(*tool))

    nominal = np.zeros(len(SLOT_NAMES))
    for i, f in enumerate(EULER_FIELDS):
        nominal[slot(f"base.{f}")] = base[i]
        nominal[slot(f"tool.{f}")] = tool[i]
    for n, row in enumerate(rows[:N_LINKS_IN_CHAIN], start=1):
        for f in LINK_FIELDS:
            nominal[slot(f"j{n}.{f}")] = row[f]

    limits_raw = data["joint_limits"]
    if not isinstance(limits_raw, list) or len(limits_raw) != 6:
        raise ModelError(f"{source}: joint_limits: expected 6 [min, max] pairs (deg)")
    limits = np.radians([_vector(v, 2, f"{source}: joint_limits[{i}]") for i, v in enumerate(limits_raw)])
    bad = np.nonzero(limits[:, 0] >= limits[:, 1])[0]
    if bad.size:
        raise ModelError(f"{source}: joint_limits[{bad[0]}]: min must be below max")

    tooling = None
    if data.get("tooling") is not None:
        t = _mapping(data["tooling"], ("radius", "balls"), f"{source}: tooling", required=("radius", "balls"))
        balls = _mapping(t["balls"], list(t["balls"]) if isinstance(t["balls"], dict) else (), f"{source}: tooling.balls")
        tooling = Tooling(radius=_number(t["radius"], f"{source}: tooling.radius"),
                          balls={str(k): _vector(v, 3, f"{source}: tooling.balls.{k}") for k, v in balls.items()})

    def box(key):
        if data.get(key) is None:
            return None
        m = _mapping(data[key], ("min", "max"), f"{source}: {key}", required=("min", "max"))
        lo, hi = _vector(m["min"], 3, f"{source}: {key}.min"), _vector(m["max"], 3, f"{source}: {key}.max")
        if np.any(lo >= hi):
            raise ModelError(f"{source}: {key}: min must be below max on every axis")
        return np.array([lo, hi])

    extra = {}
    if data.get("inertials") is not None:  # gravity torques for the compliance model (fgcal.gravity)
        from .gravity import inertials_from_dict

        extra["inertials"] = inertials_from_dict(data["inertials"], len(limits), source, last_row)
    return RobotModel(name=name, nominal=nominal, joint_limits=limits, tooling=tooling, volume=box("volume"),
                      paper_box=box("paper_box"), description=str(data.get("description", "")), extra=extra)


def load_model(name_or_path) -> RobotModel:
    """Load a built-in model by name (``puma560``, ``ur10``, ``ur5``) or a model file by path."""
    text = str(name_or_path)
    path = Path(text)
    if not path.suffix and not path.exists():
        if text not in builtin_robot_names():
            raise ModelError(f"unknown robot model {text!r}; built-in: {', '.join(builtin_robot_names())}, "
                             "or give the path of a model file")
        path = builtin_robot_path(text)
    data = read_yaml(path, error=ModelError)
    return model_from_dict(data, source=str(path))


def model_to_dict(model: RobotModel, slots=None) -> dict:
    """A model file dictionary for ``model``, with ``slots`` (37, mm/rad) in place of its nominal."""
    x = model.nominal if slots is None else np.asarray(slots, dtype=float)

    def value(name):
        v = x[slot(name)]
        return round(float(math.degrees(v) if name.split(".")[1] in ("phi", "theta", "psi", "alpha", "beta") else v), 12)

    out = {"format": FORMAT, "name": model.name}
    if model.description:
        out["description"] = model.description
    out["base"] = {f: value(f"base.{f}") for f in EULER_FIELDS}
    out["links"] = [{f: value(f"j{n}.{f}") for f in LINK_FIELDS} for n in range(1, N_LINKS_IN_CHAIN + 1)]
    out["tool"] = {f: value(f"tool.{f}") for f in EULER_FIELDS}
    out["joint_limits"] = [[round(float(v), 12) for v in np.degrees(lim)] for lim in model.joint_limits]
    if model.tooling is not None:
        out["tooling"] = {"radius": model.tooling.radius,
                          "balls": {k: [float(c) for c in v] for k, v in model.tooling.balls.items()}}
    for key in ("volume", "paper_box"):
        b = getattr(model, key)
        if b is not None:
            out[key] = {"min": [float(c) for c in b[0]], "max": [float(c) for c in b[1]]}
    if model.extra.get("inertials") is not None:
        from .gravity import inertials_to_dict

        out["inertials"] = inertials_to_dict(model.extra["inertials"])
    return out


def save_model(model: RobotModel, path, slots=None) -> None:
    """Write ``model`` (or its geometry with ``slots`` in place of the nominal) as a model file."""
    atomic_write_text(path, dump_yaml(model_to_dict(model, slots)))
