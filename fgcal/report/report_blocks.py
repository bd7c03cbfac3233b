"""The neutral blocks of a report (headings, paragraphs, tables, figures) and the number format they share.

Built by :mod:`fgcal.report.report_sections` and :mod:`fgcal.report.camera_report`, rendered by
:mod:`fgcal.report.document`. No I/O, no plotting.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Block", "ReportContent", "Section", "num"]


@dataclass
class Block:
    """``kind``: ``banner`` (text, status), ``p`` (text), ``ul`` (items), ``table`` (header, rows,
    row_flags), ``details`` (text = summary line, header, rows), ``figure`` (name, text = caption)."""

    kind: str
    text: str = ""
    items: list = field(default_factory=list)
    header: list = field(default_factory=list)
    rows: list = field(default_factory=list)
    row_flags: list = field(default_factory=list)
    status: str = ""
    name: str = ""


@dataclass
class Section:
    title: str
    blocks: list[Block] = field(default_factory=list)


@dataclass
class ReportContent:
    title: str
    sections: list[Section]


def num(v, digits: int = 2) -> str:
    """A statistic to ``digits`` significant digits, without an exponent between 1e-4 and 1e6."""
    if v is None or not np.isfinite(v):
        return "-"
    if v == 0:
        return "0"
    text = f"{v:.{digits}g}"
    if "e" in text and 1e-4 <= abs(v) < 1e6:
        decimals = max(0, digits - 1 - int(np.floor(np.log10(abs(v)))))
        text = f"{v:.{decimals}f}"
    return text
