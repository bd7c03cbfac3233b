"""``fgcal export``: the command's body (its options are in :func:`fgcal.cli.build_parser`)."""
from __future__ import annotations

import logging
import re
from pathlib import Path

from fgcal.cli.commands.checks import check_output_file
from fgcal.errors import FgcalError

log = logging.getLogger("fgcal")


def _cmd_export(args) -> int:
    from fgcal.estimation.result import load_result
    from fgcal.robots.robot_file import save_model
    from fgcal.robots.urdf import export_urdf
    from fgcal.util.yamlio import atomic_write_text

    ur_file = getattr(args, "ur_kinematics", None)
    if args.model is None and args.urdf is None and args.deltas is None and ur_file is None:
        raise FgcalError("export: give --model FILE, --urdf FILE, --deltas FILE and/or --ur-kinematics FILE")
    if ur_file:
        check_output_file(ur_file, [args.result, args.model, args.urdf, args.deltas], option="--ur-kinematics")
    if args.model:
        check_output_file(args.model, [args.result], option="--model")
    if args.urdf:
        check_output_file(args.urdf, [args.result, args.model], option="--urdf")
        if args.model and Path(args.model).absolute() == Path(args.urdf).absolute():
            raise FgcalError(f"--model and --urdf: both are {args.urdf}; give two files")
    if args.deltas:
        check_output_file(args.deltas, [args.result, args.model, args.urdf], option="--deltas")
    if getattr(args, "ur_hash", None) is not None and not re.fullmatch(r"[A-Za-z0-9_.-]{1,80}", args.ur_hash):
        raise FgcalError(f"--ur-hash {args.ur_hash[:40]!r}: letters, digits, '_', '-' and '.' only (e.g. calib_123)")
    result = load_result(args.result)
    model = result.model()
    if ur_file:
        from fgcal.robots.ur_kinematics import is_ur

        if not is_ur(model):
            raise FgcalError(f"--ur-kinematics: {args.result}: robot {model.name} is not a Universal Robots arm (the "
                             "built-in ur10/ur5, a table with the UR's structure, or a URDF with ur_description's "
                             "joint names)")
    from dataclasses import replace

    calibrated = replace(model, name=f"{model.name}-calibrated",
                         description=f"{model.name} calibrated by fgcal from {result.n_poses} poses")
    slots = result.slot_vector(model)
    if args.model:
        save_model(calibrated, args.model, slots=slots)
        print(f"wrote {args.model} (fgcal-robot/1)")
    if args.urdf:
        names = _dataset_joint_names(result, model)
        if names:  # the joint names the data were imported with, for a model without its own
            calibrated = replace(calibrated, joint_names=names)
        point = result.tool_point()  # a contact calibration: the link tool at the ball's centre (DESIGN.md 8.2)
        text = export_urdf(calibrated, slots, tool_point=point)
        cameras = _cameras(result)
        if cameras:  # each camera's mount as a link, its intrinsics beside the URDF (DESIGN.md 8.4)
            import numpy as np

            from fgcal.robots.camera_links import add_camera_links, camera_info_yaml

            shift = np.eye(4)  # a camera on the tool, seen from a tool link moved to the ball's centre
            if point is not None:
                shift[:3, 3] = -np.asarray(point, dtype=float)
            text = add_camera_links(text, [(n, c["mount"], c["T"] if c["mount"] == "world" else shift @ c["T"])
                                           for n, c in cameras.items()])
        atomic_write_text(args.urdf, text)
        kind = "a calibrated copy of the imported URDF" if "urdf" in model.extra else "URDF"
        at = "" if point is None else (f"; link tool at the centre of ball {result.tooling['tool_ball']} "
                                       f"({', '.join(f'{v:g}' for v in point)} mm in the tool frame)")
        print(f"wrote {args.urdf} ({kind}{at})")
        for n, c in cameras.items():
            info = Path(f"{args.urdf}.camera_{n}.yaml")
            atomic_write_text(info, camera_info_yaml(n, c["width"], c["height"], c["k"]))
            print(f"wrote {info} (camera {n}'s intrinsics, ROS camera_info; its frame: link camera_{n}_optical)")
    if args.deltas:
        from fgcal.io.dataset_io import write_csv

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
    if ur_file:
        _write_ur_kinematics(ur_file, calibrated, slots, args)
    if result.joint_errors.get("names"):  # what neither format can hold goes beside them as a table
        from fgcal.io.dataset_io import write_csv

        table = Path(str(args.urdf or args.model or args.deltas or ur_file) + ".joint_errors.csv")
        write_csv(table, ["name", "unit", "estimate", "sigma"],
                  [[p.name, p.unit, p.estimate, p.sigma] for p in result.parameters
                   if p.name in set(result.joint_errors["names"])])
        print(f"wrote {table}: the {len(result.joint_errors['names'])} joint-error parameters, which a "
              f"{'URDF' if args.urdf else 'model file'} cannot hold (joint = reading + correction, see fgcal.estimation.joint_errors)")
        if result.joint_errors.get("validity"):
            print(f"note: {result.joint_errors['validity']}")
    return 0


def _write_ur_kinematics(path, model, slots, args) -> None:
    """``--ur-kinematics FILE``: ur_description's kinematics file (fgcal.robots.ur_kinematics)."""
    import numpy as np

    from fgcal.robots.transforms import so3_log
    from fgcal.robots.ur_kinematics import kinematics_text, ur_kinematics
    from fgcal.util.yamlio import atomic_write_text

    given = getattr(args, "ur_hash", None) or None
    factory = model.extra.get("ur_kinematics", {}).get("hash")
    kin = ur_kinematics(model, slots, hash=given)
    tcp = kin.tcp
    xyz = tcp[:3, 3] / 1000.0
    rv = so3_log(tcp[:3, :3])
    tcp_text = ", ".join(f"{v:.6f}" for v in (*xyz, *rv))
    why = ("as given" if given else
           "fgcal_ and a digest of these values, not the controller's calibration checksum: the driver warns")
    comment = (f"UR kinematics calibrated by fgcal ({args.result}), for ur_description's kinematics_params_file:\n"
               "joint origins in metres and URDF rpy (R = Rz(yaw) Ry(pitch) Rx(roll)); base_link is the mounting "
               "face,\nbase_link_inertia = Rz(pi) the controller's Base frame; the chain ends at tool0 (the flange).\n"
               f"hash: {why}.\n"
               f"calibrated tool frame in tool0 (the TCP to set: x, y, z m, rx, ry, rz rotation vector rad): "
               f"[{tcp_text}]")
    atomic_write_text(path, kinematics_text(kin, comment))
    off = np.linalg.norm(tcp[:3, 3])
    print(f"wrote {path} (UR kinematics, hash {kin.hash})")
    if factory and not given:
        print(f"note: the factory file's hash was {factory}; --ur-hash {factory} silences the driver's check, but "
              "the controller still computes its own poses with its factory calibration")
    if off > 1e-9 or np.linalg.norm(rv) > 1e-12:
        print(f"note: the calibrated tool frame is {off:.3g} mm and {np.degrees(np.linalg.norm(rv)):.3g} deg from "
              f"tool0, which no joint origin can hold: set it as the controller's TCP [{tcp_text}] "
              "(x, y, z m, rotation vector rad; in the file as fgcal.tool_in_tool0)")


def _dataset_joint_names(result, model) -> tuple[str, ...] | None:
    """The joint columns the result's dataset was imported with (``import csv --joints``, ``import tum``),
    for a model whose joints have only the default names ``q1..qn``; None when unknown."""
    if "urdf" in model.extra or model.joint_names != tuple(f"q{k}" for k in range(1, model.n_joints + 1)):
        return None
    if not isinstance(result.dataset, str):
        return None
    from fgcal.util.yamlio import read_yaml

    try:
        provenance = read_yaml(Path(result.dataset) / "dataset.yaml").get("provenance") or {}
    except (FgcalError, OSError, AttributeError):
        return None
    columns = provenance.get("columns") if isinstance(provenance.get("columns"), dict) else provenance
    names = columns.get("joints") if isinstance(columns, dict) else None
    if (not isinstance(names, list) or len(names) != model.n_joints or len(set(map(str, names))) != len(names)
            or not all(re.fullmatch(r"[A-Za-z_][A-Za-z0-9_.-]{0,63}", str(n)) for n in names)
            or {"base", "tool"} & set(map(str, names))):
        return None
    return tuple(str(n) for n in names)


def _cameras(result) -> dict:
    """The cameras a result found: name -> ``mount``, ``T`` (4, 4, mm), ``width``, ``height``, ``k`` (9,)."""
    import numpy as np

    from fgcal.measurements.camera import INTRINSICS, pose_matrix

    setup = result.setup or {}
    out = {}
    for n, f in setup.get("fixtures", {}).items():
        if f.get("type") != "camera":
            continue
        e = setup["estimated"][n]
        pose = np.concatenate([np.asarray(e["pose"][:3], float), np.radians(e["pose"][3:6])])
        out[n] = {"mount": f["mount"], "T": pose_matrix(pose), "width": f["width"], "height": f["height"],
                  "k": [e["intrinsics"][c] for c in INTRINSICS]}
    return out
