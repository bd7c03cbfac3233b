"""``fgcal check``: the command's body (its options are in :func:`fgcal.cli.build_parser`)."""
from __future__ import annotations

import logging
import sys

from fgcal.cli.commands.checks import MAX_BATCH_ROWS

log = logging.getLogger("fgcal")


def _cmd_check(args) -> int:
    from fgcal.estimation.calibrate import identifiability_of
    from fgcal.io.dataset_io import dataset_model, load_dataset

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
        from fgcal.robots.identifiability import analyse, compact_jacobian

        params = model.parameters()
        J = compact_jacobian(params, model.joints_to_internal(ds.joints_deg), measurement=ds.tooling.offsets())
        print(f"identifiability (ball centres at these poses; {_measurement_rows(ds)} rows are more than the "
              f"{MAX_BATCH_ROWS} of the estimator's graph): " + analyse(J, params.names).summary())
        return 0
    result = identifiability_of(ds, model)
    print(f"identifiability ({', '.join(ds.levels())} at these poses, with the estimator's noise model): "
          + result.summary())
    return 0


def _measurement_rows(ds) -> int:
    return sum(len(getattr(ds, lv)) for lv in ds.levels())


def _warn_units(ds, model) -> None:
    from fgcal.estimation.sanity import unit_warnings

    for w in unit_warnings(ds, model):
        print(f"warning: {w}", file=sys.stderr)
