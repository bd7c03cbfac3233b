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
kinematics. What was folded into the base is kept as ``mounting`` (the chain's base frame in the
robot's own base frame, the table's ``base`` frame before the fold; for a URDF the base link), so
that targets can be given in the robot's base frame (:mod:`fgcal.robots.compensate`)::

    mounting: {phi: 0, theta: 0, psi: 0, px: 0, py: 0, pz: 127.3}   # written by fgcal, optional
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from fgcal.errors import ModelError
from fgcal.robots.euler_block import euler_any, euler_dict
from fgcal.robots.model import EULER_FIELDS, LINK_FIELDS, JointType, RobotModel, Tooling
from fgcal.robots.transforms import euler_zyx_trans, rot, to_euler_zyx_trans
from fgcal.util.numbers import finite_number
from fgcal.util.resources import builtin_robot_names, builtin_robot_path
from fgcal.util.yamlio import atomic_write_text, dump_yaml, read_yaml, short_repr

__all__ = ["FORMAT", "euler_dict", "load_model", "model_from_dict", "model_to_dict", "save_model"]

FORMAT = "fgcal-robot/1"


def _number(value, where: str) -> float:
    if not finite_number(value):
        raise ModelError(f"{where}: expected a finite number, got {short_repr(value)}")
    return float(value)


def _vector(value, n: int, where: str) -> np.ndarray:
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise ModelError(f"{where}: expected a list of {n} numbers, got {short_repr(value)}")
    return np.array([_number(v, f"{where}[{i}]") for i, v in enumerate(value)])


def _mapping(value, allowed, where: str, required=()) -> dict:
    if not isinstance(value, dict):
        raise ModelError(f"{where}: expected a mapping, got {short_repr(value)}")
    unknown = set(value) - set(allowed)
    if unknown:
        names = sorted(str(k)[:24] for k in unknown)
        raise ModelError(f"{where}: unknown key(s) {', '.join(names[:3])}{' ...' if len(names) > 3 else ''}; "
                         f"allowed: {', '.join(allowed)}")
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


def _table_rows(links, convention: str, source: str) -> list[dict]:
    """Link rows (rad, mm) in the paper's convention from a ``paper``, ``dh`` or ``mdh`` table.

    Standard DH is the paper's convention with beta = 0. In modified DH (Craig) row i is
    ``Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(theta_i + q_i) Tz(d_i)``; since Rx and Tx commute, row i's
    ``a, alpha`` belong to the paper's link i-1: they are shifted by one, and the first row's go
    into the base (returned as a leading pseudo-row ``{"a", "alpha"}``).
    """
    fields = LINK_FIELDS if convention == "paper" else ("theta", "d", "a", "alpha")
    rows = []
    for i, link in enumerate(links):
        m = _mapping(link, fields, f"{source}: links[{i}]")
        row = {f: _number(m.get(f, 0.0), f"{source}: links[{i}].{f}") for f in LINK_FIELDS if f in fields}
        row.setdefault("beta", 0.0)
        for f in ("theta", "alpha", "beta"):
            row[f] = math.radians(row[f])
        rows.append(row)
    if convention != "mdh":
        return rows
    shifted = [{"a": rows[0]["a"], "alpha": rows[0]["alpha"]}]
    for i, row in enumerate(rows):
        nxt = rows[i + 1] if i + 1 < len(rows) else {"a": 0.0, "alpha": 0.0}
        shifted.append({"theta": row["theta"], "d": row["d"], "a": nxt["a"], "alpha": nxt["alpha"], "beta": 0.0})
    return shifted


def _joints(data, n: int, source: str):
    """Joint types and names from the optional ``joints`` list (revolute, ``q1..qn`` by default)."""
    if data.get("joints") is None:
        return (JointType.REVOLUTE,) * n, ()
    joints = data["joints"]
    if not isinstance(joints, list) or len(joints) != n:
        raise ModelError(f"{source}: joints: expected a list of {n} entries (one per joint limit)")
    types, names = [], []
    for i, j in enumerate(joints):
        m = _mapping(j, ("name", "type"), f"{source}: joints[{i}]")
        kind = str(m.get("type", "revolute"))
        if kind not in ("revolute", "prismatic"):
            raise ModelError(f"{source}: joints[{i}].type: expected revolute or prismatic, got {kind!r}")
        types.append(JointType(kind))
        names.append(str(m.get("name", f"q{i + 1}")))
    if len(set(names)) != n or any(x in ("base", "tool") for x in names):
        raise ModelError(f"{source}: joints: names must be unique and not 'base' or 'tool'")
    return tuple(types), tuple(names)


def model_from_dict(data, source: str = "<model>") -> RobotModel:
    """Build a :class:`RobotModel` from a parsed model file; ``ModelError`` names ``source``."""
    top = ("format", "name", "description", "convention", "base", "links", "tool", "tool_offset", "joint_limits",
           "joints", "coupling", "tooling", "volume", "paper_box", "inertials", "urdf", "mounting", "ur_kinematics")
    if isinstance(data, dict) and "format" not in data:
        raise ModelError(f"{source}: not an {FORMAT} model file (no format key)")
    data = _mapping(data, top, source, required=("format", "base", "links", "tool", "joint_limits"))
    if data["format"] != FORMAT:
        raise ModelError(f"{source}: format {short_repr(data['format'])} is not known (expected {FORMAT!r})")
    name = str(data.get("name") or Path(source).stem)
    convention = str(data.get("convention", "paper"))
    if convention not in ("paper", "dh", "mdh"):
        raise ModelError(f"{source}: convention: expected paper, dh or mdh, got {convention!r}")

    def euler(block: str) -> np.ndarray:
        m = _mapping(data[block], EULER_FIELDS, f"{source}: {block}")
        vals = [_number(m.get(f, 0.0), f"{source}: {block}.{f}") for f in EULER_FIELDS]
        return np.array([math.radians(v) if i < 3 else v for i, v in enumerate(vals)])

    base, tool = euler("base"), euler("tool")
    tool_offset = euler_zyx_trans(*euler("tool_offset")) if data.get("tool_offset") is not None else None
    limits_raw = data["joint_limits"]
    if not isinstance(limits_raw, list) or not limits_raw:
        raise ModelError(f"{source}: joint_limits: expected one [min, max] pair per joint")
    n = len(limits_raw)
    types, joint_names = _joints(data, n, source)
    links = data["links"]
    if not isinstance(links, list) or len(links) not in (n - 1, n):
        raise ModelError(f"{source}: links: expected a list of {n - 1} or {n} link rows for {n} joints")
    rows = _table_rows(links, convention, source)
    table_base = euler_zyx_trans(*base)
    if convention == "mdh":
        first = rows.pop(0)
        base = to_euler_zyx_trans(euler_zyx_trans(*base) @ _link_transform({"theta": 0.0, "d": 0.0, "beta": 0.0,
                                                                              **first}))

    # Link 1's theta and d act along the base z axis: fold them into the base.
    first = rows[0]
    if first["theta"] or first["d"]:
        A = euler_zyx_trans(*base) @ _link_transform({**first, "a": 0.0, "alpha": 0.0, "beta": 0.0})
        base = to_euler_zyx_trans(A)
        first["theta"] = first["d"] = 0.0
    # What was folded into the base: the chain's base frame in the robot's own (mounting) frame.
    mounting = euler_zyx_trans(*euler("mounting")) if data.get("mounting") is not None else np.eye(4)
    mounting = mounting @ np.linalg.solve(table_base, euler_zyx_trans(*base))
    # A last link row sits between the last joint's motion and the tool: fold it into the tool.
    last_row = None
    if len(rows) == n:
        last_row = _link_transform(rows[-1])
        tool = to_euler_zyx_trans(_link_transform(rows.pop()) @ euler_zyx_trans(*tool))

    limits = np.array([_vector(v, 2, f"{source}: joint_limits[{i}]") for i, v in enumerate(limits_raw)])
    angle = np.array([t is JointType.REVOLUTE for t in types])
    limits[angle] = np.radians(limits[angle])
    bad = np.nonzero(limits[:, 0] >= limits[:, 1])[0]
    if bad.size:
        raise ModelError(f"{source}: joint_limits[{bad[0]}]: min must be below max")
    joint_map, joint_offset = _coupling(data.get("coupling"), n, angle, source)

    tooling = None
    if data.get("tooling") is not None:
        t = _mapping(data["tooling"], ("radius", "balls"), f"{source}: tooling", required=("radius", "balls"))
        balls = _mapping(t["balls"], list(t["balls"]) if isinstance(t["balls"], dict) else (), f"{source}: tooling.balls")
        tooling = Tooling(radius=_number(t["radius"], f"{source}: tooling.radius"),
                          balls={str(k): _vector(v, 3, f"{source}: tooling.balls.{k}") for k, v in balls.items()})
        if tooling.radius < 0 or not tooling.balls:
            raise ModelError(f"{source}: tooling: expected a radius >= 0 and at least one ball")

    def box(key):
        if data.get(key) is None:
            return None
        m = _mapping(data[key], ("min", "max"), f"{source}: {key}", required=("min", "max"))
        lo, hi = _vector(m["min"], 3, f"{source}: {key}.min"), _vector(m["max"], 3, f"{source}: {key}.max")
        if np.any(lo >= hi):
            raise ModelError(f"{source}: {key}: min must be below max on every axis")
        return np.array([lo, hi])

    link_names = joint_names[:-1] if joint_names else ()
    nominal = np.concatenate([base, np.array([[r[f] for f in LINK_FIELDS] for r in rows]).reshape(-1), tool])
    extra = {k: data[k] for k in ("inertials", "urdf", "ur_kinematics") if data.get(k) is not None}
    if not np.allclose(mounting, np.eye(4), rtol=0.0, atol=1e-12):
        extra["mounting"] = euler_dict(mounting)
    if "urdf" in extra:
        _check_urdf_block(extra["urdf"], n, source)
    if "inertials" in extra:  # checked, and the folded last link's centre of mass moved with it (fgcal.robots.gravity)
        from fgcal.robots.gravity import inertials_from_dict, inertials_to_dict

        extra["inertials"] = inertials_to_dict(inertials_from_dict(extra["inertials"], n, source, last_row))
    try:
        return RobotModel(name=name, nominal=nominal, joint_limits=limits, tooling=tooling, volume=box("volume"),
                          paper_box=box("paper_box"), description=str(data.get("description", "")), extra=extra,
                          joint_types=types, link_names=link_names, joint_names=joint_names,
                          joint_map=joint_map, joint_offset=joint_offset, tool_offset=tool_offset)
    except ValueError as exc:
        raise ModelError(f"{source}: {exc}") from None


def _check_urdf_block(value, n: int, source: str) -> None:
    """``urdf: {text, base, tip, frame_changes}``: the imported URDF an export copies (written by fgcal)."""
    ok = isinstance(value, dict) and isinstance(value.get("text"), str) \
        and all(value.get(k) is None or isinstance(value.get(k), str) for k in ("base", "tip"))
    fc = value.get("frame_changes") if ok else None

    def matrix(c) -> bool:
        return (isinstance(c, list) and len(c) == 4 and all(isinstance(r, list) and len(r) == 4 and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and np.isfinite(x) for x in r) for r in c))

    ok = ok and isinstance(fc, list) and len(fc) == n and all(matrix(c) for c in fc)
    if not ok:
        raise ModelError(f"{source}: urdf: expected the block fgcal writes on import ({{text: URDF, base: LINK, "
                         f"tip: LINK, frame_changes: {n} 4x4 matrices}}), got {short_repr(value)}")


def _coupling(value, n: int, angle, source: str):
    """``coupling: {matrix: n x n, offset: n (deg/mm)}``: joint variables from readings."""
    if value is None:
        return None, None
    m = _mapping(value, ("matrix", "offset"), f"{source}: coupling")
    matrix = None
    if m.get("matrix") is not None:
        rows = m["matrix"]
        if not isinstance(rows, list) or len(rows) != n:
            raise ModelError(f"{source}: coupling.matrix: expected {n} rows of {n} numbers")
        matrix = np.array([_vector(r, n, f"{source}: coupling.matrix[{i}]") for i, r in enumerate(rows)])
        cond = np.linalg.cond(matrix)  # relative: a gearbox diag(1/125) is well conditioned, det 1e-11 or not
        if not np.isfinite(cond) or cond > 1e10:
            raise ModelError(f"{source}: coupling.matrix: is singular (condition number {cond:.3g}; readings must "
                             "determine the joints)")
    offset = None
    if m.get("offset") is not None:
        offset = _vector(m["offset"], n, f"{source}: coupling.offset")
        offset = np.where(angle, np.radians(offset), offset)
    return matrix, offset


def load_model(name_or_path, chain: dict | None = None) -> RobotModel:
    """Load a built-in model by name (``puma560``, ``ur10``, ``ur5``), a model file or a URDF by path.

    ``chain`` (``{"base": LINK, "tip": LINK}``) picks the chain of a URDF with more than one leaf.
    """
    text = str(name_or_path)
    path = Path(text)
    if path.suffix.lower() == ".urdf":
        from fgcal.robots.urdf_import import load_urdf_model

        chain = chain or {}
        return load_urdf_model(path, base=chain.get("base"), tip=chain.get("tip"))
    if path.suffix.lower() not in (".yaml", ".yml"):
        if text not in builtin_robot_names():
            raise ModelError(f"unknown robot model {short_repr(text, 40)}; built-in: {', '.join(builtin_robot_names())}"
                             ", or the path of a model file (.yaml, .yml or .urdf)")
        path = builtin_robot_path(text)
    data = read_yaml(path, error=ModelError)
    return model_from_dict(data, source=str(path))


def model_to_dict(model: RobotModel, slots=None) -> dict:
    """A model file dictionary for ``model``, with ``slots`` (S, mm/rad) in place of its nominal."""
    x = model.nominal if slots is None else np.asarray(slots, dtype=float)
    values = model.slots_to_file_units(x)

    def value(name):
        return round(float(values[model.slot(name)]), 12)

    out: dict[str, object] = {"format": FORMAT, "name": model.name}
    if model.description:
        out["description"] = model.description
    out["base"] = {f: value(f"base.{f}") for f in EULER_FIELDS}
    out["links"] = [{f: value(f"{j}.{f}") for f in LINK_FIELDS} for j in model.link_names]
    out["tool"] = {f: value(f"tool.{f}") for f in EULER_FIELDS}
    if model.tool_offset is not None:
        off = euler_any(model.tool_offset)
        out["tool_offset"] = {f: round(float(math.degrees(v) if i < 3 else v), 15) for i, (f, v) in
                              enumerate(zip(EULER_FIELDS, off))}
    out["joint_limits"] = [[round(float(v), 12) for v in lim] for lim in model.joints_to_file_units(model.joint_limits.T).T]
    default_names = tuple(f"q{k}" for k in range(1, model.n_joints + 1))
    if model.joint_names != default_names or not np.all(model.joint_is_angle):
        out["joints"] = [{"name": nm, "type": t.value} for nm, t in zip(model.joint_names, model.joint_types)]
    if model.joint_map is not None or model.joint_offset is not None:
        c: dict[str, list] = {}
        if model.joint_map is not None:
            c["matrix"] = [[float(v) for v in row] for row in model.joint_map]
        if model.joint_offset is not None:
            c["offset"] = [float(v) for v in model.joints_to_file_units(model.joint_offset)]
        out["coupling"] = c
    if model.tooling is not None:
        out["tooling"] = {"radius": model.tooling.radius,
                          "balls": {k: [float(c) for c in v] for k, v in model.tooling.balls.items()}}
    for key in ("volume", "paper_box"):
        b = getattr(model, key)
        if b is not None:
            out[key] = {"min": [float(c) for c in b[0]], "max": [float(c) for c in b[1]]}
    out.update({k: v for k, v in model.extra.items() if k in ("inertials", "urdf", "mounting", "ur_kinematics")})
    return out


def save_model(model: RobotModel, path, slots=None) -> None:
    """Write ``model`` (or its geometry with ``slots`` in place of the nominal) as a model file."""
    atomic_write_text(path, dump_yaml(model_to_dict(model, slots)))
