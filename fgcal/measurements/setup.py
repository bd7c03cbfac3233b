"""Set-up unknowns: the parts of a measuring set-up that nobody knows exactly (DESIGN.md 8.1).

A *set-up block* is a small group of parameters estimated with the robot: a fixture point (a
socket, a datum cone: ``fixture.NAME.x|y|z``, mm), a plane (a table: ``plane.NAME.tilt_u|tilt_v``
(deg) and ``plane.NAME.d`` (mm)) or an instrument station (``station.NAME.phi|theta|psi|px|py|pz``,
deg and mm: the station's frame in the world, ``T = Rz(phi) Ry(theta) Rx(psi) Trans(px, py, pz)``
as the base's, DESIGN.md 8.3). Each kind is a :class:`BlockKind` in :data:`BLOCK_KINDS`. Each has a start,
an optional prior (a value and a sigma given in ``dataset.yaml``) or is fixed (``fixed: true``: known). Distances between fixture points
(``constraints.distances``) are factors on the blocks alone.

A plane is ``n . x = d`` with ``n`` a unit normal; the ball centre of a touching ball lies
``tool.radius`` from it on the side ``n`` points to; its normal is parametrised by two tilts about a
reference normal. What the blocks' entries mean in space (a station's frame, a plane's normal, a
distance between points) is :mod:`fgcal.measurements.setup_geometry`, whose names are importable
from here too. No I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from fgcal.measurements.setup_geometry import distance_error, plane_basis, plane_normal, station_transform

__all__ = [
    "BLOCK_KINDS",
    "BlockKind",
    "DistanceConstraint",
    "FixtureSpec",
    "SetupLayout",
    "SetupSpec",
    "distance_error",
    "plane_basis",
    "plane_normal",
    "register_block_kind",
    "station_transform",
]


@dataclass(frozen=True)
class BlockKind:
    """What a kind of set-up block is: its name prefix, components, which are angles, and how a
    given value (a point, a plane's normal and offset, a station's pose) becomes its entries.

    Attributes
    ----------
    type : str
        Its ``type:`` in ``dataset.yaml`` (``point``, ``plane``, ``station``).
    prefix : str
        Its parameters' first name part (``fixture``, ``plane``, ``station``).
    components : tuple of str
    angles : tuple of bool
        Which components are angles (rad inside, deg in files).
    """

    type: str
    prefix: str
    components: tuple
    angles: tuple

    @property
    def size(self) -> int:
        return len(self.components)

    def entries(self, value) -> tuple[np.ndarray, np.ndarray | None]:
        """The block's start entries (size,) for a value, and what it keeps beside (a plane's reference normal)."""
        value = np.asarray(value, dtype=float)
        if self.type == "plane":
            n0 = value[:3] / np.linalg.norm(value[:3])
            return np.array([0.0, 0.0, float(value[3])]), n0
        return value.copy(), None

    def prior_sigma(self, sigma: float) -> np.ndarray:
        """Sigmas (size,) of a block given with ``sigma`` (mm): angles by sigma over a 1 m lever."""
        return np.where(self.angles, sigma / 1000.0, sigma)


BLOCK_KINDS: dict = {
    "point": BlockKind("point", "fixture", ("x", "y", "z"), (False, False, False)),
    "plane": BlockKind("plane", "plane", ("tilt_u", "tilt_v", "d"), (True, True, False)),
    "station": BlockKind("station", "station", ("phi", "theta", "psi", "px", "py", "pz"),
                         (True, True, True, False, False, False)),
    # cameras and targets (DESIGN.md 8.4, fgcal.measurements.camera): the mount pose, translation first
    "camera": BlockKind("camera", "camera", ("px", "py", "pz", "phi", "theta", "psi", "fx", "fy", "cx", "cy",
                                             "k1", "k2", "p1", "p2", "k3"), (False,) * 3 + (True,) * 3 + (False,) * 9),
    "target": BlockKind("target", "target", ("px", "py", "pz", "phi", "theta", "psi"), (False,) * 3 + (True,) * 3),
}
FIXTURE_TYPES = ("point", "plane")


def register_block_kind(kind: BlockKind) -> None:
    """Add a kind of set-up block (a test's per-group offset, say); its ``type`` must be new."""
    if kind.type in BLOCK_KINDS:
        raise ValueError(f"a set-up block kind {kind.type!r} is registered already")
    BLOCK_KINDS[kind.type] = kind


@dataclass(frozen=True)
class FixtureSpec:
    """One fixture of ``dataset.yaml``'s ``fixtures:``.

    Attributes
    ----------
    name : str
    type : {"point", "plane"}
    value : ndarray or None
        A point ``(3,)`` mm, or a plane ``(4,)``: unit normal and offset ``d`` (mm); None: unknown.
    sigma : float or None
        The prior's sigma (mm) of a given value; None with a value and ``fixed``: known exactly.
    fixed : bool
    """

    name: str
    type: str
    value: np.ndarray | None = None
    sigma: float | None = None
    fixed: bool = False

    def entries_free(self, size: int) -> list:
        """Which of the block's ``size`` entries are estimated (all unless fixed; a camera's known
        intrinsics are not)."""
        return [not self.fixed] * size

    def entries_prior_sigma(self, kind: BlockKind) -> np.ndarray:
        """The prior sigma (internal units) of each entry (inf: none)."""
        if self.value is not None and self.sigma is not None and not self.fixed:
            return kind.prior_sigma(self.sigma)
        return np.full(kind.size, np.inf)

    def to_dict(self) -> dict:
        out: dict = {"type": self.type}
        if self.value is not None:
            if self.type == "point":
                out["position"] = [float(v) for v in self.value]
            elif self.type == "plane":
                out["normal"] = [float(v) for v in self.value[:3]]
                out["offset"] = float(self.value[3])
            elif self.type == "station":  # as stations: writes it (deg, mm)
                out["pose"] = [float(v) for v in np.degrees(self.value[:3])] + [float(v) for v in self.value[3:]]
            else:  # another kind: its entries (internal units)
                out["value"] = [float(v) for v in self.value]
        return {**out, **self.prior_entries()}

    def prior_entries(self) -> dict:
        """What ``dataset.yaml`` says of the value's prior: ``sigma`` (mm) and ``fixed``, where given."""
        out: dict = {}
        if self.sigma is not None:
            out["sigma"] = float(self.sigma)
        if self.fixed:
            out["fixed"] = True
        return out


@dataclass(frozen=True)
class DistanceConstraint:
    """A known distance (mm) between two fixture points, with its sigma (mm)."""

    a: str
    b: str
    distance: float
    sigma: float


@dataclass(frozen=True)
class SetupSpec:
    """The set-up of a dataset: its fixtures and the known distances between them."""

    fixtures: dict = field(default_factory=dict)  # name -> FixtureSpec
    distances: tuple = ()  # DistanceConstraint, ...

    def __bool__(self) -> bool:
        return bool(self.fixtures)

    def kind_of(self, name: str) -> str | None:
        f = self.fixtures.get(name)
        return None if f is None else f.type

    def to_dict(self) -> dict:
        out: dict = {}
        if self.fixtures:
            out["fixtures"] = {n: f.to_dict() for n, f in self.fixtures.items()}
        if self.distances:
            out["constraints"] = {"distances": [[c.a, c.b, float(c.distance), float(c.sigma)] for c in self.distances]}
        return out

    def placements(self) -> dict:
        """Fixture name -> its placement: fixtures linked by known distances (one plate's
        sockets) share one, numbered from 0 in the fixtures' order; any other fixture is its own."""
        parent = {n: n for n in self.fixtures}

        def root(n):
            while parent[n] != n:
                n = parent[n]
            return n

        for c in self.distances:
            if c.a in parent and c.b in parent:
                parent[root(c.b)] = root(c.a)
        order = {r: k for k, r in enumerate(dict.fromkeys(root(n) for n in self.fixtures))}
        return {n: order[root(n)] for n in self.fixtures}

    def subset(self, used) -> SetupSpec:
        """The fixtures named in ``used`` and the constraints between them."""
        used = set(used)
        return SetupSpec({n: f for n, f in self.fixtures.items() if n in used},
                         tuple(c for c in self.distances if c.a in used and c.b in used))


@dataclass
class SetupLayout:
    """The set-up blocks of one solve: their parameters in a vector ``s`` (internal units: mm, rad).

    Attributes
    ----------
    spec : SetupSpec
        The fixtures used (each seen by at least one measurement).
    offset : dict
        Fixture name -> its first index in ``s``: points take 3 entries (x, y, z), planes 3
        (tilt_u, tilt_v, d).
    reference : dict
        Plane name -> its reference unit normal ``n0`` (3,).
    start : ndarray, shape (S,)
        The values the solve starts from (and a fixed block's values).
    free : ndarray of bool, shape (S,)
        Entries that are estimated (not fixed).
    """

    spec: SetupSpec
    offset: dict
    reference: dict
    start: np.ndarray
    free: np.ndarray

    @classmethod
    def build(cls, spec: SetupSpec, starts: dict) -> SetupLayout:
        """``starts``: block name -> its start value (a point (3,), a plane (normal (3,), d), a
        station's entries (6,)) for blocks whose value is unknown."""
        offset: dict[str, int] = {}
        reference: dict[str, np.ndarray] = {}
        start: list[float] = []
        free: list[bool] = []
        for name, f in spec.fixtures.items():
            kind = BLOCK_KINDS[f.type]
            offset[name] = len(start)
            if f.value is not None:
                value = f.value
            elif f.type == "plane":
                value = np.concatenate([starts[name][0], [starts[name][1]]])
            else:
                value = starts[name]
            entries, aux = kind.entries(value)
            if aux is not None:
                reference[name] = aux
            start += [float(v) for v in entries]
            free += list(f.entries_free(kind.size))
        return cls(spec, offset, reference, np.array(start, dtype=float), np.array(free, dtype=bool))

    @property
    def size(self) -> int:
        return len(self.start)

    @property
    def n_free(self) -> int:
        return int(self.free.sum())

    def _per_block(self, values):
        out = []
        for name, f in self.spec.fixtures.items():
            kind = BLOCK_KINDS[f.type]
            k = self.offset[name]
            out += [v for v, free in zip(values(name, kind), self.free[k:k + kind.size]) if free]
        return out

    def names(self) -> list[str]:
        """Names of the free entries, ``KIND.NAME.COMPONENT``."""
        return list(self._names)

    @cached_property
    def _names(self) -> tuple[str, ...]:  # the layout is fixed once built: formed once (asked for ~6 times a solve)
        return tuple(self._per_block(lambda name, kind: [f"{kind.prefix}.{name}.{c}" for c in kind.components]))

    def is_angle(self) -> np.ndarray:
        """(S_free,) whether each free entry is an angle (a plane's tilts, a station's angles)."""
        return self._is_angle.copy()

    @cached_property
    def _is_angle(self) -> np.ndarray:
        return np.array(self._per_block(lambda name, kind: list(kind.angles)), dtype=bool)

    def prior(self) -> tuple[np.ndarray, np.ndarray]:
        """Mean and sigma ``(S_free,)`` of the free entries' priors (sigma inf: none)."""
        sig = np.full(self.size, np.inf)
        for name, f in self.spec.fixtures.items():
            kind = BLOCK_KINDS[f.type]
            k = self.offset[name]
            sig[k:k + kind.size] = f.entries_prior_sigma(kind)
        return self.start[self.free], sig[self.free]

    def full(self, s_free) -> np.ndarray:
        """The whole vector ``s`` (S,) with the free entries set to ``s_free``."""
        s = self.start.copy()
        s[self.free] = s_free
        return s

    def column(self) -> np.ndarray:
        """(S,) the column of each entry among the free ones (-1 for fixed entries)."""
        col = np.full(self.size, -1, dtype=int)
        col[self.free] = np.arange(self.n_free)
        return col

    def distance_errors(self, s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The known distances between fixture points at ``s``: errors ``|p_a - p_b| - distance``
        (k,) mm, their Jacobian (k, S) in the whole vector ``s`` and their sigmas (k,) mm."""
        ka, kb, length, sd = self._distance_tables
        diff = s[ka] - s[kb]  # (k, 3): all the constraints at once (their Python loop: 0.12 ms a linearisation at 33, now 0.01)
        dist = np.sqrt(np.einsum("kj,kj->k", diff, diff))
        u = diff / np.maximum(dist, 1e-300)[:, None]
        J = np.zeros((len(length), self.size))
        rows = np.arange(len(length))[:, None]
        np.add.at(J, (rows, ka), u)  # add.at: a constraint between two entries of one block adds both
        np.add.at(J, (rows, kb), -u)
        return dist - length, J, sd

    @cached_property
    def _distance_tables(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Each known distance's entries of its points ``a`` and ``b`` (k, 3), length and sigma (k,) mm."""
        cons = self.spec.distances
        ka = np.array([self.offset[c.a] + np.arange(3) for c in cons], dtype=int).reshape(-1, 3)
        kb = np.array([self.offset[c.b] + np.arange(3) for c in cons], dtype=int).reshape(-1, 3)
        return (ka, kb, np.array([float(c.distance) for c in cons]), np.array([c.sigma for c in cons], dtype=float))

    def prior_information(self, s) -> np.ndarray:
        """(S_free, S_free) information about the free entries from their priors and, linearised
        at ``s``, the known distances (the rows of the graph that touch the set-up blocks alone)."""
        _, sig = self.prior()
        info = np.diag(np.where(np.isfinite(sig), 1.0 / sig**2, 0.0))
        if self.spec.distances:
            _, J, sd = self.distance_errors(s)
            J = J[:, self.free] / sd[:, None]
            info = info + J.T @ J
        return info

    def point(self, s, name) -> np.ndarray:
        k = self.offset[name]
        return s[k:k + 3]

    def block(self, s, name) -> np.ndarray:
        """The entries of block ``name`` in ``s``."""
        k = self.offset[name]
        return s[k:k + BLOCK_KINDS[self.spec.fixtures[name].type].size]

    def plane(self, s, name) -> tuple[np.ndarray, float]:
        """Unit normal (3,) and offset d (mm) of plane ``name`` in ``s``."""
        k = self.offset[name]
        n, _ = plane_normal(self.reference[name], s[k:k + 2])
        return n, float(s[k + 2])

    def describe(self, s) -> dict:
        """The blocks' values in ``s`` as a plain dict (points mm; planes unit normal and offset mm;
        stations ``pose``: phi, theta, psi (deg), px, py, pz (mm); other kinds their entries)."""
        out: dict[str, dict[str, object]] = {}
        for name, f in self.spec.fixtures.items():
            k = self.offset[name]
            if f.type == "point":
                out[name] = {"type": "point", "position": [float(v) for v in self.point(s, name)]}
            elif f.type == "station":
                e = s[k:k + 6]
                out[name] = {"type": "station", "pose": [float(v) for v in np.degrees(e[:3])] + [float(v) for v in e[3:]]}
            elif f.type in ("camera", "target"):  # mount pose: mm, then deg (DESIGN.md 8.4)
                e = s[k:k + BLOCK_KINDS[f.type].size]
                out[name] = {"type": f.type, "pose": [float(v) for v in e[:3]] + [float(v) for v in np.degrees(e[3:6])]}
                if f.type == "camera":
                    out[name]["intrinsics"] = {c: float(v) for c, v in zip(BLOCK_KINDS["camera"].components[6:], e[6:])}
            elif f.type != "plane":
                out[name] = {"type": f.type, "entries": [float(v) for v in s[k:k + BLOCK_KINDS[f.type].size]]}
            else:
                n, d = self.plane(s, name)
                out[name] = {"type": "plane", "normal": [float(v) for v in n], "offset": d,
                             "reference_normal": [float(v) for v in self.reference[name]]}
            out[name]["fixed"] = bool(f.fixed)
        return out
