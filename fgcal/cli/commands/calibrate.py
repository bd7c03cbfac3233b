"""``fgcal calibrate``: the command's body (its options are in :func:`fgcal.cli.build_parser`)."""
from __future__ import annotations

import logging

import numpy as np

from fgcal.cli.commands.check import _measurement_rows, _warn_units
from fgcal.cli.commands.checks import MAX_BATCH_ROWS, check_output_file, dataset_inputs, parameter_names
from fgcal.errors import FgcalError
from fgcal.estimation.noise import NoiseMode, OutlierMode

log = logging.getLogger("fgcal")


def parse_pose_selection(text: str | None, available) -> np.ndarray:
    """Pose ids from ``odd``, ``even``, ``first:N``, ``last:N`` or ranges like ``1-21,30``."""
    available = np.asarray(available, dtype=int)
    if text is None:
        return available
    text = text.strip()
    if text in ("odd", "even"):
        chosen = available[available % 2 == (1 if text == "odd" else 0)]
        if not len(chosen):
            raise FgcalError(f"--poses {text}: the dataset has no {text} pose ids")
        return chosen
    for prefix in ("first:", "last:"):
        if text.startswith(prefix):
            try:
                n = int(text[len(prefix):])
            except ValueError:
                raise FgcalError(f"--poses {text!r}: expected {prefix}N") from None
            if n < 1:
                raise FgcalError(f"--poses {text!r}: N must be at least 1")
            if n > len(available):
                raise FgcalError(f"--poses {text!r}: the dataset has only {len(available)} poses")
            return available[:n] if prefix == "first:" else available[-n:]
    chosen = []
    for part in text.split(","):
        part = part.strip()
        try:
            first, last = part.split("-", 1) if "-" in part[1:] and not part.startswith("-") else (part, part)
            a, b = int(first), int(last)
        except ValueError:
            raise FgcalError(f"--poses {text!r}: expected odd, even, first:N, last:N or ranges like 1-21,30") from None
        if b < a:
            raise FgcalError(f"--poses: range {a}-{b} is empty (write it as {b}-{a})")
        if b - a >= len(available):
            raise FgcalError(f"--poses: range {a}-{b} spans more ids than the {len(available)} poses of the dataset")
        chosen.extend(range(a, b + 1))
    missing = sorted(set(chosen) - set(available.tolist()))
    if missing:
        raise FgcalError(f"--poses: pose(s) {', '.join(map(str, missing[:10]))} not in the dataset")
    if not chosen:
        raise FgcalError(f"--poses {text!r}: selects no pose")
    return np.array(sorted(set(chosen)), dtype=int)


def _print_result(result) -> None:
    print(f"calibrated {result.robot} from {result.n_poses} poses: {result.iterations} iterations, "
          f"{'converged' if result.converged else 'NOT converged'}; condition number {result.condition_number:.3g}")
    for level, s in result.levels.items():
        if level in ("kinematic", "prior"):
            continue
        extra = f", rotation {s.rms_rotation_deg:.4g} deg" if s.rms_rotation_deg is not None else ""
        print(f"  {level:8s} {s.n:6d}  rms {s.rms:.4g} {s.unit}{extra}  (sigma {s.sigma:.3g}; "
              f"variance factor {s.variance_factor:.3g})")
    for name, s in result.at_readings.items():
        extra = f", rotation {s.rms_rotation_deg:.4g} deg" if s.rms_rotation_deg is not None else ""
        print(f"  {name:8s} at the joint readings: rms {s.rms:.4g} {s.unit}{extra}")
    print(f"  noise ({result.noise_mode}):")
    for name, n in result.noise.items():
        est = f"estimated {n.estimated:.3g}" if n.estimated is not None else n.note
        print(f"    {name:15s} declared {n.declared:.3g} {n.unit}, {est}; test of the declared: p = {n.p_value:.2g}")
    from fgcal.report.uncertainty import outlier_location

    for o in result.outliers:
        print(f"  excluded as a gross error: {o.level} at {outlier_location(o)}, {o.residual:.3g} {o.unit} "
              f"({o.statistic:.3g} sigma)")
    from fgcal.report.report_sections import training_flags

    odd = [f for f in training_flags(result) if any(x.startswith("outlier") for x in f.flags)]
    if odd:
        print("  outlier poses (residual at the joint readings): "
              + ", ".join(f"{f.pose} ({f.error_mm:.3g} mm)" for f in odd[:10]) + (" ..." if len(odd) > 10 else ""))
    for h in result.held:
        cost = f"; costs {h['cost_mm']:.3g} mm at new poses" if "cost_mm" in h else ""
        print(f"  held at nominal: {h['name']} = {h['value']:g} ({h['reason']}{cost})")
    print(f"  {'parameter':12s} {'nominal':>12s} {'estimate':>14s} {'sigma':>10s}")
    for p in result.parameters:
        print(f"  {p.name:12s} {p.nominal:12.6g} {p.estimate:14.8g} {p.sigma:10.3g} {p.unit}")


def _cmd_calibrate(args) -> int:
    from fgcal.estimation.calibrate import calibrate
    from fgcal.estimation.options import CalibrationOptions
    from fgcal.estimation.result import save_result
    from fgcal.io.dataset_io import dataset_model, load_dataset

    paths = args.dataset if isinstance(args.dataset, list) else [args.dataset]
    for path in paths:
        check_output_file(args.out, dataset_inputs(path))
    loaded = [load_dataset(path) for path in paths]
    for path, one in zip(paths, loaded):
        check_output_file(args.out, dataset_inputs(path, one.robot))
    ds = loaded[0] if len(loaded) == 1 else _merged(paths, loaded)
    args.dataset = paths[0] if len(paths) == 1 else ", ".join(map(str, paths))
    model = dataset_model(ds)
    _warn_units(ds, model)
    ids = parse_pose_selection(args.poses, ds.pose_ids)
    if len(ids) != ds.n_poses:
        ds = ds.select(ids)
    rows = _measurement_rows(ds)
    if rows > MAX_BATCH_ROWS:
        raise FgcalError(f"{args.dataset}: {rows} measurement rows ({ds.n_poses} poses) are more than a batch "
                         f"calibration holds in memory ({MAX_BATCH_ROWS}); choose poses with --poses, or use "
                         "fgcal online")
    extra = parameter_names(model, args.extra, "--extra")
    exclude = parameter_names(model, args.exclude, "--exclude")
    options = CalibrationOptions(
        levels=tuple(args.levels.split(",")) if args.levels else None, robust=args.robust, prior=args.prior,
        joint_noise=not args.exact_joints, estimate_noise=getattr(args, "estimate_noise", False),
        noise=NoiseMode(getattr(args, "noise", "estimated")),
        outliers=OutlierMode(getattr(args, "outliers", "exclude")),
        extra=extra, exclude=exclude, engine=getattr(args, "engine", "batch"))
    if getattr(args, "model", "geometric") == "geometric" and getattr(args, "verification", None) is None:
        result = calibrate(ds, model, options)
    else:
        result = _compare_models(args, ds, model, options)
    save_result(result, args.out)
    from fgcal.estimation.sanity import unused_poses

    for note in unused_poses(ds, result.pose_ids, options.levels or ds.levels()):
        print(f"note: {note}")
    _print_result(result)
    _print_selection(result)
    print(f"wrote {args.out}")
    return 0


def _merged(paths, datasets):
    """Several datasets of one robot as one, each a station (:func:`fgcal.measurements.merge.merge_datasets`)."""
    from fgcal.io.dataset_io import dataset_model
    from fgcal.measurements.merge import merge_datasets
    from fgcal.robots.robot_file import model_to_dict

    names = [p.resolve().name or str(p) for p in paths]
    if len(set(names)) < len(names):
        raise FgcalError("calibrate: the datasets' directory names (their station names) must differ")
    first = model_to_dict(dataset_model(datasets[0]))
    for path, ds in zip(paths[1:], datasets[1:]):
        if model_to_dict(dataset_model(ds)) != first:
            raise FgcalError(f"{path}: its robot model differs from {paths[0]}'s: calibrate one robot at a time")
    return merge_datasets(datasets, names)


def _parse_payload(text):
    from fgcal.robots.gravity import Payload

    if not text:
        return Payload()
    try:
        v = [float(x) for x in text.split(",")]
    except ValueError:
        v = []
    if len(v) not in (1, 4) or v[0] < 0:
        raise FgcalError(f"--payload: expected KG or KG,X,Y,Z (kg, mm in the tool frame), got {text!r}")
    return Payload(v[0], tuple(v[1:]) if len(v) == 4 else (0.0, 0.0, 0.0))


def _compare_models(args, ds, model, options):
    """``calibrate --model``: cross-validated comparison of the models up to the one asked for."""
    from fgcal.estimation.model_select import HARMONICS_GRID, compare_models
    from fgcal.io.dataset_io import load_dataset

    ver = load_dataset(args.verification) if args.verification is not None else None
    results, _ = compare_models(ds, model, options, up_to=args.model, verification=ver, folds=args.folds,
                                rng=np.random.default_rng(args.seed), payload=_parse_payload(args.payload),
                                harmonics_grid=tuple(h for h in HARMONICS_GRID if h < args.max_harmonics)
                                + (args.max_harmonics,), fold_order=args.fold_order)
    return results[args.model]


def _print_selection(result) -> None:
    sel = result.joint_errors.get("selection")
    if result.joint_errors.get("validity"):
        ranges = ", ".join(f"q{j + 1} {lo:.1f}..{hi:.1f}" for j, (lo, hi) in
                           enumerate(result.joint_errors["joint_ranges_deg"]))
        print(f"  NOTE: {result.joint_errors['validity']}: {ranges} deg")
    if not sel:
        return
    print(f"  {'model':15s} {'parameters':>10s} {'cross-validated':>16s} {'held-out':>10s}  ({sel['folds']} folds)")
    for s in sel["scores"]:
        held = f"{s['heldout_error']:.4g}" if s.get("heldout_error") is not None else "-"
        print(f"  {s['model']:15s} {s['n_parameters']:10d} {s['cv_error']:12.4g} {s['unit']:3s} {held:>10s}")
        for w in s.get("warnings", []):
            print(f"    warning: {w}")
    print(f"  recommended: {sel['reason']}")
