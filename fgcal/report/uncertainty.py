"""The uncertainty report's content: a row per parameter with its flags, and a plain verdict.

Pure functions of a :class:`~fgcal.estimation.result.CalibrationResult` (and a verification summary); the
writing of HTML, Markdown and figures is in :mod:`fgcal.report.document`.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fgcal.estimation.options import WEAK_PRIOR
from fgcal.estimation.result import CalibrationResult

__all__ = [
    "CORRELATION_LIMIT",
    "PLAUSIBLE",
    "ParameterRow",
    "joint_error_verdict",
    "noise_verdict",
    "outlier_location",
    "parameter_table",
    "readings_note",
    "strong_correlations",
    "verdict",
]

NOISE_P = 0.01  # a declared noise whose test gives less than this is called off
NOISE_RATIO = 1.25  # ... when it is also off by more than this factor

# Deviations beyond these (the weak prior: ten times the typical ones) are not a manufacturing
# error: a sign of a wrong nominal model, a unit mix-up, or a parameter the data barely constrain.
PLAUSIBLE = {"base": {"mm": WEAK_PRIOR.base_length, "deg": WEAK_PRIOR.base_angle},
             "other": {"mm": WEAK_PRIOR.length, "deg": WEAK_PRIOR.angle}}
CORRELATION_LIMIT = 0.95
Z95 = 1.959963984540054


@dataclass
class ParameterRow:
    """One row of the report's table (file units)."""

    name: str
    unit: str
    nominal: float
    estimate: float
    deviation: float
    sigma: float | None
    interval95: tuple[float, float] | None
    z: float | None
    flags: list[str] = field(default_factory=list)


def _is_setup(name: str) -> bool:
    from fgcal.estimation.setup_params import is_setup_name

    return is_setup_name(name)


def strong_correlations(result: CalibrationResult, limit: float = CORRELATION_LIMIT) -> list[tuple[str, str, float]]:
    """Pairs of parameters whose correlation exceeds ``limit`` in magnitude, strongest first."""
    if not len(result.parameters):
        return []
    rho = result.correlation()
    names = result.names
    robot = [not _is_setup(n) for n in names]  # set-up unknowns are correlated with the robot by nature
    pairs = [(names[i], names[j], float(rho[i, j])) for i in range(len(names)) for j in range(i + 1, len(names))
             if robot[i] and robot[j] and abs(rho[i, j]) > limit]
    return sorted(pairs, key=lambda p: -abs(p[2]))


def parameter_table(result: CalibrationResult, correlation_limit: float = CORRELATION_LIMIT) -> list[ParameterRow]:
    """A row per parameter: the identified ones in order, then those held at nominal."""
    rho = result.correlation() if len(result.parameters) else np.zeros((0, 0))
    names = result.names
    rows = []
    for i, p in enumerate(result.parameters):
        dev = p.estimate - p.nominal
        flags = []
        if _is_setup(p.name):  # a set-up unknown: its "nominal" is the start the data gave
            rows.append(ParameterRow(p.name, p.unit, p.nominal, p.estimate, dev, p.sigma,
                                     (p.estimate - Z95 * p.sigma, p.estimate + Z95 * p.sigma), None,
                                     ["set-up unknown (started from the data)"]))
            continue
        others = [(names[j], rho[i, j]) for j in range(len(names))
                  if j != i and not _is_setup(names[j]) and abs(rho[i, j]) > correlation_limit]
        for other, r in sorted(others, key=lambda o: -abs(o[1])):
            flags.append(f"strongly correlated with {other} ({r:+.3f})")
        limit = PLAUSIBLE["base" if p.name.startswith("base.") else "other"].get(p.unit)  # None: joint-error block
        if limit is not None and abs(dev) > limit:
            flags.append(f"deviation larger than a plausible manufacturing error (> {limit:g} {p.unit})")
        rows.append(ParameterRow(p.name, p.unit, p.nominal, p.estimate, dev, p.sigma,
                                 (p.estimate - Z95 * p.sigma, p.estimate + Z95 * p.sigma),
                                 dev / p.sigma if p.sigma > 0 else None, flags))
    for h in result.held:
        unit = "deg" if h["name"].split(".")[1] in ("phi", "theta", "psi", "alpha", "beta") else "mm"
        rows.append(ParameterRow(h["name"], unit, h["value"], h["value"], 0.0, None, None, None,
                                 [f"not identifiable, held at nominal: {h['reason']}"]))
    return rows


def joint_error_verdict(result: CalibrationResult) -> list[str]:
    """What the report says of a joint-error block and of the model comparison, if any."""
    info = result.joint_errors or {}
    out = []
    sel = info.get("selection")
    if sel:
        rows = "; ".join(f"{s['model']} {s['cv_error']:.3g}" + (f" / {s['heldout_error']:.3g}" if s.get("heldout_error")
                                                                  is not None else "") for s in sel["scores"])
        held = " / held-out" if any(s.get("heldout_error") is not None for s in sel["scores"]) else ""
        unit = sel["scores"][0]["unit"] if sel["scores"] else ""
        out.append(f"Models compared by {sel['folds']}-fold cross-validation on the training poses (mean position "
                   f"error, {unit}, cross-validated{held}): {rows}. Recommended: {sel['reason']}.")
        for d in sel.get("drift", []):  # later poses predicted from earlier ones (fgcal.estimation.time_validation)
            later = "; ".join(f"{s['model']} {s['forward_error']:.3g} (max {s['forward_max']:.3g})"
                              for s in sel["scores"] if s.get("forward_error") is not None)
            out.append(f"Warning: {d[0].upper()}{d[1:]} (mean error at the later poses, {unit}: {later}).")
        for s in sel["scores"]:
            out += [f"Warning: {w}" for w in s.get("warnings", [])]
    if info.get("validity"):
        ranges = ", ".join(f"q{j + 1} {lo:.1f}..{hi:.1f}" for j, (lo, hi) in enumerate(info["joint_ranges_deg"]))
        out.append(f"This result carries a joint error map of {info['map_terms']} terms: {info['validity']} "
                   f"({ranges} deg). compensate and verify warn for joints outside.")
    return out


def verdict(result: CalibrationResult, verification: dict | None = None) -> list[str]:
    """Plain-language conclusions, most important first."""
    out = []
    if not result.converged:
        out.append("The solve did not converge: the estimates below are not to be used.")
    if result.held:
        by_reason: dict = {}
        for h in result.held:  # one reason once (the gauge holds six base parameters for one reason)
            by_reason.setdefault(h["reason"], []).append(h["name"])
        out.append("The data could not identify " + ", ".join(h["name"] for h in result.held)
                   + ": they are held at nominal (" + "; ".join(f"{', '.join(n)}: {r}" for r, n in by_reason.items())
                   + ").")
        costs = [(h["name"], h["cost_mm"]) for h in result.held if "cost_mm" in h]
        if costs:
            out.append("Holding them costs, if each deviates by a typical manufacturing error, "
                       + ", ".join(f"{n} {c:.2g} mm" for n, c in costs)
                       + " RMS position error at new poses (0: another parameter stands in for it everywhere; "
                       "more: poses that exercise it would identify it).")
    pairs = strong_correlations(result)
    if pairs:
        shown = ", ".join(f"{a} and {b} ({r:+.3f})" for a, b, r in pairs[:5])
        out.append(f"The data barely separate {len(pairs)} pair(s) of parameters: {shown}"
                   f"{f' and {len(pairs) - 5} more' if len(pairs) > 5 else ''}. Their sum or difference is known better "
                   "than each.")
    out += noise_verdict(result)
    implausible = [r.name for r in parameter_table(result) if any("plausible" in f for f in r.flags)]
    if implausible:
        out.append("Deviations larger than a plausible manufacturing error: " + ", ".join(implausible)
                   + ". Check the nominal model and the units.")
    out += joint_error_verdict(result)
    if verification is not None:
        after, before = verification["position_mm"], verification["before"]["position_mm"]
        out.append(f"At {verification['n_poses']} verification poses the position error went from "
                   f"{before['rms']:.3g} mm RMS (nominal) to {after['rms']:.3g} mm RMS "
                   f"(max {after['max']:.3g} mm) against the measurements.")
        if "truth" in verification:
            t = verification["truth"]["position_mm"]
            out.append(f"Against the simulated truth: {t['rms']:.3g} mm RMS, max {t['max']:.3g} mm.")
    if not out or (len(out) == 1 and verification is not None):
        what = "the estimated noise" if result.noise_mode in ("estimated", "reused") else "the assumed noise"
        out.insert(0, f"All {len(result.parameters)} parameters are identified; the residuals match {what}.")
    out += readings_note(result)
    return out


def outlier_location(o) -> str:
    where = f"line {o.line}" if o.line else f"row {o.index + 1}"
    return f"pose {o.pose}" + (f" ball {o.ball}" if o.ball else "") + f" ({where} of {o.level}.csv)"


def noise_verdict(result: CalibrationResult) -> list[str]:
    """What the residuals say about the noise: the levels whose declared noise is off, and the outliers."""
    out = []
    estimated = result.noise_mode in ("estimated", "reused")  # reused: the geometric fit's estimate
    off = []
    groups = result.noise_groups if len(result.noise_groups) > 1 else {}  # one camera's is its component's
    for name, n in (*result.noise.items(), *groups.items()):  # each camera's besides
        ratio = np.sqrt(n.variance_factor) if np.isfinite(n.variance_factor) else float("nan")
        if n.p_value < NOISE_P and (ratio > NOISE_RATIO or ratio < 1 / NOISE_RATIO):
            off.append((name, n, ratio))
    for name, n, ratio in off:
        label = name.replace("_", " ")
        if estimated and n.estimated is not None:
            why = ("the arm lands off its readings (repeatability, backlash) or they are coarser than declared"
                   if name == "joints" else "the instrument or the model's fit is worse than declared"
                   if ratio > 1 else "the declared noise is pessimistic")
            out.append(f"The {label} noise is {ratio:.2g} times the declared value ({n.declared:.3g} -> "
                       f"{n.estimated:.3g} {n.unit} estimated; test of the declared noise p = {n.p_value:.2g}): {why}. "
                       "The sigmas use the estimated noise.")
        elif ratio > 1:
            out.append(f"The {label} residuals are {ratio:.2g} times the assumed noise ({n.declared:.3g} {n.unit}; "
                       f"p = {n.p_value:.2g}): the noise is larger than assumed, or the model misses something. "
                       "Sigmas are optimistic by about that factor; the default --noise estimated corrects them.")
        else:
            out.append(f"The {label} residuals are {ratio:.2g} times the assumed noise: the assumed noise "
                       "is pessimistic, and so are the sigmas.")
    if estimated:
        fixed = [f"{name.replace('_', ' ')} ({n.note.split(': ', 1)[-1]})" for name, n in result.noise.items()
                 if n.estimated is None]
        if fixed:
            out.append("Noise kept at the declared value for " + "; ".join(fixed) + ".")
    for name, n in result.noise.items():
        s = result.levels.get(name)
        if name not in ("probes", "centres", "poses") or s is None or n.estimated is None or n.used < 2 * n.declared:
            continue
        out.append(f"About {np.sqrt(max(n.used**2 - n.declared**2, 0)):.3g} {n.unit} per coordinate of the {name} "
                   "scatter is what no geometric model explains here (compliance under gravity, gears, temperature); "
                   "the calibrated geometry cannot remove it.")
    if result.outliers:
        shown = "; ".join(f"{o.level} at {outlier_location(o)}: {o.residual:.3g} {o.unit} ({o.statistic:.2g} sigma)"
                          for o in result.outliers[:10])
        out.append(f"{len(result.outliers)} measurement(s) excluded as gross errors (re-measure them): {shown}"
                   f"{' ...' if len(result.outliers) > 10 else ''}.")
    return out


def readings_note(result: CalibrationResult) -> list[str]:
    """The error at the joint readings where it is well above the one after the joint variables moved."""
    out = []
    for level, at in result.at_readings.items():
        moved = result.levels.get(level)
        if moved is None or not moved.rms > 0 or at.rms < 1.5 * moved.rms:
            continue
        out.append(f"At the joint readings the {level} residuals are {at.rms:.3g} {at.unit} RMS; the "
                   f"{moved.rms:.3g} {moved.unit} RMS above is after the joint variables moved to absorb the "
                   "joints' noise. Predictions from joint readings carry the larger figure.")
    return out
