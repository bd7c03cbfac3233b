"""What the commands share: the library's defaults, its warnings and notes printed, the ``--force`` rule."""
from __future__ import annotations

import inspect
import sys
from collections.abc import Callable
from typing import Any

from fgcal.api.notes import FgcalNote, collect

__all__ = ["call", "default"]


def default(function: Callable, name: str) -> Any:
    """The default of ``function``'s keyword ``name``: a command's option defaults are the library's."""
    return inspect.signature(function).parameters[name].default


def call(function: Callable, *args, notes_to=None, **kwargs):
    """``function(*args, **kwargs)``, its fgcal warnings printed as ``warning:`` (standard error) and its
    notes as ``note:`` (``notes_to``, default standard output), in the order they came, also when it fails."""
    caught: list = []
    try:
        with collect() as caught:
            return function(*args, **kwargs)
    finally:
        _print(caught, notes_to)


def _print(caught, notes_to=None) -> None:
    for w in caught:
        if issubclass(w.category, FgcalNote):
            print(f"note: {w.message}", file=notes_to or sys.stdout)
        else:
            print(f"warning: {w.message}", file=sys.stderr)
