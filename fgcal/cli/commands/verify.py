"""``fgcal verify``: the command's body (its options are in :func:`fgcal.cli.build_parser`)."""
from __future__ import annotations

import logging

from fgcal.cli.commands.calibrate import parse_pose_selection
from fgcal.cli.commands.check import _warn_units
from fgcal.cli.commands.checks import check_output_file, dataset_inputs

log = logging.getLogger("fgcal")


def _cmd_verify(args) -> int:
    import json

    from fgcal.estimation.result import load_result
    from fgcal.estimation.verification import check_same_robot, verify
    from fgcal.io.dataset_io import dataset_model, load_dataset
    from fgcal.util.yamlio import atomic_write_text

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
