"""Bounded reports of skipped rows and quoted file content.

A file with 600,000 unusable rows must not write 600,000 reasons anywhere (dataset.yaml's
provenance, the terminal, an error line): the reports here hold a count and a few examples, each
cut to :data:`MAX_QUOTE` characters.
"""
from __future__ import annotations

__all__ = ["MAX_EXAMPLES", "MAX_QUOTE", "bounded", "skipped_report", "skipped_summary"]

MAX_QUOTE = 200  # characters of file content (or of one reason) an error or a report quotes
MAX_EXAMPLES = 5  # skipped rows named by example


def bounded(text, limit: int = MAX_QUOTE) -> str:
    """``text`` cut to ``limit`` characters, saying how long it was."""
    s = str(text)
    return s if len(s) <= limit else f"{s[:limit]}... ({len(s)} characters)"


def skipped_summary(skipped, examples: int = MAX_EXAMPLES) -> dict:
    """``{"count": N, "examples": [...]}``: the provenance of the rows an import left out."""
    return {"count": len(skipped), "examples": [bounded(s) for s in list(skipped[:examples])]}


def skipped_report(skipped, where: str, examples: int = MAX_EXAMPLES) -> list[str]:
    """Lines for the terminal: the first ``examples`` reasons, then a count of the others."""
    lines = [f"skipped {where}: {bounded(s)}" for s in skipped[:examples]]
    if len(skipped) > examples:
        lines.append(f"skipped {where}: ... and {len(skipped) - examples} more row(s) ({len(skipped)} in all)")
    return lines
