"""The JSON text of a calibration result (``fgcal-result/1``): non-finite numbers written as JSON can
hold them and read back, lists of numbers kept on one line."""
from __future__ import annotations

import json
import math
import re
import secrets

import numpy as np

__all__ = ["dumps", "json_float", "json_safe"]


def json_safe(obj, numeric_lists=None, marker=""):
    """``obj`` with non-finite floats as JSON can hold them (NaN: null, inf: "Infinity") and numpy
    scalars as Python's. With ``numeric_lists`` (a list), each non-empty list of finite Python
    numbers is appended to it and replaced by the string ``marker`` + its index + NUL (see :func:`dumps`)."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None if math.isnan(obj) else ("Infinity" if obj > 0 else "-Infinity")
    if isinstance(obj, dict):
        return {k: json_safe(v, numeric_lists, marker) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        if (numeric_lists is not None and obj and set(map(type, obj)) <= {float, int}
                and all(map(math.isfinite, obj))):
            numeric_lists.append(obj)
            return f"{marker}{len(numeric_lists) - 1}\0"
        return [json_safe(v, numeric_lists, marker) for v in obj]
    if isinstance(obj, (np.floating, np.integer)):
        return json_safe(obj.item())
    return obj


def dumps(obj) -> str:
    """JSON text of ``obj`` (made safe by :func:`json_safe`): indented by one space, each list of
    numbers on one line (written by json's C encoder: the residual lists of 10,000 poses would
    take seconds through the indenting one). The placeholders carry a random tag: no string of
    ``obj`` is mistaken for one."""
    lists: list = []
    tag = secrets.token_hex(8)
    text = json.dumps(json_safe(obj, lists, f"\0{tag}:"), indent=1)
    pattern = re.compile(r'"\\u0000' + tag + r':(\d+)\\u0000"')
    return pattern.sub(lambda m: json.dumps(lists[int(m.group(1))]), text)


def json_float(v) -> float:
    """A number as :func:`json_safe` wrote it, read back (null: NaN, "Infinity": inf)."""
    return float("nan") if v is None else (float(v) if not isinstance(v, str) else float(v.replace("Infinity", "inf")))
