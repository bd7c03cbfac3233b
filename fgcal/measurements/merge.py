"""One robot measured in several sessions or from several stations: datasets merged into one
(DESIGN.md 8.3: ``fgcal calibrate DS1 DS2 ...``). No I/O here.

Each dataset is a station named after it (its directory's name) unless it has a ``station``
column of its own; the first dataset's station is the world frame. Pose ids stay as they are
when they are unique across the datasets, else each dataset's ids are shifted by a multiple of
a power of ten (and the provenance says so). Fixtures of the same name are one fixture.
"""
from __future__ import annotations

import numpy as np

from fgcal.errors import FgcalError
from fgcal.measurements.dataset import Dataset
from fgcal.measurements.setup import FixtureSpec, SetupSpec
from fgcal.measurements.types import all_levels

__all__ = ["merge_datasets"]


def _same(a, b) -> bool:
    return a.keys() == b.keys() and all(np.allclose(a[k], b[k], rtol=0, atol=1e-12) for k in a)


def merge_datasets(datasets, names) -> Dataset:
    """Merge ``datasets`` (of one robot, tool and noise) into one with a station per dataset.

    Parameters
    ----------
    datasets : sequence of Dataset
    names : sequence of str
        Each dataset's station name (used where it has no station column).

    Raises
    ------
    FgcalError
        If the datasets differ in robot, tool, joint count or noise, or define a fixture twice differently.
    """
    first = datasets[0]
    for ds, name in zip(datasets[1:], names[1:]):
        what = [w for w, ok in (("robot", ds.robot == first.robot or ds.path is not None),
                                ("tool balls", _same(ds.tooling.balls, first.tooling.balls)
                                 and ds.tooling.radius == first.tooling.radius),
                                ("joint count", ds.n_joints == first.n_joints),
                                ("noise", ds.noise == first.noise), ("chain", ds.chain == first.chain)) if not ok]
        if what:
            raise FgcalError(f"{name}: its {', '.join(what)} differ from {names[0]}'s: calibrate one robot and "
                             "tool at a time")
        if ds.probes is not None or ds.poses is not None or ds.distances is not None:
            raise FgcalError(f"{name}: several stations are supported for centres.csv (and contacts) only")
    ids = [ds.pose_ids for ds in datasets]
    all_ids = np.concatenate(ids)
    shift = [0] * len(datasets)
    if len(np.unique(all_ids)) < len(all_ids):
        step = 10 ** int(np.ceil(np.log10(max(int(np.abs(all_ids).max()) + 1, 10))))
        shift = [k * step for k in range(len(datasets))]
    world = first.world_station or names[0]
    fixtures: dict = {}
    stations = []
    for ds, name in zip(datasets, names):
        st = ds.stations if ds.stations is not None else np.full(ds.n_poses, name)
        stations.append(np.where(st == (ds.world_station or name), world if ds is first else st, st))
        for n, f in ds.setup.fixtures.items():
            if n in fixtures and fixtures[n] != f:
                raise FgcalError(f"{name}: fixture {n} is defined differently in another dataset")
            fixtures[n] = f
        for st_name in dict.fromkeys(stations[-1].tolist()):
            if st_name != world and st_name not in fixtures:
                fixtures[st_name] = FixtureSpec(st_name, "station")
    distances = tuple(dict.fromkeys(c for ds in datasets for c in ds.setup.distances))
    out = Dataset(robot=first.robot, tooling=first.tooling, noise=first.noise,
                  provenance={"merged": [str(ds.path or n) for ds, n in zip(datasets, names)],
                              **({"pose_id_shift": dict(zip(names, shift))} if any(shift) else {})},
                  pose_ids=np.concatenate([i + s for i, s in zip(ids, shift)]),
                  joints_deg=np.vstack([ds.joints_deg for ds in datasets]), path=first.path, chain=first.chain,
                  setup=SetupSpec(fixtures, distances), stations=np.concatenate(stations), world_station=world)
    pieces = [_centres_whole(ds) for ds in datasets]
    for level in all_levels():
        parts = [(getattr(ds, level) if level != "centres" else whole, s)
                 for ds, whole, s in zip(datasets, pieces, shift)
                 if (getattr(ds, level, None) if level != "centres" else whole) is not None]
        if not parts or level == "station_centres":
            continue
        kind = type(parts[0][0])
        setattr(out, level, kind(**{f: np.concatenate([getattr(o, f) + s if f == "pose" else getattr(o, f)
                                                       for o, s in parts]) for f in kind.__dataclass_fields__}))
    out.split_station_centres()
    return out


def _centres_whole(ds: Dataset):
    """A dataset's centres from every station as one :class:`PointObservations` (or None)."""
    from fgcal.measurements.point import PointObservations

    parts = [o for o in (ds.centres, ds.station_centres) if o is not None]
    if not parts:
        return None
    return PointObservations(np.concatenate([o.pose for o in parts]), np.concatenate([o.ball for o in parts]),
                             np.vstack([o.xyz for o in parts]), np.concatenate([o.line for o in parts]))
