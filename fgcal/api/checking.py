"""``fgcal.check``: validate a dataset and say what its poses can identify."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from fgcal.api.notes import warn
from fgcal.api.selection import MAX_BATCH_ROWS, as_dataset, measurement_rows

__all__ = ["CheckReport", "check"]


@dataclass
class CheckReport:
    """What :func:`check` found.

    Attributes
    ----------
    lines : list of str
        What ``fgcal check`` prints.
    identifiability : Identifiability or None
        Rank, singular values and redundant parameters (None without measurements).
    outside_limits : list of int
        Pose ids whose joint readings lie outside the joint limits.
    """

    lines: list[str] = field(default_factory=list)
    identifiability: Any = None
    outside_limits: list[int] = field(default_factory=list)


def check(dataset) -> CheckReport:
    """Load ``dataset`` (a directory or a Dataset), validate it, and analyse what its poses identify.

    Warns
    -----
    FgcalWarning
        Values that look like a unit mistake.
    """
    from fgcal.estimation.calibrate import identifiability_of
    from fgcal.estimation.sanity import unit_warnings
    from fgcal.io.dataset_io import dataset_model

    ds = as_dataset(dataset)
    model = dataset_model(ds)
    for w in unit_warnings(ds, model):
        warn(w)
    out = CheckReport()
    where = ds.path or "dataset"
    out.lines.append(f"{where}: robot {model.name}, {ds.n_poses} poses; levels: {', '.join(ds.levels()) or 'none'}")
    for lv in ds.levels():
        out.lines.append(f"  {lv}: {len(getattr(ds, lv))} rows")
    outside = ~model.in_limits(model.joints_to_internal(ds.joints_deg))
    if outside.any():
        out.outside_limits = ds.pose_ids[outside].tolist()
        out.lines.append(f"  warning: {outside.sum()} pose(s) outside the joint limits: {out.outside_limits}")
    if not ds.levels():
        out.lines.append("identifiability: no measurements")
        return out
    rows = measurement_rows(ds)
    if rows > MAX_BATCH_ROWS and ds.tooling is not None and ds.tooling.balls:
        from fgcal.robots.identifiability import analyse, compact_jacobian

        params = model.parameters()
        J = compact_jacobian(params, model.joints_to_internal(ds.joints_deg), measurement=ds.tooling.offsets())
        out.identifiability = analyse(J, params.names)
        out.lines.append(f"identifiability (ball centres at these poses; {rows} rows are more than the "
                         f"{MAX_BATCH_ROWS} of the estimator's graph): " + out.identifiability.summary())
        return out
    out.identifiability = identifiability_of(ds, model)
    out.lines.append(f"identifiability ({', '.join(ds.levels())} at these poses, with the estimator's noise model): "
                     + out.identifiability.summary())
    return out
