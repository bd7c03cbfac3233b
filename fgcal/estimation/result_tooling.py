"""What a calibration result records of the tooling the data used (DESIGN.md 8.2): the balls, their
centres in the tool frame and the ball that made the contacts, where ``export --urdf`` puts the
link ``tool``. Checked on load like the rest of a result."""
from __future__ import annotations

from fgcal.measurements.contact import CONTACT_FILE
from fgcal.measurements.types import BY_LEVEL
from fgcal.util.numbers import finite_number

__all__ = ["check_tooling", "tooling_record"]


def _finite3(v) -> bool:
    return (isinstance(v, list) and len(v) == 3
            and all(map(finite_number, v)))


def tooling_record(ds, levels) -> dict:
    """What a result keeps of a dataset's tooling: ``radius`` (mm), ``balls`` (name -> its centre in
    the tool frame (3,), mm) of the balls the measurements at ``levels`` used, and ``tool_ball``: the
    one ball that made every contact (the rows of ``contacts.csv``), None without contacts or with
    several balls."""
    used: dict = {}
    touching: set = set()
    for lv in levels:
        obs = getattr(ds, lv, None)
        if obs is None or not hasattr(obs, "ball"):
            continue
        names = set(obs.ball.tolist())
        used.update({n: [float(v) for v in ds.tooling.balls[n]] for n in sorted(names) if n in ds.tooling.balls})
        if getattr(BY_LEVEL.get(lv), "file", None) == CONTACT_FILE:
            touching |= names
    return {"radius": float(ds.tooling.radius), "balls": used,
            "tool_ball": next(iter(touching)) if len(touching) == 1 else None}


def check_tooling(tooling) -> dict:
    """The ``tooling`` section of a result, checked (``ValueError`` saying what is wrong)."""
    if tooling is None:
        return {}
    if not isinstance(tooling, dict) or set(tooling) - {"radius", "balls", "tool_ball"}:
        raise ValueError("tooling: must be a mapping with radius, balls, tool_ball")
    balls = tooling.get("balls", {})
    if not isinstance(balls, dict) or not all(isinstance(n, str) and _finite3(v) for n, v in balls.items()):
        raise ValueError("tooling.balls: must map ball names to three finite numbers (mm)")
    r = tooling.get("radius", 0.0)
    if not finite_number(r) or r < 0:
        raise ValueError("tooling.radius: must be a finite number >= 0 (mm)")
    if tooling.get("tool_ball") is not None and tooling["tool_ball"] not in balls:
        raise ValueError(f"tooling.tool_ball: {str(tooling['tool_ball'])[:40]!r} is not among tooling.balls")
    return dict(tooling)
