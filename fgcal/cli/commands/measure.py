"""``fgcal measure``: the command's body (its options are in :func:`fgcal.cli.parser.build_parser`)."""
from __future__ import annotations

import logging

from fgcal.cli.commands.check import _warn_units
from fgcal.cli.commands.checks import check_output_dir
from fgcal.errors import FgcalError

log = logging.getLogger("fgcal")


def _cmd_measure(args) -> int:
    from fgcal.io.dataset_io import dataset_model, load_dataset, save_dataset
    from fgcal.measurements.measure import POSE_ROW, derived_dataset, measure_probes, quality_csv

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
    from fgcal.estimation.sanity import unused_poses

    for note in unused_poses(ds, [q.pose for q in poses], ["probes"]):
        print(f"note: {note}")
    return 0
