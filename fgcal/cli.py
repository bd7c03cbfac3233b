"""The ``fgcal`` command line: a thin layer over the library.

A user's mistake (a bad file, an impossible option) ends in one line on standard error and
exit status 2, with no traceback.
"""
from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path

import numpy as np

from . import __version__
from .cli_checks import (check_output_dir, check_output_file, dataset_inputs, finite_float, nonnegative_float,
                         nonnegative_int, os_error_message, parameter_names, positive_float, positive_int)
from .errors import FgcalError

log = logging.getLogger("fgcal")

MAX_POSES = 200_000  # simulated poses or design candidates: beyond this, memory runs out
MAX_BATCH_ROWS = 250_000  # measurement rows of one batch graph (calibrate, check) within about 1 GB


def _cmd_simulate(args) -> int:
    from .dataset import Noise
    from .dataset_io import save_dataset
    from .robot_file import load_model
    from .simulate import Deviations, SimulationSettings, simulate

    if args.cmm_sigma < 0 or args.joint_resolution < 0 or args.repeatability < 0:
        raise FgcalError("--cmm-sigma, --joint-resolution and --repeatability must not be negative")
    if not 0 <= args.outliers < 1:
        raise FgcalError("--outliers is a fraction of probe points, from 0 to below 1")
    if (args.poses or 0) > MAX_POSES or args.probes_per_ball > 1000:
        raise FgcalError(f"--poses at most {MAX_POSES} and --probes-per-ball at most 1000 (a dataset that large "
                         "would not fit in memory)")
    check_output_dir(args.out, [args.truth, Path(args.robot)], option="OUT", must_be_new=True, force=args.force)
    chain = None
    if args.chain:
        parts = args.chain.split(",")
        if len(parts) != 2 or not all(parts):
            raise FgcalError(f"--chain: expected BASE,TIP (URDF link names), got {args.chain!r}")
        chain = {"base": parts[0], "tip": parts[1]}
    model = load_model(args.robot, chain=chain)
    levels = args.levels
    if args.reflector is not None:
        from dataclasses import replace

        from .model import Tooling

        model = replace(model, tooling=Tooling(0.0, {"R": _floats(args.reflector, 3, "--reflector")}))
        levels = levels or "centres"
    robot_ref = args.robot
    if Path(args.robot).suffix or "/" in args.robot:  # a file: name it relative to the dataset directory
        robot_ref = os.path.relpath(Path(args.robot).resolve(), Path(args.out).resolve())
    settings = SimulationSettings(
        n_poses=args.poses, plan=args.plan,
        noise=Noise(args.cmm_sigma, args.joint_resolution, args.repeatability),
        deviations=Deviations(args.length_sigma, args.angle_sigma, args.base_length_sigma, args.base_angle_sigma),
        n_balls=args.balls if args.balls is not None else min(3, len(model.tooling.balls) if model.tooling else 3),
        probes_per_ball=args.probes_per_ball, outlier_fraction=args.outliers,
        outlier_size=args.outlier_size, levels=tuple((levels or "probes").split(",")))
    truth = None
    if args.truth is not None:
        from .dataset_io import load_truth

        values, _ = load_truth(args.truth)
        missing = [n for n in model.slot_names if n not in values]
        if missing:
            raise FgcalError(f"{args.truth}: lacks {', '.join(missing[:5])}{' ...' if len(missing) > 5 else ''}")
        truth = model.slots_from_file_units(np.array([values[n] for n in model.slot_names]))
    ds, notes = simulate(model, np.random.default_rng(args.seed), settings, robot_ref=robot_ref, seed=args.seed,
                         truth=truth)
    ds.chain = chain
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    save_dataset(ds, args.out, overwrite=args.force)
    counts = ", ".join(f"{len(getattr(ds, lv))} {lv}" for lv in ds.levels())
    print(f"wrote {args.out}: {ds.n_poses} poses ({args.plan} plan), {counts}; truth in truth.yaml")
    return 0


def _floats(text: str, n: int, option: str) -> np.ndarray:
    try:
        values = np.array([float(v) for v in text.split(",")])
    except ValueError:
        values = np.zeros(0)
    if values.shape != (n,) or not np.all(np.isfinite(values)):
        raise FgcalError(f"{option}: expected {n} comma-separated numbers, got {text!r}")
    return values


def _cmd_check(args) -> int:
    from .calibrate import identifiability_of
    from .dataset_io import dataset_model, load_dataset

    ds = load_dataset(args.dataset)
    model = dataset_model(ds)
    _warn_units(ds, model)
    print(f"{args.dataset}: robot {model.name}, {ds.n_poses} poses; levels: {', '.join(ds.levels()) or 'none'}")
    for lv in ds.levels():
        print(f"  {lv}: {len(getattr(ds, lv))} rows")
    outside = ~model.in_limits(model.joints_to_internal(ds.joints_deg))
    if outside.any():
        print(f"  warning: {outside.sum()} pose(s) outside the joint limits: {ds.pose_ids[outside].tolist()}")
    if not ds.levels():
        print("identifiability: no measurements")
        return 0
    if _measurement_rows(ds) > MAX_BATCH_ROWS and ds.tooling is not None and ds.tooling.balls:
        from .identifiability import analyse, compact_jacobian

        params = model.parameters()
        J = compact_jacobian(params, model.joints_to_internal(ds.joints_deg), measurement=ds.tooling.offsets())
        print(f"identifiability (ball centres at these poses; {_measurement_rows(ds)} rows are more than the "
              f"{MAX_BATCH_ROWS} of the estimator's graph): " + analyse(J, params.names).summary())
        return 0
    result = identifiability_of(ds, model)
    print(f"identifiability ({', '.join(ds.levels())} at these poses, with the estimator's noise model): "
          + result.summary())
    return 0


def _cmd_measure(args) -> int:
    from .dataset_io import dataset_model, load_dataset, save_dataset
    from .measure import POSE_ROW, derived_dataset, measure_probes, quality_csv

    out = args.out or args.dataset.with_name(args.dataset.name + "-measured")
    check_output_dir(out, [args.dataset], must_be_new=True, force=args.force)
    if args.tolerance is not None and args.method != "paper":
        raise FgcalError("--tolerance is for --method paper")
    ds = load_dataset(args.dataset)
    _warn_units(ds, dataset_model(ds))
    result = measure_probes(ds, method=args.method, free_radius=args.free_radius, threshold=args.threshold,
                            tolerance=args.tolerance)
    if not len(result.poses):
        first = next((f"pose {q.pose}: {q.status}" for q in result.quality if q.status != "ok"), "no probe points")
        raise FgcalError(f"{args.dataset}: no pose could be measured ({first}); nothing written")
    derived = derived_dataset(ds, result)
    save_dataset(derived, out, overwrite=args.force, extra_files={"quality.csv": quality_csv(result.quality)})
    balls = [q for q in result.quality if q.ball != POSE_ROW]
    poses = [q for q in result.quality if q.ball == POSE_ROW]
    bad_balls = [q for q in balls if q.status != "ok"]
    bad_poses = [q for q in poses if q.status != "ok"]
    print(f"{len(balls)} ball fits, {len(bad_balls)} flagged; {len(poses) - len(bad_poses)} of {len(poses)} poses "
          f"accepted ({args.method}); wrote {out} (centres.csv, poses.csv, quality.csv)")
    for q in (bad_balls + bad_poses)[: args.show]:
        print(f"  pose {q.pose} {'' if q.ball == POSE_ROW else 'ball ' + q.ball + ' '}{q.status}")
    if len(bad_balls) + len(bad_poses) > args.show:
        print(f"  ... {len(bad_balls) + len(bad_poses) - args.show} more in {out / 'quality.csv'}")
    from .sanity import unused_poses

    for note in unused_poses(ds, [q.pose for q in poses], ["probes"]):
        print(f"note: {note}")
    return 0


def _measurement_rows(ds) -> int:
    return sum(len(getattr(ds, lv)) for lv in ds.levels())


def _warn_units(ds, model) -> None:
    from .sanity import unit_warnings

    for w in unit_warnings(ds, model):
        print(f"warning: {w}", file=sys.stderr)


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
            a, b = part.split("-", 1) if "-" in part[1:] and not part.startswith("-") else (part, part)
            a, b = int(a), int(b)
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
    from .uncertainty import outlier_location

    for o in result.outliers:
        print(f"  excluded as a gross error: {o.level} at {outlier_location(o)}, {o.residual:.3g} {o.unit} "
              f"({o.statistic:.3g} sigma)")
    for h in result.held:
        cost = f"; costs {h['cost_mm']:.3g} mm at new poses" if "cost_mm" in h else ""
        print(f"  held at nominal: {h['name']} = {h['value']:g} ({h['reason']}{cost})")
    print(f"  {'parameter':12s} {'nominal':>12s} {'estimate':>14s} {'sigma':>10s}")
    for p in result.parameters:
        print(f"  {p.name:12s} {p.nominal:12.6g} {p.estimate:14.8g} {p.sigma:10.3g} {p.unit}")


def _cmd_calibrate(args) -> int:
    from .calibrate import CalibrationOptions, calibrate
    from .dataset_io import dataset_model, load_dataset
    from .result import save_result

    check_output_file(args.out, dataset_inputs(args.dataset))
    ds = load_dataset(args.dataset)
    check_output_file(args.out, dataset_inputs(args.dataset, ds.robot))
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
        noise=getattr(args, "noise", "estimated"), outliers=getattr(args, "outliers", "exclude"),
        extra=extra, exclude=exclude, engine=getattr(args, "engine", "batch"))
    if getattr(args, "model", "geometric") == "geometric" and getattr(args, "verification", None) is None:
        result = calibrate(ds, model, options)
    else:
        result = _compare_models(args, ds, model, options)
    save_result(result, args.out)
    from .sanity import unused_poses

    for note in unused_poses(ds, result.pose_ids, options.levels or ds.levels()):
        print(f"note: {note}")
    _print_result(result)
    _print_selection(result)
    print(f"wrote {args.out}")
    return 0


def _parse_payload(text):
    from .gravity import Payload

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
    from .dataset_io import load_dataset
    from .model_select import HARMONICS_GRID, compare_models

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


def _cmd_verify(args) -> int:
    import json

    from .dataset_io import dataset_model, load_dataset
    from .result import load_result
    from .verify import check_same_robot, verify
    from .yamlio import atomic_write_text

    if args.out:
        check_output_file(args.out, [args.result, *dataset_inputs(args.dataset)])
    result = load_result(args.result)
    ds = load_dataset(args.dataset)
    check_same_robot(result, dataset_model(ds), where=f"{args.result} against {args.dataset}")
    _warn_units(ds, dataset_model(ds))
    ids = parse_pose_selection(args.poses, ds.pose_ids)
    if len(ids) != ds.n_poses:
        ds = ds.select(ids)
    overlap = sorted(set(result.pose_ids) & set(ds.pose_ids.tolist())) if str(result.dataset) == str(ds.path) else []
    if overlap:
        print(f"note: {len(overlap)} of these poses were used in the calibration; the errors there are optimistic")
    report = verify(result, ds, dataset_model(ds))
    d = report.to_dict()
    for s in report.skipped:
        print(f"note: skipped {s}")

    def line(label, summary):
        p, o = summary["position_mm"], summary["orientation_deg"]
        text = f"  {label:28s} position mean {p['mean']:.4g} rms {p['rms']:.4g} max {p['max']:.4g} mm"
        if o is not None:  # None for position-only data
            text += f"; orientation mean {o['mean']:.4g} rms {o['rms']:.4g} max {o['max']:.4g} deg"
        return text

    print(f"verification on {d['n_poses']} poses ({d['reference']}):")
    print(line("nominal vs measured", d["before"]))
    print(line("calibrated vs measured", d))
    if "truth" in d:
        print(line("nominal vs truth", d["truth"]["before"]))
        print(line("calibrated vs truth", d["truth"]))
    if args.out:
        atomic_write_text(args.out, json.dumps(d, indent=1) + "\n")
        print(f"wrote {args.out}")
    return 0


def _cmd_report(args) -> int:
    import json

    from .report import write_report
    from .result import load_result

    from .yamlio import read_text_file

    check_output_dir(args.out, [args.result, args.verify])
    result = load_result(args.result)
    verification = None
    if args.verify is not None:
        text = read_text_file(args.verify, max_bytes=256 * 1024 * 1024)
        try:
            verification = json.loads(text)
        except ValueError as exc:
            raise FgcalError(f"{args.verify}: not a verification file (invalid JSON: {exc.msg}, "
                             f"line {getattr(exc, 'lineno', '?')})") from None
        from .verify import check_verification

        check_verification(verification, args.verify)
        robot = verification.get("robot")
        if robot is not None and robot != result.model().name:
            raise FgcalError(f"{args.verify}: a verification of a {robot} result, but {args.result} is a "
                             f"result for {result.model().name}")
    volume = None
    try:
        volume = result.model().volume
    except FgcalError:
        log.info("robot %s not found: the pose plot has no measuring volume", result.robot)
    tolerance = getattr(args, "tolerance", None)
    if tolerance is not None and not tolerance > 0:
        raise FgcalError(f"--tolerance must be a positive length in mm, got {tolerance:g}")
    path = write_report(result, args.out, verification, volume, tolerance=tolerance)
    print(f"wrote {path} (and report.md, figures as PNG) in {args.out}")
    if tolerance is not None and verification is not None:
        from .accuracy import tolerance_verdict
        tv = tolerance_verdict(verification, tolerance)
        print(tv.sentence())
        return 0 if tv.passed else 1
    return 0


def _parse_tcp(text):
    from .compensate import tcp_matrix

    try:
        v = [float(t) for t in text.split(",")]
    except ValueError:
        v = []
    if len(v) not in (3, 6) or not np.all(np.isfinite(v)):
        raise FgcalError(f"--tcp {text!r}: give X,Y,Z or X,Y,Z,RX,RY,RZ (mm, deg) in the tool frame")
    return tcp_matrix(v[:3], v[3:] or (0.0, 0.0, 0.0))


def _parse_branch(text):
    from .ik import BRANCHES

    for b in BRANCHES:
        if str(b) == text:
            return b
    raise FgcalError(f"--branch {text!r}: one of {', '.join(map(str, BRANCHES))}")


PARTIAL = 3  # exit status of compensate when some targets were not reachable


def _cmd_compensate(args) -> int:
    from .compensate import Frame, compensate_targets
    from .dataset_io import JOINT_COLUMNS, read_targets, write_csv
    from .result import load_result

    if args.out:
        check_output_file(args.out, [args.result, args.targets])
    tcp = _parse_tcp(args.tcp) if args.tcp else None
    branch = _parse_branch(args.branch) if args.branch else None
    result = load_result(args.result)
    ids, T, seeds = read_targets(args.targets)
    model = result.model()
    c = compensate_targets(model, result.slot_vector(model), T, seeds, frame=Frame(args.frame), tcp=tcp,
                           branch=branch, max_change_deg=args.max_change)
    for note in c.notes:
        print(f"note: {note}", file=sys.stderr)
    ok = c.reachable
    q = np.array(c.q, dtype=float)
    if result.joint_errors.get("names") and ok.any():  # joint-error block: command what lands on q
        from .joint_errors import commands_for, outside_region

        for message in outside_region(result, q[ok]):
            print(f"warning: {args.targets}: {message}", file=sys.stderr)
        q[ok] = commands_for(result, q[ok])
    rows = [[int(p), *map(float, np.degrees(qi))] for p, qi, good in zip(ids, q, ok) if good]
    if args.out:
        write_csv(args.out, JOINT_COLUMNS, rows)
        if ok.any():
            print(f"wrote {args.out}: {len(rows)} of {len(ids)} joint commands; the calibrated model reaches them "
                  f"within {np.nanmax(c.position_error_mm):.2g} mm and {np.nanmax(c.orientation_error_deg):.2g} deg, "
                  f"every joint within {np.nanmax(c.joint_change_deg):.2g} deg of its seed (same configuration)")
        else:
            print(f"wrote {args.out}: no target was reachable")
    else:
        print(",".join(JOINT_COLUMNS))
        for r in rows:
            print(",".join([str(r[0])] + [repr(v) for v in r[1:]]))
    for p, why in zip(ids, c.reasons):
        if why:
            print(f"{args.targets}: pose {p}: not written: {why}", file=sys.stderr)
    if not ok.all():
        print(f"{int((~ok).sum())} of {len(ids)} targets not reachable (exit status {PARTIAL})", file=sys.stderr)
        return PARTIAL
    return 0


def _cmd_export(args) -> int:
    from .result import load_result
    from .robot_file import save_model
    from .urdf import export_urdf
    from .yamlio import atomic_write_text

    if args.model is None and args.urdf is None and args.deltas is None:
        raise FgcalError("export: give --model FILE, --urdf FILE and/or --deltas FILE")
    if args.model:
        check_output_file(args.model, [args.result], option="--model")
    if args.urdf:
        check_output_file(args.urdf, [args.result, args.model], option="--urdf")
        if args.model and Path(args.model).absolute() == Path(args.urdf).absolute():
            raise FgcalError(f"--model and --urdf: both are {args.urdf}; give two files")
    if args.deltas:
        check_output_file(args.deltas, [args.result, args.model, args.urdf], option="--deltas")
    result = load_result(args.result)
    model = result.model()
    from dataclasses import replace

    calibrated = replace(model, name=f"{model.name}-calibrated",
                         description=f"{model.name} calibrated by fgcal from {result.n_poses} poses")
    slots = result.slot_vector(model)
    if args.model:
        save_model(calibrated, args.model, slots=slots)
        print(f"wrote {args.model} (fgcal-robot/1)")
    if args.urdf:
        atomic_write_text(args.urdf, export_urdf(calibrated, slots))
        kind = "a calibrated copy of the imported URDF" if "urdf" in model.extra else "URDF"
        print(f"wrote {args.urdf} ({kind})")
    if args.deltas:
        from .dataset_io import write_csv

        rows = [[p.name, p.unit, p.nominal, p.estimate, p.estimate - p.nominal, p.sigma, "identified"]
                for p in result.parameters]
        nominal = model.slots_to_file_units(model.nominal)
        for h in result.held:
            unit = "deg" if model.slot_is_angle[model.slot(h["name"])] else "mm"
            value = float(h["value"])
            rows.append([h["name"], unit, float(nominal[model.slot(h["name"])]), value,
                         value - float(nominal[model.slot(h["name"])]), "", "held: " + h["reason"].replace(",", ";")])
        write_csv(args.deltas, ["name", "unit", "nominal", "estimate", "delta", "sigma", "status"], rows)
        print(f"wrote {args.deltas} ({len(result.parameters)} identified, {len(result.held)} held)")
    if result.joint_errors.get("names"):  # what neither format can hold goes beside them as a table
        from .dataset_io import write_csv

        table = Path(str(args.urdf or args.model or args.deltas) + ".joint_errors.csv")
        write_csv(table, ["name", "unit", "estimate", "sigma"],
                  [[p.name, p.unit, p.estimate, p.sigma] for p in result.parameters
                   if p.name in set(result.joint_errors["names"])])
        print(f"wrote {table}: the {len(result.joint_errors['names'])} joint-error parameters, which a "
              f"{'URDF' if args.urdf else 'model file'} cannot hold (joint = reading + correction, see fgcal.joint_errors)")
        if result.joint_errors.get("validity"):
            print(f"note: {result.joint_errors['validity']}")
    return 0


def _cmd_online(args) -> int:
    from .dataset_io import dataset_model, load_dataset
    from .online_run import Display, OnlineRun, follow
    from .result import save_result

    if args.stdin and args.follow:
        raise FgcalError("--stdin and --follow: choose one source of new poses")
    if args.out:
        check_output_file(args.out, [args.checkpoint, *dataset_inputs(args.dataset)])
    if args.plot:
        check_output_file(args.plot, [args.out, args.checkpoint, *dataset_inputs(args.dataset)], option="--plot")
    if args.stdin:
        from .dataset_io import load_dataset_meta

        ds = load_dataset_meta(args.dataset)  # robot, tool and noise; poses come on standard input
    else:
        ds = load_dataset(args.dataset)
    model = dataset_model(ds)
    from .online_run import default_checkpoint

    checkpoint = args.checkpoint or default_checkpoint(args.dataset, args.engine, args.out)
    if args.drift and args.engine == "isam2":
        raise FgcalError("--drift is for the filters (ekf, ukf): iSAM2 keeps the parameters constant")
    engine_kw = {}
    if args.drift:
        length, angle = args.drift
        if length < 0 or angle < 0:
            raise FgcalError("--drift takes two non-negative numbers: mm and deg per pose")
        params = model.parameters()
        engine_kw["drift"] = np.where(params.is_angle, np.radians(angle), length)
    run = OnlineRun(ds, model, args.engine, checkpoint, engine_kw=engine_kw, restart=args.restart)
    restored = run.resume()
    if restored:
        print(f"resumed from {checkpoint}: {restored} pose(s) already processed")
    display = Display(run)
    try:
        if args.stdin:
            from .online_run import read_stream

            for rec in read_stream(sys.stdin.buffer, ds.tooling.balls, model=model):
                display.show(run.feed(rec, streamed=True))
        elif args.follow:
            print(f"following {args.dataset} (Ctrl-C to stop); checkpoint {checkpoint}")
            for rec in run.pending():
                display.show(run.feed(rec))
            follow(run, display, interval=args.interval)
        else:
            pending = run.pending()
            for rec in pending:
                display.show(run.feed(rec), total=ds.n_poses)
    except KeyboardInterrupt:
        print(f"\ninterrupted: {len(run.processed)} pose(s) processed, state in {checkpoint}; run again to resume")
        if not args.follow:
            return 130
    rejected = [p for p in run.processed if not p["accepted"]]
    for p in rejected:
        print(f"rejected pose {p['pose']}: {p['reason']}")
    result = run.result()
    if args.out:
        save_result(result, args.out)
        print(f"wrote {args.out} ({result.n_poses} poses, engine {args.engine})")
    if args.plot and run.history:
        from .plots import plot_convergence
        from .yamlio import atomic_write_bytes
        import io

        names = result.names
        rel = result.sigma / run.engine.params.to_file_units(run.engine.prior_sigma)
        show = list(np.argsort(-rel)[:6])
        n = [h["n"] for h in run.history]
        est = np.array([h["estimate"] for h in run.history])[:, show]
        sig = np.array([h["sigma"] for h in run.history])[:, show]
        ax = plot_convergence(n, est, sig, [names[i] for i in show])
        buf = io.BytesIO()
        ax.figure.savefig(buf, format="png", dpi=110)
        atomic_write_bytes(args.plot, buf.getvalue())
        print(f"wrote {args.plot}")
    return 0


def _cmd_study(args) -> int:
    from .study import trials_for
    from .study_run import run_study, study_figures, summary, write_figures

    trials = trials_for(args.name, trials=args.trials, poses=args.poses, seed=args.seed)
    out = check_output_dir(args.out or Path(f"study-{args.name}"))
    t0 = __import__("time").perf_counter()
    rows = run_study(trials, out, workers=args.workers, scheduler=args.scheduler)
    elapsed = __import__("time").perf_counter() - t0
    paths = write_figures(study_figures(args.name, rows), out)
    print(summary(args.name, rows))
    print(f"{out / 'trials.csv'} ({len(rows)} rows; this run {elapsed:.1f} s); figures: "
          + ", ".join(p.name for p in paths))
    return 0


def _progress(every: float = 2.0):
    """A progress reporter for long runs: a line on standard error at most every ``every`` s."""
    import time

    t0 = time.perf_counter()
    last = [t0]

    def say(text: str) -> None:
        now = time.perf_counter()
        if now - last[0] >= every:
            print(f"design: {text} ({now - t0:.0f} s)", file=sys.stderr, flush=True)
            last[0] = now
    return say


def _cmd_design_dataset(args) -> int:
    from .dataset_io import dataset_model, load_dataset
    from .design_dataset import DATASET_INDEX, design_from_dataset, load_plan, save_plan

    ds = load_dataset(args.dataset)
    candidates = None
    if args.candidates is not None:
        if args.candidates.isdigit():
            raise FgcalError("with --dataset, --candidates is a joints.csv-like file (pose,q1..q6 deg), "
                             f"not a count: {args.candidates}")
        candidates = load_plan(Path(args.candidates))
    check_output_file(args.out, [*dataset_inputs(args.dataset, ds.robot)]
                      + ([Path(args.candidates)] if candidates is not None else []))
    plan = design_from_dataset(ds, dataset_model(ds), args.poses, candidates, index=args.index or DATASET_INDEX,
                               rng=np.random.default_rng(args.seed), progress=_progress())
    save_plan(plan, args.out)
    print("\n".join(plan.summary()))
    print(f"wrote {args.out} (pose ids of the candidates)")
    return 0


def _cmd_design(args) -> int:
    from .dataset import Noise
    from .dataset_io import joint_columns, write_csv
    from .design import INDICES, Candidates, candidate_pool, design_plan, random_design_values
    from .design_info import layout_from_access
    from .robot_file import load_model
    from .simulate import random_plan

    if args.dataset is not None:
        return _cmd_design_dataset(args)
    if args.poses < 5:
        raise FgcalError("--poses must be at least 5 (30 parameters, 6 equations per pose)")
    if args.candidates is not None and not args.candidates.isdigit():
        raise FgcalError(f"--candidates {args.candidates}: a file of candidate poses needs --dataset (for the "
                         "robot, tool, measurement type and noise); without it, give a number of random poses")
    n_candidates = 2000 if args.candidates is None else int(args.candidates)
    if not 1 <= n_candidates <= MAX_POSES:
        raise FgcalError(f"--candidates: from 1 to {MAX_POSES} random poses")
    check_output_file(args.out, [Path(args.robot)])
    model = load_model(args.robot)
    if model.tooling is None:
        raise FgcalError(f"robot model {model.name} has no tooling (balls) to plan for")
    rng = np.random.default_rng(args.seed)
    noise = Noise(args.cmm_sigma, args.joint_resolution, args.repeatability)
    levels = (args.level,)
    pool = candidate_pool(model, n_candidates, rng, levels=levels)
    q_verify = pool if model.volume is None else random_plan(
        model, model.nominal, 1000, rng, model.tooling, model.volume, min(3, len(model.tooling.balls)))
    prepared = Candidates.build(model, pool, noise, q_verify, layout=layout_from_access(model, pool, levels))
    d = design_plan(model, args.poses, pool, noise, index=args.index or "pred", prepared=prepared,
                    progress=_progress())
    write_csv(args.out, joint_columns(model.n_joints),
              [[i + 1, *map(float, model.joints_to_file_units(q))] for i, q in enumerate(d.q)])
    random_pred = [random_design_values(prepared, args.poses, np.random.default_rng([args.seed, k]))[1]["pred"]
                   for k in range(200)]
    print(f"designed {args.poses} poses from {len(pool)} candidates by {d.index} ({d.iterations} DETMAX steps); "
          f"wrote {args.out}")
    print("  " + ", ".join(f"{k} {d.values[k]:.4g}" for k in INDICES if k != "pred"))
    print(f"  predicted position error RMS at new poses: {d.values['pred']:.4g} mm "
          f"(random {args.poses}-pose sets from the same candidates: median {np.median(random_pred):.4g}, "
          f"quartiles {np.percentile(random_pred, 25):.4g}-{np.percentile(random_pred, 75):.4g} mm)")
    if prepared.dropped:
        print(f"  not identifiable from these candidates, not designed for: {', '.join(prepared.dropped)}")
    return 0


def _cmd_demo(args) -> int:
    """The paper's experiment on the bundled dataset: identify on 24 poses, verify on the other 24."""
    from .resources import default_dataset_dir

    ds_dir = default_dataset_dir()
    out = check_output_dir(args.out, [ds_dir])
    out.mkdir(parents=True, exist_ok=True)
    print(f"fgcal demo: {ds_dir} (a simulated PUMA 560, the paper's 48-pose plan); results in {out}/")
    print("\n== check: what the poses can identify")
    _cmd_check(argparse.Namespace(dataset=ds_dir))
    print("\n== calibrate on the odd poses: one factor graph from raw probe points")
    _cmd_calibrate(argparse.Namespace(dataset=ds_dir, out=out / "result.json", poses="odd", levels=None, robust=None,
                                      prior="none", exact_joints=False, noise="estimated", outliers="exclude", extra=None,
                                      exclude=None))
    print("\n== verify on the even poses (the paper's VERIFY)")
    _cmd_verify(argparse.Namespace(result=out / "result.json", dataset=ds_dir, poses="even", out=out / "verify.json"))
    print("\n== the uncertainty report")
    return _cmd_report(argparse.Namespace(result=out / "result.json", verify=out / "verify.json", out=out / "report"))


class _Parser(argparse.ArgumentParser):
    """Option errors in one line (no usage block), exit status 2."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="fgcal", description="Calibrate robot arm geometry as a factor graph.")
    p.add_argument("--version", action="version", version=f"fgcal {__version__}")
    p.add_argument("-v", "--verbose", action="store_true", help="log progress to standard error")
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("simulate", help="the paper's POSE program: simulate a measured robot (writes a dataset)")
    s.add_argument("out", type=Path, help="dataset directory to write")
    s.add_argument("--robot", default="puma560",
                   help="built-in model name, model file or URDF file (default puma560)")
    s.add_argument("--chain", default=None, metavar="BASE,TIP",
                   help="URDF link names of the chain's base and tip (when the URDF has several leaves)")
    s.add_argument("--reflector", default=None, metavar="X,Y,Z",
                   help="measure one tracker reflector at X,Y,Z (mm, tool frame) instead of the model's tooling "
                        "balls (levels default to centres)")
    s.add_argument("--poses", type=positive_int, default=None, help="number of poses (random plan; default 21)")
    s.add_argument("--seed", type=nonnegative_int, default=0, help="random seed (default 0)")
    s.add_argument("--plan", choices=("random", "paper"), default="random",
                   help="random reachable joint sets, or the paper's 48-pose experiment")
    s.add_argument("--cmm-sigma", type=nonnegative_float, default=0.01, help="CMM noise per coordinate, mm (default 0.01)")
    s.add_argument("--joint-resolution", type=nonnegative_float, default=0.01,
                   help="joint readings rounded to this, deg (default 0.01; 0 = exact)")
    s.add_argument("--repeatability", type=nonnegative_float, default=0.0,
                   help="joints land off the readings by N(0, this) deg (default 0)")
    s.add_argument("--outliers", type=finite_float, default=0.0, help="fraction of probe points with a gross error")
    s.add_argument("--outlier-size", type=nonnegative_float, default=0.5, help="size of a gross error, mm (default 0.5)")
    s.add_argument("--balls", type=positive_int, default=None,
                   help="balls measured per pose (default 3, or all the tool has if fewer)")
    s.add_argument("--probes-per-ball", type=positive_int, default=4, help="probe points per ball (default 4)")
    s.add_argument("--levels", default=None,
                   help="comma-separated files to write: probes, centres, poses (default probes; centres with "
                        "--reflector)")
    s.add_argument("--length-sigma", type=nonnegative_float, default=0.5,
                   help="link length deviations, mm (default 0.5)")
    s.add_argument("--angle-sigma", type=nonnegative_float, default=0.05,
                   help="link angle deviations, deg (default 0.05)")
    s.add_argument("--base-length-sigma", type=nonnegative_float, default=5.0,
                   help="base placement deviation, mm (default 5)")
    s.add_argument("--base-angle-sigma", type=nonnegative_float, default=0.5,
                   help="base angle deviation, deg (default 0.5)")
    s.add_argument("--truth", type=Path, default=None,
                   help="truth.yaml of another simulated dataset: the same actual robot (a verification set)")
    s.add_argument("--force", action="store_true", help="replace OUT if it exists")
    s.set_defaults(func=_cmd_simulate)

    c = sub.add_parser("check", help="validate a dataset and report what its poses can identify")
    c.add_argument("dataset", type=Path)
    c.set_defaults(func=_cmd_check)

    m = sub.add_parser("measure", help="probe points -> ball centres -> poses, with quality checks (two-stage)")
    m.add_argument("dataset", type=Path)
    m.add_argument("--out", type=Path, default=None,
                   help="dataset directory to write (default: DATASET-measured beside DATASET)")
    m.add_argument("--method", choices=("svd", "paper"), default="svd",
                   help="least-squares rigid fit of the good balls, or the paper's T = P' P^-1 (default svd)")
    m.add_argument("--free-radius", action="store_true", help="fit each ball's radius too")
    m.add_argument("--threshold", type=positive_float, default=None,
                   help="RMS sphere-fit residual (mm) that flags a ball; default from the CMM noise")
    m.add_argument("--tolerance", type=positive_float, default=None, help="eqs. 19-21 tolerance for --method paper")
    m.add_argument("--show", type=nonnegative_int, default=10, help="flagged rows to print (default 10)")
    m.add_argument("--force", action="store_true", help="replace OUT if it exists")
    m.set_defaults(func=_cmd_measure)

    k = sub.add_parser("calibrate", help="batch factor-graph calibration (the paper's ID6); writes fgcal-result/1")
    k.add_argument("dataset", type=Path)
    k.add_argument("--out", type=Path, required=True, help="result file (JSON)")
    k.add_argument("--poses", default=None, help="poses to use: odd, even, first:N, last:N or ranges like 1-21")
    k.add_argument("--levels", default=None, help="comma-separated levels to use (default: all present)")
    k.add_argument("--robust", choices=("huber", "cauchy"), default=None, help="robust loss on the measurements")
    k.add_argument("--engine", choices=("batch", "gtsam"), default="batch",
                   help="batch: fgcal's batched Levenberg-Marquardt (default); gtsam: GTSAM's own optimiser on the "
                        "same factor graph (slower, same result)")
    k.add_argument("--prior", choices=("none", "weak"), default="none",
                   help="weak: 10x the typical deviation on every parameter (default none)")
    k.add_argument("--noise", choices=("estimated", "declared"), default="estimated",
                   help="estimated (default): each level's noise, joint readings included, from the residuals "
                        "where the redundancy allows; declared: dataset.yaml's values only")
    k.add_argument("--estimate-noise", action="store_const", dest="noise", const="estimated",
                   help="the default now (kept for old scripts)")
    k.add_argument("--outliers", choices=("exclude", "none"), default="exclude",
                   help="exclude (default): detect gross errors, exclude and name them; none: keep all")
    k.add_argument("--exact-joints", action="store_true", help="treat the joint readings as exact")
    k.add_argument("--extra", default=None, help="extra slots to estimate, e.g. j1.theta (redundancy is reported)")
    k.add_argument("--exclude", default=None, help="parameters to hold at nominal")
    k.add_argument("--model", choices=("geometric", "compliance", "compliance+map"), default="geometric",
                   help="beyond geometry: gravity compliance of the loaded joints, plus a per-joint error map "
                        "(harmonics, chosen by cross-validation on these poses); the simpler models are scored too")
    k.add_argument("--verification", type=Path, default=None,
                   help="held-out dataset: each model's error there is reported (never used for fitting)")
    k.add_argument("--folds", type=int, default=5, help="cross-validation folds (default 5)")
    k.add_argument("--max-harmonics", type=int, default=30,
                   help="largest number of map harmonics per joint tried by the cross-validation (default 30)")
    k.add_argument("--seed", type=int, default=0, help="seed of the fold assignment (default 0)")
    k.add_argument("--fold-order", choices=("random", "blocked"), default="random",
                   help="folds drawn at random, or as contiguous stretches of the poses in id (time) order, which "
                        "also scores drift over the session (default random)")
    k.add_argument("--payload", default=None, help="load on the tool for the gravity torques: KG or KG,X,Y,Z (mm)")
    k.set_defaults(func=_cmd_calibrate)

    v = sub.add_parser("verify", help="the paper's VERIFY: errors of a result at the poses of a dataset")
    v.add_argument("result", type=Path)
    v.add_argument("dataset", type=Path)
    v.add_argument("--poses", default=None, help="poses to use (as for calibrate)")
    v.add_argument("--out", type=Path, default=None, help="write verify.json")
    v.set_defaults(func=_cmd_verify)

    r = sub.add_parser("report", help="the uncertainty report per parameter: HTML, Markdown and PNG figures")
    r.add_argument("result", type=Path)
    r.add_argument("--verify", type=Path, default=None, help="verify.json from fgcal verify")
    r.add_argument("--out", type=Path, required=True, help="output directory")
    r.add_argument("--tolerance", type=float, default=None, metavar="MM",
                   help="position tolerance (mm): pass or fail at the verification poses "
                        "(exit status 1 on fail, the report is written either way)")
    r.set_defaults(func=_cmd_report)

    from .cli_import import add_import_parser

    add_import_parser(sub)

    c2 = sub.add_parser("compensate", help="joint commands that bring the calibrated robot to target poses")
    c2.add_argument("result", type=Path)
    c2.add_argument("targets", type=Path, help="CSV: pose,x,y,z,qw,qx,qy,qz[,q1..q6 seed joints in deg]")
    c2.add_argument("--out", type=Path, default=None,
                    help="CSV of pose,q1..q6 (deg) of the reachable targets; standard output if omitted. The "
                         "unreachable ones are named on standard error and the exit status is 3")
    c2.add_argument("--frame", choices=("instrument", "base"), default="instrument",
                    help="frame of the targets: the measuring instrument's (default) or the robot's base as the "
                         "model places it (calibrated); a first link's d and theta are folded into the base, so "
                         "for the UR10 this frame is 127.3 mm above the mounting face")
    c2.add_argument("--tcp", default=None, metavar="X,Y,Z[,RX,RY,RZ]",
                    help="the targets are for this TCP, given in the model's tool frame (the flange for the "
                         "built-in robots): mm, and deg as R = Rz(RZ) Ry(RY) Rx(RX)")
    c2.add_argument("--branch", default=None, help="configuration of targets without seed joints (PUMA-type arms), "
                                                   "e.g. righty/up/noflip; default: the one reaching most targets")
    c2.add_argument("--max-change", type=float, default=10.0, metavar="DEG",
                    help="refuse a solution moving a joint further than this from its seed (default 10)")
    c2.set_defaults(func=_cmd_compensate)

    e = sub.add_parser("export", help="the calibrated model as a robot model file and/or URDF")
    e.add_argument("result", type=Path)
    e.add_argument("--model", type=Path, default=None, help="fgcal-robot/1 YAML file to write")
    e.add_argument("--urdf", type=Path, default=None, help="URDF file to write")
    e.add_argument("--deltas", type=Path, default=None,
                   help="CSV of the identified parameters: name,unit,nominal,estimate,delta,sigma (and held ones)")
    e.set_defaults(func=_cmd_export)

    o = sub.add_parser("online", help="incremental calibration as poses arrive (iSAM2, iterated EKF, UKF)")
    o.add_argument("dataset", type=Path)
    o.add_argument("--engine", choices=("isam2", "ekf", "ukf"), default="isam2")
    o.add_argument("--out", type=Path, default=None, help="result file (fgcal-result/1) at the end")
    o.add_argument("--checkpoint", type=Path, default=None,
                   help="state after every pose (default OUT.ENGINE.checkpoint with --out, else "
                        "fgcal-online-DATASET-DIGEST-ENGINE.checkpoint here)")
    o.add_argument("--restart", action="store_true", help="ignore an existing checkpoint and start over")
    o.add_argument("--follow", action="store_true", help="keep reading poses appended to the dataset")
    o.add_argument("--stdin", action="store_true",
                   help="read poses from standard input (DATASET gives robot, tool and noise); "
                        "records: joints,POSE,q1..q6 / probe,POSE,BALL,x,y,z / centre,... / pose,... / end,POSE")
    o.add_argument("--interval", type=positive_float, default=1.0, help="seconds between polls with --follow")
    o.add_argument("--plot", type=Path, default=None, help="convergence plot (PNG) at the end")
    o.add_argument("--drift", type=finite_float, nargs=2, metavar=("MM", "DEG"), default=None,
                   help="random-walk drift of the parameters per pose for ekf/ukf (default none)")
    o.set_defaults(func=_cmd_online)

    st = sub.add_parser("study", help="simulation studies: the paper's Figs. 8, 9, 13, its experiment, noise sweeps")
    st.add_argument("name", choices=("fig8-9", "fig13", "experiment", "sweep-cmm", "sweep-joint",
                                     "sweep-repeatability", "design"))
    st.add_argument("--out", type=Path, default=None, help="output directory (default study-NAME); resumes")
    st.add_argument("--trials", type=positive_int, default=None, help="trials (per point for fig8-9, experiment, sweeps)")
    st.add_argument("--poses", type=positive_int, default=None, help="observations per calibration (fig13, sweeps)")
    st.add_argument("--seed", type=nonnegative_int, default=0)
    st.add_argument("--workers", type=positive_int, default=None, help="local processes (default: all cores)")
    st.add_argument("--scheduler", default=None, help="Dask distributed scheduler address, e.g. tcp://host:8786")
    st.set_defaults(func=_cmd_study)

    de = sub.add_parser("design", help="which poses to measure: an optimal plan from a candidate pool")
    de.add_argument("--dataset", type=Path, default=None,
                    help="design for this dataset's robot, tool, measurement type and noise; its poses are the "
                         "candidates unless --candidates FILE")
    de.add_argument("--robot", default="puma560", help="without --dataset: the robot to plan for")
    de.add_argument("--level", choices=("probes", "centres", "poses"), default="probes",
                    help="without --dataset: what is measured at a pose (default probes on 3 balls)")
    de.add_argument("--poses", type=positive_int, default=12)
    de.add_argument("--candidates", default=None,
                    help="with --dataset: a joints.csv-like file of candidate poses (pose,q1..q6 deg); "
                         "without: the number of random reachable candidates (default 2000)")
    de.add_argument("--index", choices=("O1", "O2", "O3", "O4", "O5", "pred"), default=None,
                    help="criterion: observability index O1-O5, or pred (predicted accuracy; default)")
    de.add_argument("--seed", type=nonnegative_int, default=0)
    de.add_argument("--cmm-sigma", type=nonnegative_float, default=0.01)
    de.add_argument("--joint-resolution", type=nonnegative_float, default=0.01)
    de.add_argument("--repeatability", type=nonnegative_float, default=0.0)
    de.add_argument("--out", type=Path, required=True, help="plan CSV: pose,q1..q6 (deg); the candidates' pose ids")
    de.set_defaults(func=_cmd_design)

    d = sub.add_parser("demo", help="run the main job on the bundled dataset")
    d.add_argument("--out", type=Path, default=Path("fgcal-demo"), help="output directory (default fgcal-demo)")
    d.set_defaults(func=_cmd_demo)
    return p


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s: %(message)s")
    try:
        return args.func(args)
    except FgcalError as exc:
        print(f"fgcal: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("fgcal: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into head and the like
        sys.stderr.close()
        return 0
    except OSError as exc:
        print(f"fgcal: error: {os_error_message(exc)}", file=sys.stderr)
        return 2
    except MemoryError:
        print("fgcal: error: out of memory: the input is too large for this command on this machine",
              file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
