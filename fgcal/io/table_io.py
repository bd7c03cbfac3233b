"""Reading a measurement table: joint readings plus a measured point or pose per row.

A :class:`ColumnSpec` (:mod:`fgcal.io.column_spec`) says which columns hold what and in which
units; :func:`read_measurements` reads any delimited text file with a header line (delimiter and
decimal comma detected unless given) into :class:`Measurements` in fgcal's units (rad for joints,
mm for lengths, rotation matrices). Every row that cannot be used is named with its line and the
reason, and skipped.
Presets (the Landgraf series, see :mod:`fgcal.io.landgraf`) are ColumnSpecs.
"""
from __future__ import annotations

import csv
import math
import re
from array import array
from collections import Counter
from dataclasses import dataclass, field
from itertools import chain, islice
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from fgcal.errors import DatasetError
from fgcal.io.column_spec import AngleUnit, ColumnSpec, LengthUnit, QuaternionOrder
from fgcal.io.skipped import bounded

__all__ = [
    "AngleUnit",
    "ColumnSpec",
    "LengthUnit",
    "Measurements",
    "QuaternionOrder",
    "detect_format",
    "read_columns",
    "read_lines",
    "read_measurements",
    "rotation_from_columns",
]

_MISSING = ("", "nan", "na", "n/a", "none", "null")
_DECIMAL_COMMA = re.compile(r"^\s*[+-]?\d*,\d+([eE][+-]?\d+)?\s*$")
QUATERNION_NORM_TOLERANCE = 0.01


@dataclass
class Measurements:
    """The usable rows of a measurement table, in fgcal's units.

    Attributes
    ----------
    line : ndarray of int, shape (N,)
        Line of each row in the file (header = 1); the pose id of the imported dataset.
    joints_rad : ndarray, shape (N, n_joints)
    xyz : ndarray, shape (N, 3)
        Measured positions (instrument frame, mm).
    R : ndarray, shape (N, 3, 3) or None
        Measured orientations; None for points.
    position_std : ndarray, shape (N, 3) or None
        Per-axis standard deviation (mm) when the file has them.
    rotation_std_deg : ndarray, shape (N, 3) or None
    group_values : ndarray, shape (N, k) or None
        Values of the group columns (rows with equal values are one configuration).
    skipped : list of str
        ``"line L: reason"`` for every row left out.
    source : str
    """

    line: np.ndarray
    joints_rad: np.ndarray
    xyz: np.ndarray
    R: np.ndarray | None = None
    position_std: np.ndarray | None = None
    rotation_std_deg: np.ndarray | None = None
    group_values: np.ndarray | None = None
    skipped: list[str] = field(default_factory=list)
    source: str = ""

    def __len__(self):
        return len(self.line)

    @property
    def T(self) -> np.ndarray:
        """Measured poses ``(N, 4, 4)`` (mm); identity rotations for points."""
        T = np.tile(np.eye(4), (len(self.line), 1, 1))
        if self.R is not None:
            T[:, :3, :3] = self.R
        T[:, :3, 3] = self.xyz
        return T

    def groups(self) -> np.ndarray:
        """Group id per row: equal group values (rounded to 1e-6) share one; each row alone without them."""
        if self.group_values is None:
            return np.arange(len(self.line))
        keys: dict[tuple, int] = {}
        return np.array([keys.setdefault(tuple(np.round(g, 6)), len(keys)) for g in self.group_values], dtype=int)

    def subset(self, mask) -> Measurements:
        def cut(a):
            return None if a is None else a[mask]
        return Measurements(self.line[mask], self.joints_rad[mask], self.xyz[mask], cut(self.R), cut(self.position_std),
                            cut(self.rotation_std_deg), cut(self.group_values), list(self.skipped), self.source)


def detect_format(lines, delimiter: str | None = None) -> tuple[str, bool]:
    """``(delimiter, decimal_comma)`` of a table from its first lines (header first).

    The delimiter (unless given) is the most frequent of ``;``, tab and ``,`` in the header, else
    whitespace (``" "``). Decimal commas are assumed when the delimiter is not a comma and a data
    field looks like ``12,5``.
    """
    lines = [ln for ln in lines if ln.strip()]
    if delimiter is None:
        counts = {d: lines[0].count(d) for d in (";", "\t", ",")} if lines else {",": 1}
        delimiter = max(counts, key=lambda d: counts[d]) if max(counts.values()) > 0 else " "
    decimal_comma = False
    if delimiter != ",":
        for ln in lines[1:]:
            fields = ln.split() if delimiter == " " else ln.split(delimiter)
            if any(_DECIMAL_COMMA.match(f) for f in fields):
                decimal_comma = True
                break
    return delimiter, decimal_comma


def _value(text: str, decimal_comma: bool):
    t = text.strip()
    if t.lower() in _MISSING:
        return None
    if decimal_comma:
        t = t.replace(",", ".")
    v = float(t)
    return v if math.isfinite(v) else None


def rotation_from_columns(values, spec: ColumnSpec) -> np.ndarray:
    """Rotation matrices ``(N, 3, 3)`` from the rotation columns ``(N, 3 or 4)`` of a pose spec."""
    values = np.asarray(values, dtype=float)
    if spec.euler_convention is not None:
        return Rotation.from_euler(spec.euler_convention, values, degrees=spec.rotation_unit is AngleUnit.DEG).as_matrix()
    xyzw = values if spec.quaternion_order is QuaternionOrder.XYZW else values[:, [1, 2, 3, 0]]
    return Rotation.from_quat(xyzw).as_matrix()


MAX_TABLE_LINE = 1 << 20  # bytes of a line: a row is a few kB; a longer line is refused before it is read whole
MAX_TABLE_BYTES = 2 << 30  # a table is streamed (bench/bench_memory.py): beyond this, refused, naming the size


def read_lines(path: Path):
    """The lines of a text file (UTF-8, byte-order mark ignored), read as they are used (an iterator:
    the memory of one line); :class:`DatasetError` naming the file when unreadable."""
    from fgcal.util.yamlio import text_lines

    return text_lines(path, DatasetError, MAX_TABLE_BYTES, MAX_TABLE_LINE)


def _csv_rows(reader, path):
    """``(line, fields)`` of a csv reader; a malformed record is a :class:`DatasetError` naming the line."""
    try:
        for r in reader:
            yield reader.line_num, r
    except csv.Error as exc:
        raise DatasetError(f"{path}: line {reader.line_num + 1}: {exc}") from None


def _rows(path: Path, delimiter: str | None, decimal_comma: bool | None):
    """``(header, decimal_comma, iterator of (line, fields))``."""
    lines = read_lines(path)
    head = list(islice(lines, 50))
    delimiter, comma = detect_format(head, delimiter)
    lines = chain(head, lines)
    decimal_comma = comma if decimal_comma is None else decimal_comma
    if delimiter == " ":
        rows = ((i + 1, ln.split()) for i, ln in enumerate(lines))
    else:
        rows = _csv_rows(csv.reader(lines, delimiter=delimiter), path)
    first = next(rows, None)
    if first is None:
        raise DatasetError(f"{path}: empty file")
    return [h.strip() for h in first[1]], decimal_comma, rows


def read_columns(path, required, optional=(), delimiter: str | None = None, decimal_comma: bool | None = None,
                 label: str = "", check=None):
    """Numbers of named columns of a table with a header line.

    Parameters
    ----------
    required : sequence of str
        Columns that must be in the header and hold a number in every usable row.
    optional : sequence of sequence of str
        Column groups used (and then required in every row) when all of the group is in the header.
    check : callable, optional
        ``check(values) -> reason or None`` on each row's ``{column: value}``; a reason skips it.

    Returns
    -------
    lines : ndarray of int, shape (N,)
    values : dict of str to ndarray, shape (N,)
        The required columns and the optional ones present.
    skipped : list of str
        ``"line L: reason"`` for each row left out.
    """
    path = Path(path)
    header, decimal_comma, rows = _rows(path, delimiter, decimal_comma)
    col = {h: i for i, h in enumerate(header)}
    missing = [c for c in required if c not in col]
    if missing:
        what = f"not a {label} file: " if label else ""
        raise DatasetError(f"{path}: line 1: {what}missing column(s) {', '.join(missing)} (header: "
                           f"{', '.join(header[:12])}{' ...' if len(header) > 12 else ''})")
    wanted = list(required) + [n for c in optional if all(n in col for n in c) for n in c]
    kept, columns = array("q"), {n: array("d") for n in wanted}  # 8 bytes a value, not a dict a row
    skipped: list[str] = []
    for line, record in rows:
        if not record or all(not c.strip() for c in record):
            continue
        if len(record) < len(header):
            skipped.append(f"line {line}: {len(record)} fields, expected {len(header)}")
            continue
        values, bad = {}, []
        for name in wanted:
            try:
                v = _value(record[col[name]], decimal_comma)
            except ValueError:
                v = None
            if v is None:
                bad.append(name)
            values[name] = v
        if bad:
            skipped.append(f"line {line}: missing or unreadable {', '.join(bad)}")
            continue
        reason = check(values) if check else None
        if reason:
            skipped.append(f"line {line}: {reason}")
            continue
        kept.append(line)
        for n in wanted:
            columns[n].append(values[n])
    if not kept:
        raise DatasetError(f"{path}: no usable rows ({len(skipped)} skipped{': ' + bounded(skipped[0]) if skipped else ''})")
    return (np.frombuffer(kept, dtype=np.int64), {n: np.frombuffer(columns[n], dtype=float) for n in wanted}, skipped)


def read_measurements(path, spec: ColumnSpec) -> Measurements:
    """Read a table into :class:`Measurements`; rows that cannot be used are listed in ``skipped``.

    Raises :class:`DatasetError` naming the file for a missing column or no usable row.
    """
    def quaternion_norm(values):
        norm = float(np.linalg.norm([values[c] for c in spec.pose[3:]]))
        return f"quaternion norm {norm:.4g} is not 1" if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE else None

    optional = [c for c in (spec.position_std, spec.rotation_std, spec.group) if c is not None]
    lines, values, skipped = read_columns(path, spec.required, optional, spec.delimiter, spec.decimal_comma,
                                          spec.label, quaternion_norm if spec.quaternion_order else None)

    uses = Counter(n for c in (spec.joints, spec.point or spec.pose or (), *optional) for n in c)

    def table(names, scale=1.0):  # a column given up at its last use: one copy of the numbers at a time
        out = np.stack([values[n] for n in names], axis=1)
        for n in names:
            uses[n] -= 1
            if uses[n] == 0:
                values.pop(n)
        return out * scale if scale != 1.0 else out

    angle = 1.0 if spec.joint_unit is AngleUnit.RAD else math.pi / 180.0
    cols = spec.point or spec.pose or ()
    has: dict[tuple | None, bool] = {c: all(n in values for n in c) for c in optional}
    joints, xyz = table(spec.joints, angle), table(cols[:3], spec.length_unit.to_mm)
    R = None if spec.pose is None else rotation_from_columns(table(spec.pose[3:]), spec)
    return Measurements(
        line=lines, joints_rad=joints, xyz=xyz, R=R,
        position_std=table(spec.position_std, spec.length_unit.to_mm) if has.get(spec.position_std) else None,
        rotation_std_deg=table(spec.rotation_std, 1.0 if spec.rotation_unit is AngleUnit.DEG else 180.0 / math.pi)
        if has.get(spec.rotation_std) else None,
        group_values=table(spec.group) if has.get(spec.group) else None,
        skipped=skipped, source=str(path))
