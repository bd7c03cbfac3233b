"""``fgcal export``: the command's body (its options are in :func:`fgcal.cli.build_parser`)."""
from __future__ import annotations

import logging
from pathlib import Path

from fgcal.cli.commands.checks import check_output_file
from fgcal.errors import FgcalError

log = logging.getLogger("fgcal")


def _cmd_export(args) -> int:
    from fgcal.estimation.result import load_result
    from fgcal.robots.robot_file import save_model
    from fgcal.robots.urdf import export_urdf
    from fgcal.util.yamlio import atomic_write_text

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
        point = result.tool_point()  # a contact calibration: the link tool at the ball's centre (DESIGN.md 8.2)
        atomic_write_text(args.urdf, export_urdf(calibrated, slots, tool_point=point))
        kind = "a calibrated copy of the imported URDF" if "urdf" in model.extra else "URDF"
        at = "" if point is None else (f"; link tool at the centre of ball {result.tooling['tool_ball']} "
                                       f"({', '.join(f'{v:g}' for v in point)} mm in the tool frame)")
        print(f"wrote {args.urdf} ({kind}{at})")
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
    if result.joint_errors.get("names"):  # what neither format can hold goes beside them as a table
        from fgcal.io.dataset_io import write_csv

        table = Path(str(args.urdf or args.model or args.deltas) + ".joint_errors.csv")
        write_csv(table, ["name", "unit", "estimate", "sigma"],
                  [[p.name, p.unit, p.estimate, p.sigma] for p in result.parameters
                   if p.name in set(result.joint_errors["names"])])
        print(f"wrote {table}: the {len(result.joint_errors['names'])} joint-error parameters, which a "
              f"{'URDF' if args.urdf else 'model file'} cannot hold (joint = reading + correction, see fgcal.estimation.joint_errors)")
        if result.joint_errors.get("validity"):
            print(f"note: {result.joint_errors['validity']}")
    return 0
