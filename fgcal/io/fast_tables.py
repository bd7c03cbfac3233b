"""The fast path of reading a dataset's CSV tables: whole columns converted at once.

A measurement file of 10,000 poses has 120,000 rows; checking them one cell at a time
(:mod:`fgcal.measurements.cells`) costs more than the calibration's linear algebra. Here a plain
file (no quotes, no carriage returns without line feeds, no blank lines, every row as wide as the
header, a valid header) is split into columns and each column converted by one ``map`` of the same
``int``/``float`` the checked path uses; the values are then checked for the whole column at once.
Whenever anything is out of the ordinary the functions return None, and the caller reads the file
with its checked row-by-row path, which names the file, line and cell of the problem: the fast path
never decides what an error is, so the messages are the checked path's. No state, no I/O beyond
reading the file.
"""
from __future__ import annotations

from itertools import repeat
from pathlib import Path

import numpy as np

__all__ = ["float_columns", "int_column", "read_columns"]


def read_columns(path: Path, columns, optional=()) -> dict[str, tuple[str, ...]] | None:
    """``{column: cells}`` of a plain CSV file whose header holds ``columns`` (and maybe ``optional``).

    Parameters
    ----------
    path : Path
        The file (UTF-8); the header is its first line.
    columns, optional : sequence of str
        Required and allowed column names.

    Returns
    -------
    dict or None
        Each column's cells (unstripped text, one per data row, in file order: row ``k`` is on
        line ``k + 2``), or None when the file needs the checked reader (or is not there: that
        reader says so).
    """
    try:
        with open(path, encoding="utf-8", newline="") as fh:
            text = fh.read()
    except (OSError, UnicodeDecodeError, ValueError):
        return None
    if '"' in text or "\r" in text.replace("\r\n", "\n"):
        return None  # quoted cells or old Mac line ends: csv's own rules
    lines = text.replace("\r\n", "\n").split("\n")
    if lines and lines[-1] == "":
        lines.pop()
    if len(lines) < 2:
        return None
    header = [h.strip() for h in lines[0].split(",")]
    allowed = set(columns) | set(optional)
    if len(set(header)) != len(header) or not set(columns) <= set(header) or not set(header) <= allowed:
        return None
    body = lines[1:]
    if set(map(str.count, body, repeat(","))) != {len(header) - 1}:
        return None  # blank lines or ragged rows
    cells = ",".join(body).split(",")  # row k's cells are cells[k * width : (k + 1) * width]
    return {name: tuple(cells[k::len(header)]) for k, name in enumerate(header)}


def int_column(cells) -> np.ndarray | None:
    """Integer ids (N,) of ``cells`` as the checked path's ``int`` reads them, or None if one is not."""
    try:
        return np.array(list(map(int, cells)), dtype=np.int64)
    except (ValueError, TypeError, OverflowError):
        return None


def float_columns(columns, limit: float) -> np.ndarray | None:
    """Finite floats (N, k) of ``k`` columns of cells, each of magnitude at most ``limit``, or None."""
    try:
        values = np.array([list(map(float, c)) for c in columns], dtype=float).T
    except (ValueError, TypeError):
        return None
    if values.size and not (np.isfinite(values).all() and np.abs(values).max() <= limit):
        return None
    return values
