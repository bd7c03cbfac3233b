"""Set-up blocks in the online engines (DESIGN.md 8.2): fixture points and planes join the state
when a pose first touches them.

The engines' state is ``x = [theta (P), s (S)]``: the robot's parameters, then the free entries of
a :class:`~fgcal.measurements.setup.SetupLayout` over the fixtures seen so far, in the order they
were first seen (a new block is appended: the columns of the others do not move).

* A fixture point starts at the predicted centre of the first ball seated in it (at the current
  estimate), with a prior of :data:`WIDE_PRIOR_MM` per axis (a given position: its own sigma).
* A plane cannot be started from one contact (one point does not give a normal): its contacts
  are kept *pending* (the pose is taken; nothing of the plane enters the state) until at least
  :data:`PLANE_MIN_CONTACTS` of them, spread by at least :data:`PLANE_MIN_SPREAD_MM` across a
  line, give a plane fit (the predicted centres at the current estimate, its normal towards the
  tool, as the batch's start). The plane then starts from that fit (tilts zero about the fitted
  normal, a prior of :data:`WIDE_PRIOR_MM` on the offset and of the same over a 1 m lever on the
  tilts), and the pending contacts enter with the pose that completed it. A plane with a given
  normal and offset starts from them at once.
* A station's frame (``station.NAME.*``, DESIGN.md 8.3) cannot be started from one centre either:
  the centres measured from it are kept pending until at least :data:`FIT_MIN_ROWS` of them,
  spread by :data:`PLANE_MIN_SPREAD_MM` across a line, give the rigid fit of the robot's predicted
  centres (at the current estimate) to the measured ones (the type's ``block_starts``, as the
  batch starts it); it starts there with a prior of :data:`WIDE_PRIOR_MM` on its position and of
  the same over a 1 m lever on its angles, and the pending centres enter with the pose that
  completed it. A station with a given pose starts from it at once.
* A known distance between two fixture points (``constraints.distances``) enters with the pose
  whose contact brings the second of them into the state.

All of it is decided when a pose is taken (:meth:`OnlineSetup.propose` builds the proposal, the
engine commits it only if the pose is accepted), so a replay of the journal, in the same order
and from the same estimates, rebuilds the same blocks. No I/O here.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from fgcal.errors import FgcalError
from fgcal.measurements.setup import BLOCK_KINDS, SetupLayout, SetupSpec, distance_error
from fgcal.online.records import PoseData, block_observations, setup_types

__all__ = ["CAMERA_MIN_IMAGES", "FIT_MIN_ROWS", "PLANE_MIN_CONTACTS", "PLANE_MIN_SPREAD_MM", "WIDE_PRIOR_MM", "OnlineSetup",
           "SetupProposal"]

log = logging.getLogger(__name__)

WIDE_PRIOR_MM = 100.0  # a new unknown block's prior sigma (mm; a plane's tilts: this over a 1 m lever)
PLANE_MIN_CONTACTS = 3
PLANE_MIN_SPREAD_MM = 10.0  # RMS distance of the contacts from their best line, for a plane fit
FIT_MIN_ROWS = 3  # measurements of a block started by a fit of several (a station: a rigid fit of its centres)
CAMERA_MIN_IMAGES = 6  # images of a camera's target before its hand-eye start (three determine it; six steady it)


@dataclass
class Pending:
    """A measurement of a block not started yet (a contact to a plane, a centre from a station):
    its pose's id and joints, level, ball, block and measured values (None for a contact)."""

    pose: int
    q: np.ndarray
    level: str
    ball: str
    fixture: str
    values: np.ndarray | None = None

    @property
    def touch(self) -> tuple:
        return (self.level, self.ball, self.fixture, self.values)

    def to_json(self) -> list:
        out = [self.pose, self.q.tolist(), self.level, self.ball, self.fixture]
        return out if self.values is None else out + [np.asarray(self.values, dtype=float).tolist()]

    @classmethod
    def from_json(cls, d) -> Pending:
        values = np.array(d[5], dtype=float) if len(d) > 5 else None
        return cls(int(d[0]), np.array(d[1], dtype=float), str(d[2]), str(d[3]), str(d[4]), values)


@dataclass
class SetupGroup:
    """The contacts of one pose to blocks in the state: ``current`` (the pose being taken: its
    joints' noise is folded in with its other rows) or a pending one's (its own joints)."""

    q: np.ndarray
    kind: object  # a measurement type with ``uses_setup``
    data: tuple  # its terms' payload over ``layout``
    n: int
    current: bool
    fixtures: list = field(default_factory=list)  # the fixture of each contact
    blocks: list = field(default_factory=list)  # the blocks each row depends on (a corner: camera, target)


@dataclass
class SetupProposal:
    """What a pose does to the set-up blocks if it is taken."""

    layout: SetupLayout | None
    n_before: int  # free set-up entries in the state before the pose
    mean: np.ndarray  # (k,) the starts of the free entries the pose adds
    sigma: np.ndarray  # (k,) their prior sigmas
    groups: list = field(default_factory=list)
    constraints: list = field(default_factory=list)  # DistanceConstraint entering with the pose
    pending: list = field(default_factory=list)  # Pending after the pose
    started: list = field(default_factory=list)  # the names of the blocks the pose starts
    starts: dict = field(default_factory=dict)  # name -> start (as SetupLayout.build takes it), after

    @property
    def n_rows(self) -> int:
        return sum(g.n * g.kind.width for g in self.groups) + len(self.constraints)

    def augment(self, x, P):
        """The state ``(x, P)`` with the new blocks' starts and priors appended (unchanged if none)."""
        if not len(self.mean):
            return x, P
        k, n = len(self.mean), len(x)
        Pa = np.zeros((n + k, n + k))
        Pa[:n, :n] = P
        Pa[n:, n:] = np.diag(self.sigma**2)
        return np.concatenate([x, self.mean]), Pa

    def rows(self, engine, x):
        """The set-up rows at state ``x``: ``[(e (m,), J_x (m, len(x)), J_q (m, n) or None, group)]``
        (a constraint's group is None); their declared sigmas come from :meth:`sigmas`."""
        if self.layout is None:  # every measurement pending: no block in the state yet
            return []
        P = len(engine.params)
        theta = np.asarray(x[:P], dtype=float)
        s = self.layout.full(np.asarray(x[P:], dtype=float))
        col = self.layout.column()
        out = []
        for g in self.groups:
            qs = np.broadcast_to(g.q, (g.n, len(g.q)))
            e, J_t, J_q, J_s, cols = g.kind.setup_error(theta, qs, g.data, s, engine.index, engine.held,
                                                        engine.model.chain)
            m, w = e.shape
            J = np.zeros((m, w, len(x)))
            J[:, :, :P] = J_t
            where = col[cols]  # (m, 3): the free column of each block entry, -1 for a fixed one
            for i in range(m):
                for j in range(cols.shape[1]):
                    if where[i, j] >= 0:
                        J[i, :, P + where[i, j]] += J_s[i, :, j]
            out.append((e.reshape(-1), J.reshape(m * w, -1), J_q.reshape(m * w, -1), g))
        for c in self.constraints:
            ka, kb = self.layout.offset[c.a], self.layout.offset[c.b]
            err, u = distance_error(s[ka:ka + 3], s[kb:kb + 3], c.distance)
            J = np.zeros((1, len(x)))
            for k, sign in ((ka, 1.0), (kb, -1.0)):
                for j in range(3):
                    if col[k + j] >= 0:
                        J[0, P + col[k + j]] += sign * u[j]
            out.append((np.array([err]), J, None, None))
        return out

    def sigmas(self, engine) -> np.ndarray:
        """The declared sigmas (mm) of the rows of :meth:`rows`, in their order."""
        parts = [np.tile(g.kind.sigma(engine.sigmas), g.n) for g in self.groups]
        parts += [np.array([c.sigma]) for c in self.constraints]
        return np.concatenate(parts) if parts else np.zeros(0)


class OnlineSetup:
    """The set-up blocks an engine has started, and the plane contacts waiting for a plane fit."""

    def __init__(self, spec: SetupSpec):
        self.spec = spec
        self.starts: dict = {}  # name -> start: a point (3,), or a plane (normal (3,), d)
        self.order: list[str] = []  # the blocks in the state, in the order first seen
        self.layout: SetupLayout | None = None
        self.pending: list[Pending] = []

    @property
    def has_references(self) -> bool:
        """Whether a block's parameters depend on where it started (a plane's tilts are about the
        normal of its start), or a contact waits for such a block."""
        return bool(self.pending) or (self.layout is not None and bool(self.layout.reference))

    @property
    def n_free(self) -> int:
        return 0 if self.layout is None else self.layout.n_free

    def _layout(self, order, starts) -> SetupLayout | None:
        if not order:
            return None
        used = set(order)
        spec = SetupSpec({n: self.spec.fixtures[n] for n in order},
                         tuple(c for c in self.spec.distances if c.a in used and c.b in used))
        return SetupLayout.build(spec, starts)

    def propose(self, engine, rec: PoseData, theta) -> SetupProposal | None:
        """What taking ``rec`` would do to the blocks at the robot's estimate ``theta`` (P,); None
        when the pose measures no set-up block."""
        touches = [(lv, b, n, None) for lv, b, n in rec.contacts] + list(rec.block_rows)
        if not touches:
            return None
        kinds = {k.level: k for k in setup_types()}
        order, starts, started = list(self.order), dict(self.starts), []
        for level, ball, name, _ in touches:
            f = self.spec.fixtures.get(name)
            if f is None or level not in kinds:
                raise FgcalError(f"pose {rec.pose}: {name!r} is not in dataset.yaml's fixtures or stations")
            need = _needs(kinds[level], name, ball, self.spec)
            if all(n in order for n in need):
                continue
            if len(need) > 1:  # blocks started together from one fit of their rows (a camera and its target)
                new = [n for n in need if n not in order]
                unknown = {n for n in new if self.spec.fixtures[n].value is None}
                if unknown:
                    mine = [(p.q, p.ball, p.values) for p in self.pending if p.fixture == name]
                    mine += [(rec.q, b, v) for lv, b, n, v in touches if n == name]
                    fits = _fitted_starts(engine, theta, kinds[level], name, mine, unknown, self.spec)
                    if fits is None:
                        continue
                    starts.update(fits)
                order += new
                started += new
                continue
            if name in order:
                continue
            if f.value is None and f.type == "point":
                starts[name] = _centres(engine, theta, [(rec.q, ball)])[0][0]
            elif f.value is None:
                mine = [(p.q, p.ball, p.values) for p in self.pending if p.fixture == name]
                mine += [(rec.q, b, v) for lv, b, n, v in touches if n == name]
                if f.type == "plane":
                    fit = _plane_fit(*_centres(engine, theta, [(q, b) for q, b, _ in mine]), engine.ds.tooling.radius)
                else:
                    fit = (_fitted_starts(engine, theta, kinds[level], name, mine, {name}, self.spec) or {}).get(name)
                if fit is None:
                    continue
                starts[name] = fit
            order.append(name)
            started.append(name)
        layout = self._layout(order, starts)
        n_before = self.n_free
        mean = layout.start[layout.free][n_before:] if layout is not None else np.zeros(0)
        prior = layout.prior()[1][n_before:] if layout is not None else np.zeros(0)
        wide = np.concatenate([_wide_prior(self.spec.fixtures[n]) for n in started] or [np.zeros(0)])
        sigma = np.where(np.isfinite(prior), prior, wide)
        def ready(t) -> bool:  # every block the row depends on is in the state
            return layout is not None and all(n in layout.offset for n in _needs(kinds[t[0]], t[2], t[1], self.spec))

        groups = []
        here = [t for t in touches if ready(t)]
        groups += _groups(kinds, here, rec.q, engine.ds.tooling, layout, True, self.spec)
        entering: dict = {}  # the pending rows that enter, by pose: one group per pose and level
        for p in self.pending:
            if ready(p.touch):
                entering.setdefault(p.pose, (p.q, []))[1].append(p.touch)
        for q, touched in entering.values():
            groups += _groups(kinds, touched, q, engine.ds.tooling, layout, False, self.spec)
        pending = [p for p in self.pending if not ready(p.touch)]
        pending += [Pending(rec.pose, rec.q.copy(), lv, b, n, v) for lv, b, n, v in touches if not ready((lv, b, n, v))]
        before = set(self.order)
        constraints = [c for c in self.spec.distances if {c.a, c.b} <= set(order) and not {c.a, c.b} <= before]
        return SetupProposal(layout, n_before, mean, sigma, groups, constraints, pending, started, starts)

    def commit(self, proposal: SetupProposal | None) -> None:
        """Take the proposal of an accepted pose."""
        if proposal is None:
            return
        for name in proposal.started:
            log.info("set-up block %s joins the state", name)
        self.order = list(proposal.layout.spec.fixtures) if proposal.layout is not None else []
        self.starts = dict(proposal.starts)
        self.layout = proposal.layout
        self.pending = list(proposal.pending)

    def adopt(self, layout: SetupLayout) -> None:
        """Take ``layout`` (the final smoothing's: the batch's order and plane references) as the state's."""
        self.layout = layout
        self.order = list(layout.spec.fixtures)
        self.starts = {}
        for name, f in layout.spec.fixtures.items():
            k = layout.offset[name]
            self.starts[name] = layout.block(layout.start, name).copy() if f.type != "plane" else \
                (layout.reference[name].copy(), float(layout.start[k + 2]))
        self.pending = [p for p in self.pending if p.fixture not in layout.offset]

    def to_json(self) -> dict:
        starts = {n: (v.tolist() if isinstance(v, np.ndarray) else [list(map(float, v[0])), float(v[1])])
                  for n, v in self.starts.items()}
        return {"order": self.order, "starts": starts, "pending": [p.to_json() for p in self.pending]}

    def restore(self, d: dict) -> None:
        self.order = list(d.get("order", []))
        self.starts = {n: (np.array(v, dtype=float) if self.spec.fixtures[n].type != "plane"
                           else (np.array(v[0], dtype=float), float(v[1]))) for n, v in d.get("starts", {}).items()}
        self.layout = self._layout(self.order, self.starts)
        self.pending = [Pending.from_json(p) for p in d.get("pending", [])]

    def describe(self, values) -> dict:
        """The result's ``setup`` section (as :func:`fgcal.estimation.calibrate._setup_info`) at free values ``values``."""
        if self.layout is None:
            return {}
        return {**self.layout.spec.to_dict(), "estimated": self.layout.describe(self.layout.full(values))}


def _needs(kind, block: str, ball: str, spec: SetupSpec) -> list:
    """The blocks one row (of block ``block``, ball or label ``ball``) depends on: its block, or
    those the type names (a corner: its camera and the target that has the point)."""
    return kind.row_blocks(block, ball, spec.fixtures) if hasattr(kind, "row_blocks") else [block]


def _wide_prior(f) -> np.ndarray:
    """A new block's prior sigmas over its free entries: :data:`WIDE_PRIOR_MM` (over a 1 m lever for
    angles; a camera's estimated intrinsics: the same in px, and over 1000 for the distortion)."""
    kind = BLOCK_KINDS[f.type]
    wide = kind.prior_sigma(WIDE_PRIOR_MM)
    if f.type == "camera":  # the distortion is dimensionless: a tenth, as the angles
        wide[10:] = WIDE_PRIOR_MM / 1000.0
    return wide[np.asarray(f.entries_free(kind.size), dtype=bool)]


def _observations(kind, balls, blocks, values, spec: SetupSpec):
    """The type's observations of one pose's rows (pose id 0): ``values`` None for a contact (the
    block alone), else the measured values (M, k) of a type that carries them."""
    pose = np.zeros(len(balls), dtype=int)
    if values is None:
        return kind.observations(pose, np.array(balls), np.array(blocks))
    return block_observations(kind, pose, np.array(balls), np.array(blocks), np.array(values, dtype=float), spec)


def _groups(kinds, touches, q, tooling, layout, current: bool, spec: SetupSpec) -> list:
    """One :class:`SetupGroup` per level of ``touches`` ((level, ball, block, values or None), one pose's)."""
    out = []
    for level in dict.fromkeys(t[0] for t in touches):
        rows = [t for t in touches if t[0] == level]
        kind = kinds[level]
        values = None if rows[0][3] is None else [t[3] for t in rows]
        obs = _observations(kind, [t[1] for t in rows], [t[2] for t in rows], values, spec)
        out.append(SetupGroup(np.asarray(q, dtype=float), kind, kind.terms(obs, tooling, {0: 0}, layout).data,
                              len(rows), current, [t[2] for t in rows],
                              [_needs(kind, t[2], t[1], spec) for t in rows]))
    return out


def _fitted_starts(engine, theta, kind, name, rows, unknown: set, spec: SetupSpec) -> dict | None:
    """The starts of the blocks ``unknown`` measured through block ``name`` by its rows ``rows``
    ((q, ball, values), ...) at the robot's estimate ``theta``, by the type's ``block_starts`` (a
    station: the rigid fit of the predicted centres to the measured ones; a camera and its target:
    per-image PnP and a hand-eye solve, from :data:`CAMERA_MIN_IMAGES` images), or None while the
    rows are fewer than :data:`FIT_MIN_ROWS` or their values lie within :data:`PLANE_MIN_SPREAD_MM`
    of one line (the type's own start refusing them: too few images)."""
    from fgcal.robots.kinematics import forward

    if len(rows) < FIT_MIN_ROWS:
        return None
    values = np.array([v for _, _, v in rows], dtype=float).reshape(len(rows), -1)
    if getattr(kind, "block_specs", False):
        if len({np.asarray(q, dtype=float).tobytes() for q, _, _ in rows}) < CAMERA_MIN_IMAGES:
            return None
    elif values.shape[1] >= 3:
        sv = np.linalg.svd(values[:, :3] - values[:, :3].mean(axis=0), compute_uv=False)
        if sv[1] / np.sqrt(len(rows)) < PLANE_MIN_SPREAD_MM:
            return None
    qs = np.array([q for q, _, _ in rows])
    T = forward(engine.params.full(theta, engine.held), qs, engine.model.chain)
    # one pose id per joint set: a camera's start takes the rows of one image together
    _, image = np.unique(qs, axis=0, return_inverse=True)
    obs = _observations(kind, [b for _, b, _ in rows], [name] * len(rows), values, spec)
    obs.pose = np.asarray(image, dtype=int).reshape(-1)
    try:
        fits = kind.block_starts(obs, T, engine.ds.tooling, set(unknown), "online")
    except FgcalError as exc:
        log.info("block %s not started yet: %s", name, exc)
        return None
    return fits if set(unknown) <= set(fits) else None


def _centres(engine, theta, touches) -> tuple[np.ndarray, np.ndarray]:
    """Predicted ball centres (k, 3) and tool origins (k, 3) of ``touches`` ((q, ball), ...) at ``theta``."""
    balls = engine.ds.tooling.balls
    centres, origins = [], []
    for q, ball in touches:
        h, _, _ = engine._ball_kinematics(theta, np.asarray(q, dtype=float), np.array([balls[ball], [0.0, 0.0, 0.0]]))
        centres.append(h[0])
        origins.append(h[1])
    return np.array(centres).reshape(-1, 3), np.array(origins).reshape(-1, 3)


def _plane_fit(centres, origins, radius):
    """``(normal, d)`` of the plane the balls at ``centres`` touch (the normal towards the tool, as
    the batch starts it: :func:`fgcal.estimation.build._setup_layout`), or None while the contacts
    are too few or too close to one line."""
    if len(centres) < PLANE_MIN_CONTACTS:
        return None
    c0 = centres - centres.mean(axis=0)
    sv, vt = np.linalg.svd(c0)[1:]
    if sv[1] / np.sqrt(len(centres)) < PLANE_MIN_SPREAD_MM:
        return None
    n = vt[2]
    if np.mean((origins - centres) @ n) < 0:
        n = -n
    return n, float(np.mean(centres @ n)) - float(radius)
