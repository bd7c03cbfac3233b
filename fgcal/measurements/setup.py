"""Set-up unknowns: the parts of a measuring set-up that nobody knows exactly (DESIGN.md 8.1).

A *set-up block* is a small group of parameters estimated with the robot: a fixture point (a
socket, a datum cone: ``fixture.NAME.x|y|z``, mm) or a plane (a table: ``plane.NAME.tilt_u|tilt_v``
(deg) and ``plane.NAME.d`` (mm)). Each has a start, an optional prior (a value and a sigma given
in ``dataset.yaml``) or is fixed (``fixed: true``: known). Distances between fixture points
(``constraints.distances``) are factors on the blocks alone.

A plane is ``n . x = d`` with ``n`` a unit normal; the ball centre of a touching ball lies
``tool.radius`` from it on the side ``n`` points to. Its normal is parametrised about a reference
normal ``n0`` (the given normal, else the start's fit) by two tilts: ``n = normalise(n0 + tan(tilt_u)
u + tan(tilt_v) v)`` with ``u, v`` orthonormal to ``n0``, so the parameters are free of the
singularities of angle pairs. No I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["FixtureSpec", "DistanceConstraint", "SetupSpec", "SetupLayout", "plane_basis", "plane_normal"]

FIXTURE_TYPES = ("point", "plane")


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

    def to_dict(self) -> dict:
        out: dict = {"type": self.type}
        if self.value is not None:
            if self.type == "point":
                out["position"] = [float(v) for v in self.value]
            else:
                out["normal"] = [float(v) for v in self.value[:3]]
                out["offset"] = float(self.value[3])
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

    def subset(self, used) -> "SetupSpec":
        """The fixtures named in ``used`` and the constraints between them."""
        used = set(used)
        return SetupSpec({n: f for n, f in self.fixtures.items() if n in used},
                         tuple(c for c in self.distances if c.a in used and c.b in used))


def plane_basis(n0) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors ``u, v`` orthonormal to the unit normal ``n0`` (a fixed, deterministic choice)."""
    n0 = np.asarray(n0, dtype=float)
    helper = np.eye(3)[int(np.argmin(np.abs(n0)))]
    u = np.cross(n0, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(n0, u)


def plane_normal(n0, tilts) -> tuple[np.ndarray, np.ndarray]:
    """The unit normal for tilts ``(tilt_u, tilt_v)`` (rad) about ``n0``, and ``dn/dtilt`` (3, 2)."""
    u, v = plane_basis(n0)
    tu, tv = np.tan(tilts[0]), np.tan(tilts[1])
    m = np.asarray(n0, dtype=float) + tu * u + tv * v
    norm = np.linalg.norm(m)
    n = m / norm
    dm = np.column_stack([u / np.cos(tilts[0]) ** 2, v / np.cos(tilts[1]) ** 2])
    return n, (np.eye(3) - np.outer(n, n)) @ dm / norm


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
    def build(cls, spec: SetupSpec, starts: dict) -> "SetupLayout":
        """``starts``: fixture name -> a start point (3,) or plane (normal (3,), d) for unknown fixtures."""
        offset, reference, start, free = {}, {}, [], []
        for name, f in spec.fixtures.items():
            offset[name] = len(start)
            if f.type == "point":
                value = f.value if f.value is not None else starts[name]
                start += [float(v) for v in value]
            else:
                value = f.value if f.value is not None else np.concatenate([starts[name][0], [starts[name][1]]])
                n0 = np.asarray(value[:3], dtype=float)
                reference[name] = n0 / np.linalg.norm(n0)
                start += [0.0, 0.0, float(value[3])]
            free += [not f.fixed] * 3
        return cls(spec, offset, reference, np.array(start, dtype=float), np.array(free, dtype=bool))

    @property
    def size(self) -> int:
        return len(self.start)

    @property
    def n_free(self) -> int:
        return int(self.free.sum())

    def names(self) -> list[str]:
        """Names of the free entries, ``KIND.NAME.COMPONENT``."""
        out = []
        for name, f in self.spec.fixtures.items():
            comps = [f"fixture.{name}.{c}" for c in "xyz"] if f.type == "point" else \
                [f"plane.{name}.tilt_u", f"plane.{name}.tilt_v", f"plane.{name}.d"]
            out += [c for c, k in zip(comps, self.free[self.offset[name]:self.offset[name] + 3]) if k]
        return out

    def is_angle(self) -> np.ndarray:
        """(S_free,) whether each free entry is an angle (a plane's tilts)."""
        flags = []
        for name, f in self.spec.fixtures.items():
            comps = [False, False, False] if f.type == "point" else [True, True, False]
            flags += [a for a, k in zip(comps, self.free[self.offset[name]:self.offset[name] + 3]) if k]
        return np.array(flags, dtype=bool)

    def prior(self) -> tuple[np.ndarray, np.ndarray]:
        """Mean and sigma ``(S_free,)`` of the free entries' priors (sigma inf: none)."""
        sig = np.full(self.size, np.inf)
        for name, f in self.spec.fixtures.items():
            if f.value is not None and f.sigma is not None and not f.fixed:
                k = self.offset[name]
                if f.type == "point":
                    sig[k:k + 3] = f.sigma
                else:  # a given plane: its offset by sigma, its tilts by sigma over a 1 m lever
                    sig[k:k + 3] = [f.sigma / 1000.0, f.sigma / 1000.0, f.sigma]
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
        cons = self.spec.distances
        e, J = np.zeros(len(cons)), np.zeros((len(cons), self.size))
        for i, c in enumerate(cons):
            ka, kb = self.offset[c.a], self.offset[c.b]
            diff = s[ka:ka + 3] - s[kb:kb + 3]
            dist = np.linalg.norm(diff)
            e[i] = dist - c.distance
            u = diff / max(dist, 1e-300)
            J[i, ka:ka + 3] += u
            J[i, kb:kb + 3] -= u
        return e, J, np.array([c.sigma for c in cons], dtype=float)

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

    def plane(self, s, name) -> tuple[np.ndarray, float]:
        """Unit normal (3,) and offset d (mm) of plane ``name`` in ``s``."""
        k = self.offset[name]
        n, _ = plane_normal(self.reference[name], s[k:k + 2])
        return n, float(s[k + 2])

    def describe(self, s) -> dict:
        """The fixtures' values in ``s`` as a plain dict (points mm; planes unit normal and offset mm)."""
        out = {}
        for name, f in self.spec.fixtures.items():
            if f.type == "point":
                out[name] = {"type": "point", "position": [float(v) for v in self.point(s, name)]}
            else:
                n, d = self.plane(s, name)
                out[name] = {"type": "plane", "normal": [float(v) for v in n], "offset": d,
                             "reference_normal": [float(v) for v in self.reference[name]]}
            out[name]["fixed"] = bool(f.fixed)
        return out
