"""``fgcal compensate``: the command's body (its options are in :func:`fgcal.cli.build_parser`)."""
from __future__ import annotations

import logging
import sys

import numpy as np

from fgcal.cli.commands.checks import check_output_file
from fgcal.errors import FgcalError

PARTIAL = 3  # exit status of compensate when some targets were not reachable

log = logging.getLogger("fgcal")


def _parse_tcp(text):
    from fgcal.robots.compensate import tcp_matrix

    try:
        v = [float(t) for t in text.split(",")]
    except ValueError:
        v = []
    if len(v) not in (3, 6) or not np.all(np.isfinite(v)):
        raise FgcalError(f"--tcp {text!r}: give X,Y,Z or X,Y,Z,RX,RY,RZ (mm, deg) in the tool frame")
    return tcp_matrix(v[:3], v[3:] or (0.0, 0.0, 0.0))


def _parse_branch(text):
    from fgcal.robots.ik import BRANCHES

    for b in BRANCHES:
        if str(b) == text:
            return b
    raise FgcalError(f"--branch {text!r}: one of {', '.join(map(str, BRANCHES))}")


def _cmd_compensate(args) -> int:
    from fgcal.estimation.result import load_result
    from fgcal.io.dataset_io import joint_columns, write_csv
    from fgcal.io.targets import read_targets
    from fgcal.robots.compensate import Frame, compensate_targets

    if args.out:
        check_output_file(args.out, [args.result, args.targets])
    tcp = _parse_tcp(args.tcp) if args.tcp else None
    branch = _parse_branch(args.branch) if args.branch else None
    result = load_result(args.result)
    model = result.model()
    ids, T, seeds = read_targets(args.targets, model.n_joints)
    if seeds is not None:
        seeds = model.joints_to_internal(seeds)
    c = compensate_targets(model, result.slot_vector(model), T, seeds, frame=Frame(args.frame), tcp=tcp,
                           branch=branch, max_change_deg=args.max_change)
    for note in c.notes:
        print(f"note: {note}", file=sys.stderr)
    ok = c.reachable
    q = np.array(c.q, dtype=float)
    if result.joint_errors.get("names") and ok.any():  # joint-error block: command what lands on q
        from fgcal.estimation.joint_errors import commands_for, outside_region

        for message in outside_region(result, q[ok]):
            print(f"warning: {args.targets}: {message}", file=sys.stderr)
        q[ok] = commands_for(result, q[ok])
    rows = [[int(p), *map(float, model.joints_to_file_units(qi))] for p, qi, good in zip(ids, q, ok) if good]
    if args.out:
        write_csv(args.out, joint_columns(model.n_joints), rows)
        if ok.any():
            print(f"wrote {args.out}: {len(rows)} of {len(ids)} joint commands; the calibrated model reaches them "
                  f"within {np.nanmax(c.position_error_mm):.2g} mm and {np.nanmax(c.orientation_error_deg):.2g} deg, "
                  f"every joint within {np.nanmax(c.joint_change_deg):.2g} deg of its seed (same configuration)")
        else:
            print(f"wrote {args.out}: no target was reachable")
    else:
        print(",".join(joint_columns(model.n_joints)))
        for r in rows:
            print(",".join([str(r[0])] + [repr(v) for v in r[1:]]))
    for p, why in zip(ids, c.reasons):
        if why:
            print(f"{args.targets}: pose {p}: not written: {why}", file=sys.stderr)
    if not ok.all():
        print(f"{int((~ok).sum())} of {len(ids)} targets not reachable (exit status {PARTIAL})", file=sys.stderr)
        return PARTIAL
    return 0
