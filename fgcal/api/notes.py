"""Warnings and notes of the library functions, as Python :mod:`warnings`.

A library function says what the command prints: ``warning:`` lines (a value that looks like a
unit mistake, poses outside the joint limits) are :class:`FgcalWarning`, ``note:`` lines (poses
left out, an optimistic verification) are :class:`FgcalNote`. A script sees them as warnings
(``warnings.simplefilter("ignore", fgcal.FgcalNote)`` silences the notes); the command line
collects them with :func:`collect` and prints them.
"""
from __future__ import annotations

import contextlib
import warnings
from collections.abc import Iterator

__all__ = ["FgcalNote", "FgcalWarning", "collect", "note", "warn"]


class FgcalWarning(UserWarning):
    """Something in the input looks wrong, but the work went on."""


class FgcalNote(FgcalWarning):
    """Something the user should know about the work (poses left out, an optimistic check)."""


def warn(message: str) -> None:
    """Issue ``message`` as an :class:`FgcalWarning`."""
    warnings.warn(message, FgcalWarning, stacklevel=3)


def note(message: str) -> None:
    """Issue ``message`` as an :class:`FgcalNote`."""
    warnings.warn(message, FgcalNote, stacklevel=3)


@contextlib.contextmanager
def collect() -> Iterator[list[warnings.WarningMessage]]:
    """Record every fgcal warning and note issued inside the block (none is shown or lost).

    Yields
    ------
    list of warnings.WarningMessage
        Filled in order when the block ends; other warnings pass through unchanged.
    """
    out: list[warnings.WarningMessage] = []
    others: list[warnings.WarningMessage] = []
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", FgcalWarning)
            try:
                yield out
            finally:
                for w in caught:
                    (out if issubclass(w.category, FgcalWarning) else others).append(w)
    finally:
        for w in others:  # not ours: shown as Python would have shown them
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
