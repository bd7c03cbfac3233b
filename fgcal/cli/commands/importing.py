"""``fgcal import csv|tum|landgraf``: measurement files of other tools to fgcal datasets (thin CLI layer)."""
from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np

from fgcal.cli.commands.checks import check_output_dir
from fgcal.cli.commands.options import fraction, nonnegative_deg, positive, positive_deg, positive_mm, seed
from fgcal.errors import FgcalError
from fgcal.util.parsing import chain_links

__all__ = ["add_import_parser"]

DELIMITERS = {"tab": "\t", "space": " ", "semicolon": ";", "comma": ","}


def _columns(text: str | None):
    return None if text is None else tuple(c.strip() for c in text.split(",") if c.strip())


def _delimiter(text: str | None):
    if text is None:
        return None
    d = DELIMITERS.get(text.lower(), text.replace("\\t", "\t"))
    if len(d) != 1:
        raise FgcalError(f"--delimiter {text!r}: one character, or tab, space, semicolon, comma")
    return d


def _measurements(args):
    from fgcal.io.table_io import ColumnSpec, read_measurements

    if args.format == "landgraf":
        from fgcal.io.landgraf import CITATION, read_series

        return read_series(args.file), "ur10", "ur10-landgraf", {"citation": CITATION}
    if args.format == "tum":
        from fgcal.io.tum import read_tum_with_joint_log

        m = read_tum_with_joint_log(args.file, args.joint_log, _columns(args.joints), args.time_column,
                                    args.joint_unit, args.max_time_difference, args.length_unit,
                                    _delimiter(args.delimiter), True if args.decimal_comma else None)
        return m, args.robot, None, {"joint_log": str(args.joint_log), "joints": list(_columns(args.joints)),
                                     "time_column": args.time_column, "max_time_difference": args.max_time_difference}
    spec = ColumnSpec(joints=_columns(args.joints), joint_unit=args.joint_unit, point=_columns(args.point),
                      pose=_columns(args.pose), quaternion_order=args.quaternion_order,
                      euler_convention=args.euler_convention, rotation_unit=args.rotation_unit,
                      length_unit=args.length_unit, group=_columns(args.group), delimiter=_delimiter(args.delimiter),
                      decimal_comma=True if args.decimal_comma else None)
    return read_measurements(args.file, spec), args.robot, None, {"columns": spec.describe()}


def _with_chain_hint(load, *args, **kw):
    """``load(*args, **kw)``; a loader's hint about dataset.yaml's chain becomes the import's option."""
    try:
        return load(*args, **kw)
    except FgcalError as exc:  # the dataset that hint names is the one being written: the option is the way
        raise FgcalError(str(exc).replace("chain: {base: LINK, tip: LINK} in dataset.yaml", "--chain BASE,TIP")) \
            from None


def _cmd_import(args) -> int:
    from fgcal.io.importer import to_datasets

    if not 0 <= args.holdout < 1:
        raise FgcalError("--holdout is a fraction from 0 to below 1")
    from fgcal.cli.commands.inputs import run_inputs

    inputs = run_inputs(robots=[getattr(args, "robot", None)], files=[args.file, getattr(args, "joint_log", None)])
    check_output_dir(args.out, inputs, option="OUT", must_be_new=True, force=args.force)
    if args.holdout > 0:
        check_output_dir(args.out.with_name(args.out.name + "-holdout"), inputs, option="OUT-holdout",
                         must_be_new=True, force=args.force)
    m, robot, name, settings = _measurements(args)
    from fgcal.io.skipped import skipped_report

    for line in skipped_report(m.skipped, str(args.file)):
        print(line)
    result = _with_chain_hint(to_datasets, m, robot, position_only=args.position_only, holdout=args.holdout,
                              rng=np.random.default_rng(args.seed), position_sigma=args.sigma,
                              orientation_sigma=args.orientation_sigma, joint_resolution=args.joint_resolution,
                              name=name, provenance={"importer": f"fgcal import {args.format}", **settings},
                              chain=chain_links(getattr(args, "chain", None)), accept_fit=args.accept_fit)
    written = result.save(args.out, overwrite=args.force)
    kind = "positions" if result.calibration.centres is not None else "full poses"
    print(f"wrote {written[0]}: {result.calibration.n_poses} poses ({kind}); {len(m.skipped)} row(s) skipped; "
          f"base and tool fitted to the data (RMS {result.rms:.3g} mm"
          + ("" if result.rotation_rms_deg is None else f", {result.rotation_rms_deg:.3g} deg")
          + f") in {written[0] / 'robot.yaml'}")
    if len(written) > 1 and result.holdout is not None:
        print(f"wrote {written[1]}: {result.holdout.n_poses} held-out poses (repeated measurements kept on one side)")
    return 0


def _common(p: argparse.ArgumentParser, robot: bool = True) -> None:
    p.add_argument("file", type=Path, help="the file to import (delimited text with one header line; "
                                           "the landgraf series: its measurements CSV)")
    p.add_argument("out", type=Path, help="dataset directory to write (OUT-holdout too with --holdout)")
    if robot:
        p.add_argument("--robot", required=True, help="built-in model name, model file or URDF of the measured robot")
        p.add_argument("--chain", default=None, help="BASE,TIP links of a URDF with more than one leaf (a gripper's "
                       "fingers, say): the chain to calibrate")
    p.add_argument("--position-only", action="store_true", help="keep only the measured positions (centres.csv)")
    p.add_argument("--holdout", type=fraction(), default=0.0,
                   help="fraction (0..1) of the rows (of the groups) to write to OUT-holdout for verification (default 0)")
    p.add_argument("--seed", type=seed, default=0, help="seed of the held-out draw")
    p.add_argument("--sigma", type=positive_mm, default=None,
                   help="position noise per axis, mm (default: the file's std columns, else 0.02)")
    p.add_argument("--orientation-sigma", type=positive_deg, default=None,
                   help="orientation noise, deg (default: the file's std columns, else 0.01)")
    p.add_argument("--joint-resolution", type=nonnegative_deg, default=0.0, help="joint reading resolution, deg (default 0)")
    p.add_argument("--force", action="store_true", help="replace OUT if it exists")
    p.add_argument("--accept-fit", action="store_true",
                   help="import even when the nominal robot misfits the data like a unit or convention mistake "
                        "(by more than 20 mm or 2%% of the workspace, or 2 deg): refused by default, naming the cause")
    p.set_defaults(func=_cmd_import)


def _table_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--delimiter", default=None, help="field separator: a character or tab, space, semicolon, "
                                                     "comma (default: detected)")
    p.add_argument("--decimal-comma", action="store_true", help="numbers like 12,5 (default: detected)")


def add_import_parser(sub) -> None:
    """Add ``import`` with its formats to the ``fgcal`` subcommands."""
    i = sub.add_parser("import", help="turn a tracker export or another tool's file into an fgcal dataset")
    formats = i.add_subparsers(dest="format", required=True)

    c = formats.add_parser("csv", help="any table of joints plus a measured point or pose per row")
    _common(c)
    c.add_argument("--joints", required=True, help="joint columns in chain order, comma-separated")
    c.add_argument("--joint-unit", choices=("deg", "rad"), required=True,
                   help="unit of the joint columns (required: ROS logs radians, controllers often degrees)")
    what = c.add_mutually_exclusive_group(required=True)
    what.add_argument("--point", help="X,Y,Z columns of a measured point (a tracker reflector)")
    what.add_argument("--pose", help="X,Y,Z,R1,R2,R3[,R4] columns: position and Euler angles or a quaternion")
    c.add_argument("--quaternion-order", choices=("wxyz", "xyzw"), default=None,
                   help="order of the 4 quaternion columns (default: from names ending in w, x, y, z)")
    c.add_argument("--euler-convention", default=None,
                   help="axes of 3 Euler angle columns: XYZ (intrinsic, upper case) or zyx (extrinsic, lower case)")
    c.add_argument("--rotation-unit", choices=("deg", "rad"), default="deg", help="unit of Euler angles (default deg)")
    c.add_argument("--length-unit", choices=("mm", "m"), default="mm", help="unit of positions (default mm)")
    c.add_argument("--group", default=None,
                   help="columns whose equal values mark repeats of one configuration (kept together by --holdout)")
    _table_options(c)

    t = formats.add_parser("tum", help="a TUM trajectory (timestamp tx ty tz qx qy qz qw) plus a joint log")
    _common(t)
    t.add_argument("--joint-log", type=Path, required=True, help="table with a time column and the joint columns")
    t.add_argument("--joints", required=True, help="joint columns of the log in chain order, comma-separated")
    t.add_argument("--joint-unit", choices=("deg", "rad"), default="rad", help="default rad (as ROS logs them)")
    t.add_argument("--time-column", default="time", help="time column of the joint log (default time)")
    t.add_argument("--max-time-difference", type=positive("timestamp units", 1e9), default=0.01,
                   help="largest time between a pose and its joint reading (default 0.01, timestamp units)")
    t.add_argument("--length-unit", choices=("mm", "m"), default="m", help="unit of TUM positions (default m)")
    _table_options(t)

    lg = formats.add_parser("landgraf", help="the UR10 laser-tracker series of Landgraf et al. (2021)")
    _common(lg, robot=False)

    mk = formats.add_parser("mukca", help="the MUKCa two-socket tool: one folder per placement with hole_0.csv, "
                                          "hole_1.csv (joint sets, rad)")
    mk.add_argument("file", type=Path, metavar="DIR", help="folder of placement folders")
    mk.add_argument("out", type=Path, help="dataset directory to write (OUT-holdout too with --holdout-placements)")
    mk.add_argument("--robot", type=Path, required=True, help="the robot's URDF or model file (copied into OUT)")
    mk.add_argument("--chain", default=None, help="BASE,TIP links of a URDF with more than one leaf "
                                                  "(TIP: the link at the ball's centre)")
    mk.add_argument("--distance", type=positive_mm, default=50.0, help="distance between the sockets, mm (default 50)")
    mk.add_argument("--distance-sigma", type=positive_mm, default=0.05,
                    help="uncertainty of that distance, mm (default 0.05)")
    mk.add_argument("--contact-sigma", type=positive_mm, default=0.05,
                    help="declared seating error of the ball per axis, mm (default 0.05; estimated by calibrate)")
    mk.add_argument("--holdout-placements", default=None, help="placements (folder names) to write to OUT-holdout")
    mk.add_argument("--force", action="store_true", help="replace OUT if it exists")
    mk.set_defaults(func=_cmd_import_mukca)

    ur = formats.add_parser("ur-kinematics", help="a UR's kinematics file (ur_calibration's, ur_description's "
                                                 "kinematics_params_file) as a robot model file")
    ur.add_argument("file", type=Path, metavar="FILE.yaml", help="kinematics: shoulder .. wrist_3 (m, rad), hash")
    ur.add_argument("out", type=Path, metavar="OUT.yaml", help="fgcal-robot/1 model file to write")
    ur.add_argument("--name", default=None, help="the model's name (default: the file's stem)")
    ur.add_argument("--angles", choices=("urdf", "eigen"), default="urdf",
                    help="how roll, pitch, yaw compose: urdf Rz(yaw) Ry(pitch) Rx(roll), as ur_description reads "
                         "the file (default); eigen Rx(roll) Ry(pitch) Rz(yaw), as ur_calibration computed them")
    ur.add_argument("--like", default=None, metavar="ROBOT",
                    help="built-in model or model file to take joint limits, tooling and volume from")
    ur.add_argument("--force", action="store_true", help="replace OUT if it exists")
    ur.set_defaults(func=_cmd_import_ur)


def _cmd_import_ur(args) -> int:
    """``fgcal import ur-kinematics``: a UR's factory calibration as the nominal model (or a start)."""
    from dataclasses import replace

    from fgcal.cli.commands.checks import check_output_file
    from fgcal.robots.robot_file import load_model, save_model
    from fgcal.robots.ur_kinematics import model_from_kinematics, parse_kinematics
    from fgcal.util.yamlio import read_yaml

    if args.out.exists() and not args.force:
        raise FgcalError(f"OUT {args.out}: exists; give --force to replace it")
    check_output_file(args.out, [args.file], option="OUT")
    kin = parse_kinematics(read_yaml(args.file), str(args.file), angles=args.angles)
    like = load_model(args.like) if args.like else None
    if like is not None and like.n_joints != 6:
        raise FgcalError(f"--like {args.like}: {like.n_joints} joints, a UR has 6")
    model = model_from_kinematics(kin, name=args.name or args.file.stem,
                                  joint_limits=None if like is None else like.joint_limits, source=str(args.file))
    if like is not None:  # not the inertials: they are given in the other model's link frames
        model = replace(model, tooling=like.tooling, volume=like.volume)
    save_model(model, args.out)
    print(f"wrote {args.out}: {model.name}, ur_description's chain base_link -> tool0 from {args.file} "
          f"(hash {kin.hash or 'none'}); joints {', '.join(model.joint_names)}")
    return 0


def _cmd_import_mukca(args) -> int:
    """``fgcal import mukca``: the two-socket tool's placements as contacts at unknown fixture points."""
    from fgcal.io.dataset_io import save_dataset
    from fgcal.io.mukca import read_mukca
    from fgcal.robots.robot_file import load_model
    from fgcal.util.resources import builtin_robot_names, builtin_robot_path
    from fgcal.util.yamlio import read_text_file

    chain = chain_links(args.chain)
    held = _columns(args.holdout_placements) or ()
    if args.holdout_placements is not None and not held:
        raise FgcalError(f"--holdout-placements {args.holdout_placements!r}: no placement named "
                         "(folder names, comma-separated)")
    robot = args.robot
    if not os.path.lexists(robot) and str(robot) in builtin_robot_names():
        robot = builtin_robot_path(str(robot))  # a built-in model: its file is copied
    inputs = [args.file, robot]
    check_output_dir(args.out, inputs, option="OUT", must_be_new=True, force=args.force)
    holdout_dir = args.out.with_name(args.out.name + "-holdout")
    if held:
        check_output_dir(holdout_dir, inputs, option="OUT-holdout", must_be_new=True, force=args.force)
    model = _with_chain_hint(load_model, robot, chain=chain)
    robot_name = "robot" + Path(robot).suffix.lower()
    robot_text = read_text_file(robot, FgcalError, max_bytes=20 << 20)
    imp = read_mukca(args.file, robot_name, model.n_joints, chain, args.distance, args.distance_sigma,
                     args.contact_sigma, held)
    written = [(save_dataset(imp.calibration, args.out, overwrite=args.force,
                             extra_files={robot_name: robot_text}), imp.calibration, imp.placements)]
    if imp.holdout is not None:
        written.append((save_dataset(imp.holdout, holdout_dir, overwrite=args.force,
                                     extra_files={robot_name: robot_text}), imp.holdout, imp.held_out))
    for path, ds, names in written:
        print(f"wrote {path}: {ds.n_poses} contacts at {len(ds.setup.fixtures)} sockets of {len(names)} "
              f"placement(s) ({', '.join(names)}); {len(ds.setup.distances)} distance(s) of {args.distance:g} mm")
    return 0
