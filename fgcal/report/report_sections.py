"""The report's content as neutral blocks (headings, paragraphs, tables, figures), rendered by :mod:`fgcal.report.document`.

Answers "is this calibration good enough, and what next" from a result, a verification summary
(``verify.json``'s dict) and an optional position tolerance. No I/O, no plotting.
"""
from __future__ import annotations

import logging

import numpy as np

from fgcal.errors import FgcalError
from fgcal.estimation.result import CalibrationResult
from fgcal.report.accuracy import (
    OUTLIER_Z,
    AccuracyStats,
    accuracy_stats,
    flag_poses,
    held_parameter_cost,
    predicted_position_sigma,
    round_to_sigma,
    tolerance_verdict,
    verification_joints,
)
from fgcal.report.budget import budget_sentence, error_budget
from fgcal.report.camera_report import camera_sections
from fgcal.report.report_blocks import Block, ReportContent, Section, num
from fgcal.report.uncertainty import parameter_table, verdict

log = logging.getLogger(__name__)

__all__ = ["Block", "ReportContent", "Section", "build_content", "num", "training_flags"]

MAX_FLAGGED_ROWS = 30


def _listed(ids, limit: int = 20) -> str:
    """Pose ids as "1, 2, 3 and 7 more"."""
    text = ", ".join(map(str, ids[:limit]))
    return text + (f" and {len(ids) - limit} more" if len(ids) > limit else "")


def _stats_row(label: str, s: AccuracyStats, predicted: str = "-") -> list[str]:
    bias = "-" if s.bias_xyz is None else f"{num(s.bias)} ({', '.join(num(b) for b in s.bias_xyz)})"
    return [label, str(s.n), num(s.mean), num(s.std), num(s.rms), num(s.p95), num(s.max), bias, predicted]


STATS_HEADER = ["model vs reference", "poses", "mean (mm)", "std (mm)", "RMS (mm)", "95th percentile (mm)",
                "max (mm)", "mean error vector: length (x, y, z) (mm)", "predicted by the covariance (mm RMS)"]


def _next_steps(result, verification, tolerance, flags, predicted_rms, joints=None) -> list[str]:
    """What to do next; its first verdict from the error budget (:mod:`fgcal.report.budget`) at the
    verification ``joints`` (K, n; internal units, or None)."""
    out = []
    if verification is None:
        out.append("Verify the result on poses that were not used to calibrate (fgcal verify RESULT DATASET "
                   "--out verify.json) and give the report --verify verify.json: only errors at other poses "
                   "say whether the calibration is good enough.")
        return out
    after = verification["position_mm"]["rms"]
    if predicted_rms is not None or joints is not None:  # first: whether the noise or the model is the limit
        out.append(budget_sentence(result, after, error_budget(result, joints, predicted_rms)))
    if tolerance is None:
        out.append("No tolerance was given: run the report with --tolerance MM for a pass or fail.")
    outliers = [f.pose for f in flags if any(x.startswith("outlier") for x in f.flags)]
    if outliers:
        out.append(f"Outliers at poses {_listed(outliers)}: check or re-measure them before trusting the statistics.")
    worse = [f.pose for f in flags if "worse than the nominal model" in f.flags]
    if worse:
        out.append(f"{len(worse)} pose(s) got worse than with the nominal model: {_listed(worse)}.")
    return out


def _parameter_rows(result: CalibrationResult):
    header = ["name", "unit", "nominal", "estimate", "sigma", "deviation", "95% interval", "deviation/sigma", "flags"]
    rows, flagged = [], []
    for r in parameter_table(result):
        if r.sigma is None or r.interval95 is None:
            cells = [r.name, r.unit, f"{r.nominal:.8g}", f"{r.estimate:.8g}", "-", "0", "-", "-"]
        else:
            est, sig = round_to_sigma(r.estimate, r.sigma)
            dev, _ = round_to_sigma(r.deviation, r.sigma)
            lo, _ = round_to_sigma(r.interval95[0], r.sigma)
            hi, _ = round_to_sigma(r.interval95[1], r.sigma)
            cells = [r.name, r.unit, f"{r.nominal:.8g}", est, sig, dev, f"[{lo}, {hi}]",
                     "-" if r.z is None else f"{r.z:.1f}"]
        rows.append(cells + ["; ".join(r.flags)])
        flagged.append(bool(r.flags))
    return header, rows, flagged


def _pose_table(flags):
    header = ["pose", "calibrated error (mm)", "nominal error (mm)", "flags"]
    return header, [[str(f.pose), num(f.error_mm, 3), num(f.nominal_mm, 3), "; ".join(f.flags)] for f in flags]


def build_content(result: CalibrationResult, verification: dict | None = None, tolerance: float | None = None,
                  captions: dict[str, str] | None = None, title: str | None = None) -> ReportContent:
    """Everything the report says, in the order it says it."""
    if tolerance is not None and not tolerance > 0:
        raise FgcalError(f"--tolerance must be a positive length in mm, got {tolerance:g}")
    title = title or f"fgcal calibration report: {result.robot}, {result.n_poses} poses"
    top = Section("Is this calibration good enough?")
    flags, predicted, joints = [], None, verification_joints(verification)
    if joints is not None:
        try:
            joints = result.model().joints_to_internal(joints)
        except (FgcalError, ValueError) as exc:  # joints of another robot
            log.warning("verification joints not usable: %s", exc)
            joints = None
    if verification is not None:
        if tolerance is not None:
            tv = tolerance_verdict(verification, tolerance)
            top.blocks.append(Block("banner", tv.sentence(), status="pass" if tv.passed else "fail"))
        else:
            top.blocks.append(Block("banner", "No verdict: no tolerance was given (--tolerance MM).", status="none"))
        flags = flag_poses(verification, tolerance)
        if joints is not None and len(result.parameters):
            try:
                predicted = float(np.sqrt(np.mean(predicted_position_sigma(result, joints) ** 2)))
            except (FgcalError, ValueError, IndexError) as exc:  # a model the Jacobian cannot take
                predicted = None
                top.blocks.append(Block("p", f"The predicted error could not be computed ({exc})."))
    else:
        top.blocks.append(Block("banner", "No verdict: the report has no verification (--verify verify.json).",
                                status="none"))
    top.blocks.append(Block("p", "What next:"))
    top.blocks.append(Block("ul", items=_next_steps(result, verification, tolerance, flags, predicted, joints)))
    top.blocks.append(Block("p", "What the calibration says about itself:"))
    top.blocks.append(Block("ul", items=verdict(result, verification)))
    sections = [top]

    if verification is not None:
        acc = Section("Accuracy at the verification poses (ISO 9283 style)")
        poses = verification.get("poses") or []
        have_vec = poses and all("error_xyz_mm" in p for p in poses)
        rows = []
        for label, key, vec in (("nominal vs measured", "before_position_mm", "before_error_xyz_mm"),
                                ("calibrated vs measured", "position_mm", "error_xyz_mm")):
            s = accuracy_stats([p[key] for p in poses], [p[vec] for p in poses] if have_vec else None)
            rows.append(_stats_row(label, s, num(predicted) if key == "position_mm" and predicted else "-"))
        if poses and all("truth_position_mm" in p for p in poses):
            truth = accuracy_stats([p["truth_position_mm"] for p in poses])
            rows.append(_stats_row("calibrated vs simulated truth", truth))
        acc.blocks.append(Block("table", header=STATS_HEADER, rows=rows))
        acc.blocks.append(Block("p", "Each pose was visited once, so the error at a pose is its accuracy AP in the "
                                     "sense of ISO 9283 (distance from the commanded to the attained position); "
                                     "repeatability (RP) needs repeated visits and is not measured here. The mean "
                                     "error vector is the systematic part of the error. The predicted column is "
                                     "the error the parameters' covariance alone implies at these poses."))
        shown = [f for f in flags if f.flags]
        if shown:
            worst = sorted(shown, key=lambda f: -f.error_mm)[:MAX_FLAGGED_ROWS]
            header, rows = _pose_table(worst)
            acc.blocks.append(Block("p", f"{len(shown)} pose(s) need a look"
                                         + (f" (the {MAX_FLAGGED_ROWS} largest errors shown):" if len(shown) >
                                            MAX_FLAGGED_ROWS else ":")))
            acc.blocks.append(Block("table", header=header, rows=rows, row_flags=[True] * len(rows)))
        else:
            acc.blocks.append(Block("p", "No verification pose is an outlier, beyond the tolerance or worse than "
                                         "with the nominal model."))
        if flags:
            header, rows = _pose_table(sorted(flags, key=lambda f: -f.error_mm))
            acc.blocks.append(Block("details", f"All {len(flags)} verification poses, largest error first",
                                    header=header, rows=rows))
        sections.append(acc)

    if getattr(result, "pose_residuals", None):
        sections.append(_training_section(result))

    if result.held:
        held = Section("What the parameters held at nominal cost")
        where = "At the verification poses"
        q = joints
        try:
            if q is None:  # no verification joints: random joint sets within the limits
                limits = np.asarray(result.model().joint_limits, dtype=float)
                q = np.random.default_rng(0).uniform(limits[:, 0], limits[:, 1], size=(200, len(limits)))
                where = "Over 200 random joint sets within the joint limits (no verification joints given)"
            costs = held_parameter_cost(result, q)
            held.blocks.append(Block("ul", items=[c.sentence()[0].upper() + c.sentence()[1:] for c in costs]))
            angles = [c.name for c in costs if c.name.startswith("tool.") and c.unit == "deg"]
            if angles:
                held.blocks.append(Block("p", f"The held tool angles ({', '.join(angles)}) do not move the tool "
                                              "frame's origin, but they turn a TCP placed away from it: "
                                              f"{num(np.radians(0.05) * 100.0)} mm per 100 mm of lever for a "
                                              "typical 0.05 deg."))
            held.blocks.append(Block("p", f"{where}, for the tool frame's origin, after the identified parameters "
                                          "are re-fitted to absorb what they can; a typical deviation is "
                                          "DESIGN.md's (0.5 mm, 0.05 deg; base 5 mm, 0.5 deg)."))
        except (FgcalError, ValueError, IndexError) as exc:  # a model the Jacobian cannot take
            held.blocks.append(Block("p", f"Cannot say for this model ({exc})."))
        sections.append(held)


    sections += camera_sections(result)  # a camera's reprojection residuals per image and over the image
    header, rows, flagged = _parameter_rows(result)
    sections.append(Section("Parameters", [
        Block("p", "Estimates and intervals are rounded to the digits their standard deviation supports "
                   "(two significant digits of sigma); result.json keeps the full values."),
        Block("table", header=header, rows=rows, row_flags=flagged)]))
    sections.append(Section("Calibration", [Block("table", header=[], rows=[list(r) for r in _summary(result)])]))
    if captions:
        sections.append(Section("Figures", [Block("figure", name=n, text=c) for n, c in captions.items()]))
    return ReportContent(title, sections)


def training_flags(result: CalibrationResult) -> list:
    """Each calibration pose's flags (:func:`~fgcal.accuracy.flag_poses` on its residual at the readings
    against the nominal geometry's), plus its measurements excluded as gross errors."""
    rows = [p for p in result.pose_residuals if np.isfinite(p.rms_mm)]
    flags = flag_poses({"poses": [{"pose": p.pose, "position_mm": p.rms_mm, "before_position_mm": p.nominal_mm}
                                  for p in rows]})
    for f, p in zip(flags, rows):
        if p.excluded:
            f.flags.append(f"{p.excluded} measurement(s) excluded as gross errors")
    return flags


def _training_section(result: CalibrationResult) -> Section:
    sec = Section("Residuals at the calibration poses")
    res = {p.pose: p for p in result.pose_residuals}
    flags = training_flags(result)
    outliers = [f.pose for f in flags if any(x.startswith("outlier") for x in f.flags)]
    excluded = [p.pose for p in result.pose_residuals if p.excluded]
    sec.blocks.append(Block("p", "What the calibrated model misses at each calibration pose, with the joints at their "
                                 "readings (the error a user of the readings sees), after the joint variables moved "
                                 "to absorb the readings' noise, and with the nominal geometry (base fitted). A "
                                 "pose's residuals are its probe points' distances off their spheres and its measured "
                                 "centres' and poses' position errors."))
    if "pixels" in getattr(result, "levels", {}):  # camera data: a pose is an image (DESIGN.md 8.4)
        only = set(result.levels) <= {"pixels", "prior", "joints", "constraints"}
        sec.blocks.append(Block("p", "A camera's pose is an image: its residual is the RMS reprojection error of "
                                     "its corners, in px" + (" (the columns below read px, not mm)." if only else
                                     ", summed with the other instruments' mm in this table.")))
    if outliers:
        sec.blocks.append(Block("p", f"Outlier poses (residual at the readings more than {OUTLIER_Z:g} robust sigma "
                                     f"above the median): {_listed(outliers)}. Check their joint readings and "
                                     "measurements, or re-measure them."))
    if excluded:
        sec.blocks.append(Block("p", f"Poses with measurements excluded as gross errors (re-measure them): "
                                     f"{_listed(excluded)}."))
    if not outliers and not excluded:
        sec.blocks.append(Block("p", "No calibration pose is an outlier and no measurement was excluded."))
    header = ["pose", "at the readings (mm RMS)", "after the joints moved (mm RMS)", "nominal (mm RMS)",
              "largest (mm)", "flags"]

    def row(f):
        p = res[f.pose]
        return [str(p.pose), num(p.rms_mm, 3), num(p.moved_mm, 3), num(p.nominal_mm, 3), num(p.max_mm, 3),
                "; ".join(f.flags)]

    ranked = sorted(flags, key=lambda f: -f.error_mm)
    shown = [f for f in ranked if f.flags][:MAX_FLAGGED_ROWS]
    if shown:
        sec.blocks.append(Block("table", header=header, rows=[row(f) for f in shown], row_flags=[True] * len(shown)))
    sec.blocks.append(Block("details", f"All {len(ranked)} calibration poses, largest residual first", header=header,
                            rows=[row(f) for f in ranked]))
    return sec


def _summary(result: CalibrationResult) -> list[tuple[str, str]]:
    items = [("robot", result.robot), ("poses", str(result.n_poses)),
             ("parameters identified", f"{len(result.parameters)} (held at nominal: {len(result.held)})"),
             ("solve", f"{result.iterations} iterations, {'converged' if result.converged else 'NOT converged'}"),
             ("condition number (scaled information)", num(result.condition_number, 3))]
    for level, s in result.levels.items():
        if level in ("kinematic", "prior"):
            continue
        text = (f"{num(s.rms, 3)} {s.unit} RMS over {s.n} (assumed sigma {num(s.sigma)} {s.unit}; "
                f"variance factor {num(s.variance_factor)})")
        if s.rms_rotation_deg is not None:
            text += f"; rotation {num(s.rms_rotation_deg, 3)} deg RMS"
        items.append((f"residuals: {level}", text))
    for name, at in getattr(result, "at_readings", {}).items():
        rot = f"; rotation {num(at.rms_rotation_deg, 3)} deg RMS" if at.rms_rotation_deg is not None else ""
        items.append((f"residuals at the joint readings: {name}", f"{num(at.rms, 3)} {at.unit} RMS over {at.n}{rot}"))
    for name, n in getattr(result, "noise", {}).items():
        est = num(n.estimated) if n.estimated is not None else "-"
        items.append((f"noise ({result.noise_mode}): {name}", f"declared {num(n.declared)} {n.unit}, estimated {est}, "
                      f"used {num(n.used)}; redundancy {num(n.redundancy, 4)}; test of the declared p = {num(n.p_value)}"))
    return items
