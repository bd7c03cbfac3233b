"""``fgcal.calibrate``: the batch calibration of a dataset, with the checks and notes of ``fgcal calibrate``.

The command (:mod:`fgcal.cli.commands.calibrate`) parses its options, calls :func:`calibrate`,
saves the result and prints :func:`calibration_summary`; every default is this function's.
"""
from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from fgcal.api.notes import note, warn
from fgcal.api.selection import MAX_BATCH_ROWS, measurement_rows, parameter_names, select_poses
from fgcal.errors import FgcalError

if TYPE_CHECKING:
    from fgcal.estimation.result import CalibrationResult
    from fgcal.measurements.dataset import Dataset

__all__ = ["KEEP", "MODELS", "calibrate", "calibration_summary", "load_datasets", "parse_payload"]

log = logging.getLogger(__name__)

MODELS = ("geometric", "compliance", "compliance+map")
KEEP = ("asked", "recommended")
SHOWN_JOINT_ERRORS = 12  # joint-error parameters listed one a line; beyond, one line per joint


def load_datasets(dataset) -> tuple[Dataset, str]:
    """One dataset from a directory, a :class:`Dataset` or several of either (each a station).

    Returns
    -------
    dataset : Dataset
    where : str
        How messages name it (its directory, or the directories joined).
    """
    from fgcal.io.dataset_io import load_dataset

    many = isinstance(dataset, list | tuple)
    items = list(dataset) if many else [dataset]
    if not items:
        raise FgcalError("calibrate: no dataset")
    loaded = [load_dataset(d) if isinstance(d, str | Path) else d for d in items]
    names = [str(d) if isinstance(d, str | Path) else str(ds.path or f"dataset {k + 1}")
             for k, (d, ds) in enumerate(zip(items, loaded, strict=True))]
    if len(loaded) == 1:
        return loaded[0], names[0]
    return _merged([Path(n) for n in names], loaded), ", ".join(names)


def _merged(paths: list[Path], datasets: list) -> Dataset:
    """Several datasets of one robot as one, each a station (:func:`fgcal.measurements.merge.merge_datasets`)."""
    from fgcal.io.dataset_io import dataset_model
    from fgcal.measurements.merge import merge_datasets
    from fgcal.robots.robot_file import model_to_dict

    names = [p.resolve().name or str(p) for p in paths]
    if len(set(names)) < len(names):
        raise FgcalError("calibrate: the datasets' directory names (their station names) must differ")
    first = model_to_dict(dataset_model(datasets[0]))
    for path, ds in zip(paths[1:], datasets[1:], strict=True):
        if model_to_dict(dataset_model(ds)) != first:
            raise FgcalError(f"{path}: its robot model differs from {paths[0]}'s: calibrate one robot at a time")
    return merge_datasets(datasets, names)


def parse_payload(payload):
    """A :class:`~fgcal.robots.gravity.Payload` from None, itself, ``"KG"``/``"KG,X,Y,Z"`` or a sequence (kg, mm)."""
    from fgcal.robots.gravity import Payload

    if payload is None or payload == "":
        return Payload()
    if isinstance(payload, Payload):
        return payload
    text = payload if isinstance(payload, str) else ",".join(map(str, payload))
    try:
        v = [float(x) for x in text.split(",")]
    except ValueError:
        v = []
    if len(v) not in (1, 4) or not np.all(np.isfinite(v)) or v[0] < 0:
        raise FgcalError(f"--payload: expected KG or KG,X,Y,Z (kg, mm in the tool frame), got {text!r}")
    return Payload(v[0], (v[1], v[2], v[3]) if len(v) == 4 else (0.0, 0.0, 0.0))


def calibrate(dataset, *, poses: str | Sequence[int] | None = None, levels: str | Sequence[str] | None = None,
              robust: str | None = None, engine: str = "batch", prior: str = "none", noise: str = "estimated",
              outliers: str = "exclude", exact_joints: bool = False, extra: str | Sequence[str] | None = None,
              exclude: str | Sequence[str] | None = None, model: str = "geometric", keep: str = "asked",
              verification=None, folds: int = 5, max_harmonics: int = 30, seed: int = 0,
              fold_order: str = "random", payload: Any = None) -> CalibrationResult:
    """Calibrate the robot of ``dataset``: what ``fgcal calibrate`` does, without writing.

    Parameters
    ----------
    dataset : path, Dataset, or a list of either
        A dataset directory or a loaded dataset; several: one robot measured in several sessions
        or from several stations, each a station named after its directory (the first is the world).
    poses : str or sequence of int, optional
        The poses to use: ``odd``, ``even``, ``first:N``, ``last:N``, ranges like ``1-21,30``, or pose ids.
    levels : str or sequence of str, optional
        Measurement levels to use (``probes``, ``centres``, ``poses``, ...); all present by default.
    robust : {None, "huber", "cauchy"}
        Robust loss on the measurements.
    engine : {"batch", "gtsam"}
        fgcal's batched Levenberg-Marquardt, or GTSAM's optimiser on the same graph (slower, same result).
    prior : {"none", "weak"}
        ``weak``: ten times the typical deviation on every parameter.
    noise : {"estimated", "declared"}
        Each level's noise estimated from the residuals where the redundancy allows, or
        dataset.yaml's values only.
    outliers : {"exclude", "none"}
        Detect, exclude and name gross errors, or keep every measurement.
    exact_joints : bool
        Treat the joint readings as exact.
    extra, exclude : str or sequence of str, optional
        Slots to estimate beyond the default ones (e.g. ``j1.theta``) / to hold at nominal.
    model : {"geometric", "compliance", "compliance+map"}
        Beyond geometry: gravity compliance of the loaded joints, plus a per-joint error map; the
        simpler models are calibrated and scored by cross-validation too.
    keep : {"asked", "recommended"}
        With a model comparison, return the model asked for or the one the comparison recommends.
    verification : path or Dataset, optional
        Held-out poses: each model's error there is reported (never used for fitting).
    folds : int
        Cross-validation folds (model comparison).
    max_harmonics : int
        Largest number of map harmonics per joint the cross-validation tries.
    seed : int
        Seed of the fold assignment.
    fold_order : {"random", "blocked"}
        Folds drawn at random, or as contiguous stretches of the poses in id (time) order.
    payload : str, sequence or Payload, optional
        Load on the tool for the gravity torques: ``KG`` or ``KG,X,Y,Z`` (kg; mm in the tool frame).

    Returns
    -------
    CalibrationResult
        ``result.save(path)`` writes ``fgcal-result/1``.

    Warns
    -----
    FgcalWarning
        Values that look like a unit mistake (radians in joints.csv, metres for millimetres).
    FgcalNote
        Poses not used (no measurement at the levels used).
    """
    from fgcal.estimation.calibrate import calibrate as solve
    from fgcal.estimation.noise import NoiseMode, OutlierMode
    from fgcal.estimation.options import CalibrationOptions
    from fgcal.estimation.sanity import unit_warnings, unused_poses
    from fgcal.io.dataset_io import dataset_model

    for value, allowed, option in ((noise, ("estimated", "declared"), "--noise"),
                                   (outliers, ("exclude", "none"), "--outliers"),
                                   (engine, ("batch", "gtsam"), "--engine"), (prior, ("none", "weak"), "--prior"),
                                   (robust, (None, "huber", "cauchy"), "--robust"),
                                   (fold_order, ("random", "blocked"), "--fold-order")):
        if value not in allowed:
            raise FgcalError(f"{option} {value!r}: one of {', '.join(str(a) for a in allowed)}")
    if model not in MODELS:
        raise FgcalError(f"--model {model!r}: one of {', '.join(MODELS)}")
    if keep not in KEEP:
        raise FgcalError(f"--keep {keep!r}: one of {', '.join(KEEP)}")
    payload = parse_payload(payload)
    ds, where = load_datasets(dataset)
    robot = dataset_model(ds)
    for w in unit_warnings(ds, robot):
        warn(w)
    ds = select_poses(ds, poses)
    rows = measurement_rows(ds)
    if rows > MAX_BATCH_ROWS:
        raise FgcalError(f"{where}: {rows} measurement rows ({ds.n_poses} poses) are more than a batch "
                         f"calibration holds in memory ({MAX_BATCH_ROWS}); choose poses with --select, or use "
                         "fgcal online")
    level_names = tuple(levels.split(",")) if isinstance(levels, str) else (tuple(levels) if levels else None)
    options = CalibrationOptions(
        levels=level_names, robust=robust, prior=prior, joint_noise=not exact_joints, noise=NoiseMode(noise),
        outliers=OutlierMode(outliers), extra=parameter_names(robot, extra, "--extra"),
        exclude=parameter_names(robot, exclude, "--exclude"), engine=engine)
    if model == "geometric" and verification is None:
        result = solve(ds, robot, options)
    else:
        result = _compare_models(ds, robot, options, model, keep, verification, folds, max_harmonics, seed,
                                 fold_order, payload)
    for message in unused_poses(ds, result.pose_ids, options.levels or ds.levels()):
        note(message)
    return result


def _compare_models(ds, robot, options, model, keep, verification, folds, max_harmonics, seed, fold_order, payload):
    """The cross-validated comparison of the models up to ``model``; the one asked for, or the recommended one."""
    from fgcal.estimation.model_select import HARMONICS_GRID, compare_models
    from fgcal.io.dataset_io import load_dataset

    ver = load_dataset(verification) if isinstance(verification, str | Path) else verification
    grid = tuple(h for h in HARMONICS_GRID if h < max_harmonics) + (max_harmonics,)
    results, selection = compare_models(ds, robot, options, up_to=model, verification=ver, folds=folds,
                                        rng=np.random.default_rng(seed), payload=parse_payload(payload),
                                        harmonics_grid=grid, fold_order=fold_order)
    return results[selection.recommended if keep == "recommended" else model]


def calibration_summary(result: CalibrationResult) -> list[str]:
    """The lines ``fgcal calibrate`` prints for ``result``: fit, noise, outliers, held and estimated parameters.

    A joint-error block of more than a dozen parameters is shown as one line per joint (its
    values are in the result and in ``fgcal export --deltas``).
    """
    from fgcal.report.report_sections import training_flags
    from fgcal.report.uncertainty import outlier_location

    out = [f"calibrated {result.robot} from {result.n_poses} poses: {result.iterations} iterations, "
           f"{'converged' if result.converged else 'NOT converged'}; condition number {result.condition_number:.3g}"]
    for level, s in result.levels.items():
        if level in ("kinematic", "prior"):
            continue
        extra = f", rotation {s.rms_rotation_deg:.4g} deg" if s.rms_rotation_deg is not None else ""
        out.append(f"  {level:8s} {s.n:6d}  rms {s.rms:.4g} {s.unit}{extra}  (sigma {s.sigma:.3g}; "
                   f"variance factor {s.variance_factor:.3g})")
    for name, r in result.at_readings.items():
        extra = f", rotation {r.rms_rotation_deg:.4g} deg" if r.rms_rotation_deg is not None else ""
        out.append(f"  {name:8s} at the joint readings: rms {r.rms:.4g} {r.unit}{extra}")
    out.append(f"  noise ({result.noise_mode}):")
    groups = result.noise_groups if len(result.noise_groups) > 1 else {}  # one camera's is its component's
    for name, n in (*result.noise.items(), *groups.items()):  # then each camera's own
        est = f"estimated {n.estimated:.3g}" if n.estimated is not None else n.note
        out.append(f"    {name:15s} declared {n.declared:.3g} {n.unit}, {est}; "
                   f"test of the declared: p = {n.p_value:.2g}")
    for o in result.outliers:
        out.append(f"  excluded as a gross error: {o.level} at {outlier_location(o)}, {o.residual:.3g} {o.unit} "
                   f"({o.statistic:.3g} sigma)")
    odd = [f for f in training_flags(result) if any(x.startswith("outlier") for x in f.flags)]
    if odd:
        out.append("  outlier poses (residual at the joint readings): "
                   + ", ".join(f"{f.pose} ({f.error_mm:.3g} mm)" for f in odd[:10]) + (" ..." if len(odd) > 10 else ""))
    for h in result.held:
        cost = f"; costs {h['cost_mm']:.3g} mm at new poses" if "cost_mm" in h else ""
        out.append(f"  held at nominal: {h['name']} = {h['value']:g} ({h['reason']}{cost})")
    block = set(result.joint_errors.get("names") or ())
    shown = [p for p in result.parameters if p.name not in block or len(block) <= SHOWN_JOINT_ERRORS]
    out.append(f"  {'parameter':12s} {'nominal':>12s} {'estimate':>14s} {'sigma':>10s}")
    for p in shown:
        out.append(f"  {p.name:12s} {p.nominal:12.6g} {p.estimate:14.8g} {p.sigma:10.3g} {p.unit}")
    if len(block) > SHOWN_JOINT_ERRORS:
        out += _joint_error_lines(result, block)
    out += _selection_lines(result)
    return out


def _joint_error_lines(result, block: set) -> list[str]:
    """One line per joint of a large joint-error block: its compliance and its map's size and amplitude."""
    per_joint: dict[str, dict] = {}
    for p in result.parameters:
        if p.name not in block:
            continue
        parts = p.name.split(".")
        joint = parts[1] if parts[0] == "map" else parts[0]
        entry = per_joint.setdefault(joint, {"compliance": None, "map": []})
        if parts[-1] == "compliance":
            entry["compliance"] = p
        else:
            entry["map"].append(p.estimate)
    out = [f"  joint-error block: {len(block)} parameters (in the result; fgcal export --deltas writes them)"]
    for joint, entry in per_joint.items():
        text = f"    {joint}:"
        c = entry["compliance"]
        if c is not None:
            text += f" compliance {c.estimate:.4g} +- {c.sigma:.2g} {c.unit}"
        if entry["map"]:
            amp = float(np.sqrt(np.sum(np.square(entry["map"])) / 2))
            text += (f"{';' if c is not None else ''} map of {len(entry['map']) // 2} harmonics, "
                     f"RMS amplitude {amp:.3g} urad")
        out.append(text)
    return out


def _selection_lines(result) -> list[str]:
    """The model comparison's table and recommendation, when there was one."""
    out = []
    sel = result.joint_errors.get("selection")
    if result.joint_errors.get("validity"):
        ranges = ", ".join(f"q{j + 1} {lo:.1f}..{hi:.1f}" for j, (lo, hi) in
                           enumerate(result.joint_errors["joint_ranges_deg"]))
        out.append(f"  NOTE: {result.joint_errors['validity']}: {ranges} deg")
    if not sel:
        return out
    out.append(f"  {'model':15s} {'parameters':>10s} {'cross-validated':>16s} {'held-out':>10s}  "
               f"({sel['folds']} folds)")
    for s in sel["scores"]:
        held = f"{s['heldout_error']:.4g}" if s.get("heldout_error") is not None else "-"
        out.append(f"  {s['model']:15s} {s['n_parameters']:10d} {s['cv_error']:12.4g} {s['unit']:3s} {held:>10s}")
        for w in s.get("warnings", []):
            out.append(f"    warning: {w}")
    out.append(f"  recommended: {sel['reason']}")
    if sel.get("recommended") and sel["recommended"] != _model_of(result):
        out.append(f"  this result is the {_model_of(result)} model; --keep recommended writes the "
                   f"{sel['recommended']} one")
    return out


def _model_of(result) -> str:
    """``geometric``, ``compliance`` or ``compliance+map``: the model of ``result``."""
    spec = result.joint_errors.get("spec") or {}
    if not result.joint_errors.get("names"):
        return "geometric"
    return "compliance+map" if spec.get("harmonics") else "compliance"
