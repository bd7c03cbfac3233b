"""The set-up section of a calibration result (DESIGN.md 8.1): the fixtures, constraints and
estimated set-up unknowns, checked on load against themselves and the result's parameter names."""
from __future__ import annotations

import numpy as np

from fgcal.util.numbers import finite_number

__all__ = ["SETUP_KEYS", "check_setup"]

SETUP_KEYS = ("fixtures", "constraints", "estimated", "gauge", "start", "refused")


def _setup_prefixes() -> dict:
    """A parameter's first name part -> its block's type (``fixture`` -> ``point``, ``station`` -> ``station``),
    over the registered block kinds (:data:`fgcal.measurements.setup.BLOCK_KINDS`)."""
    from fgcal.measurements.setup import BLOCK_KINDS

    return {k.prefix: k.type for k in BLOCK_KINDS.values()}


def _finite_list(v, n: int) -> bool:
    return (isinstance(v, list) and len(v) == n
            and all(map(finite_number, v)))


def _finite(v) -> bool:
    return finite_number(v)


def check_setup(setup, names) -> dict:
    """The ``setup`` section of a result, checked against itself and the parameters' names
    (``fixture.NAME.x``, ``plane.NAME.d``): ``ValueError`` saying what is wrong."""
    if setup is None:
        setup = {}
    if not isinstance(setup, dict):
        raise ValueError(f"setup: must be a mapping, got {type(setup).__name__}")
    unknown = sorted(str(k)[:24] for k in setup if k not in SETUP_KEYS)
    if unknown:
        raise ValueError(f"setup: unknown key(s) {', '.join(unknown[:3])} (expected {', '.join(SETUP_KEYS)})")
    fixtures = setup.get("fixtures", {})
    if not isinstance(fixtures, dict):
        raise ValueError("setup.fixtures: must be a mapping {NAME: {type: point|plane, ...}}")
    kinds = set(_setup_prefixes().values())
    for name, f in fixtures.items():
        if not isinstance(f, dict) or f.get("type") not in kinds:
            raise ValueError(f"setup.fixtures.{str(name)[:40]}: must be a mapping with type "
                             f"{' or '.join(sorted(kinds))}")
    cons = setup.get("constraints", {})
    if not isinstance(cons, dict) or not isinstance(cons.get("distances", []), list):
        raise ValueError("setup.constraints: must be a mapping with distances: [[A, B, mm, sigma], ...]")
    for i, c in enumerate(cons.get("distances", [])):
        if (not isinstance(c, list) or len(c) != 4 or any(x not in fixtures for x in c[:2] if isinstance(x, str))
                or not all(isinstance(x, str) for x in c[:2]) or not all(_finite(x) and x > 0 for x in c[2:])):
            raise ValueError(f"setup.constraints.distances[{i}]: must be [fixture A, fixture B, mm, sigma] "
                             "of the result's fixtures")
    estimated = setup.get("estimated", {})
    if not isinstance(estimated, dict):
        raise ValueError("setup.estimated: must be a mapping {NAME: {type, position | normal and offset}}")
    missing = [n for n in fixtures if n not in estimated]
    if missing:
        raise ValueError(f"setup.estimated: no value for fixture {str(missing[0])[:40]}")
    for name, e in estimated.items():
        where = f"setup.estimated.{str(name)[:40]}"
        if name not in fixtures:
            raise ValueError(f"{where}: not among setup.fixtures")
        if not isinstance(e, dict) or e.get("type") != fixtures[name]["type"]:
            raise ValueError(f"{where}: must be a mapping with the fixture's type ({fixtures[name]['type']})")
        if e["type"] == "point" and not _finite_list(e.get("position"), 3):
            raise ValueError(f"{where}: position must be three finite numbers (mm)")
        if e["type"] == "plane" and not (_finite_list(e.get("normal"), 3) and _finite(e.get("offset"))
                                         and abs(float(np.linalg.norm(e["normal"])) - 1.0) < 1e-6):
            raise ValueError(f"{where}: a plane needs a unit normal (three finite numbers) and a finite offset (mm)")
        if e["type"] == "station" and not _finite_list(e.get("pose"), 6):
            raise ValueError(f"{where}: a station needs its pose, six finite numbers (deg, mm)")
    if "gauge" in setup and not isinstance(setup["gauge"], str):
        raise ValueError("setup.gauge: must be text")
    prefixes = _setup_prefixes()
    for n in names:
        kind, _, rest = str(n).partition(".")
        if kind in prefixes:
            fixture = rest.rpartition(".")[0]
            if fixtures.get(fixture, {}).get("type") != prefixes[kind]:
                raise ValueError(f"parameter {str(n)[:60]}: no {prefixes[kind]} fixture {fixture[:40]!r} "
                                 "in setup.fixtures")
    return dict(setup)
