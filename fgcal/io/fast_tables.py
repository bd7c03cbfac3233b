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

import os
import stat
from itertools import repeat
from pathlib import Path

import numpy as np

from fgcal.measurements.cells import MAX_ID

__all__ = ["CHUNK_CHARS", "MAX_FAST_BYTES", "float_columns", "int_column", "read_column_chunks", "read_columns"]

# Whole-file reading holds ~10 objects a row (text, cells): beyond this size the streaming checked
# reader (memory linear in the rows with a small constant, tests/test_hostile_large.py) is used.
MAX_FAST_BYTES = 2 << 20
# A larger file is read in chunks of whole lines this long (characters) by read_column_chunks.
CHUNK_CHARS = 1 << 19


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
    try:  # a FIFO or device would block open(): only a regular file of bounded size takes this path
        st = os.stat(path)
        if not stat.S_ISREG(st.st_mode) or st.st_size > MAX_FAST_BYTES:
            return None  # the checked reader refuses the first and streams the second in small memory
    except (OSError, ValueError):
        return None
    chunks = list(read_column_chunks(path, columns, optional, chunk_chars=MAX_FAST_BYTES + 1))
    if not chunks or any(c is None for c in chunks):
        return None
    out = chunks[0]
    for c in chunks[1:]:  # a file grown since its size was read
        assert c is not None
        out = {k: out[k] + c[k] for k in out}
    return out


def read_column_chunks(path: Path, columns, optional=(), chunk_chars: int | None = None):
    """:func:`read_columns` of a file of any size, ``chunk_chars`` characters of whole lines at a time.

    Yields ``{column: cells}`` per chunk (rows in file order; the first chunk's row ``k`` is on line
    ``k + 2``); yields None once and stops when the file needs the checked reader (the caller drops
    what it read). Memory: the chunk's text and cells (~10 objects a row of it) and no more.
    ``chunk_chars``: default :data:`CHUNK_CHARS`.
    """
    chunk_chars = CHUNK_CHARS if chunk_chars is None else chunk_chars
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            yield None
            return
        fh = open(path, encoding="utf-8", newline="")
    except (OSError, ValueError):
        yield None
        return
    with fh:
        header: list[str] | None = None
        carry = ""
        while True:
            try:
                text = fh.read(chunk_chars)
            except (OSError, UnicodeDecodeError, ValueError):
                yield None
                return
            last = not text
            text = carry + text
            cut = len(text) if last else text.rfind("\n") + 1  # whole lines only; the rest waits
            piece, carry = text[:cut], text[cut:]
            if not piece:
                if last:
                    if header is None:
                        yield None  # empty, or only a header without a line end: the checked reader
                    return
                continue
            if '"' in piece or "\r" in piece.replace("\r\n", "\n"):
                yield None  # quoted cells or old Mac line ends: csv's own rules
                return
            lines = piece.replace("\r\n", "\n").split("\n")
            if lines[-1] == "":
                lines.pop()
            if header is None:
                header = [h.strip() for h in lines[0].split(",")]
                allowed = set(columns) | set(optional)
                if (len(set(header)) != len(header) or not set(columns) <= set(header)
                        or not set(header) <= allowed or len(lines) < 2):
                    yield None
                    return
                lines = lines[1:]
            if set(map(str.count, lines, repeat(","))) - {len(header) - 1}:
                yield None  # blank lines or ragged rows
                return
            cells = ",".join(lines).split(",")  # row k's cells are cells[k * width : (k + 1) * width]
            yield {name: tuple(cells[k::len(header)]) for k, name in enumerate(header)}
            if last:
                return


def int_column(cells) -> np.ndarray | None:
    """Integer ids (N,) of ``cells`` as the checked path's ``int`` reads them, or None if one is not."""
    try:
        ids = np.array(list(map(int, cells)), dtype=np.int64)
    except (ValueError, TypeError, OverflowError):
        return None
    if ids.size and not (ids.min() >= 0 and ids.max() <= MAX_ID):  # the checked path names the row
        return None
    return ids


def float_columns(columns, limit: float) -> np.ndarray | None:
    """Finite floats (N, k) of ``k`` columns of cells, each of magnitude at most ``limit``, or None."""
    try:
        values = np.array([list(map(float, c)) for c in columns], dtype=float).T
    except (ValueError, TypeError):
        return None
    if values.size and not (np.isfinite(values).all() and np.abs(values).max() <= limit):
        return None
    return values
