"""The iSAM2 engine: incremental smoothing over the batch graph's GTSAM factors, in segments."""
from __future__ import annotations

from typing import Any

import numpy as np

import factors as fx
from fgcal.errors import FgcalError
from fgcal.estimation.options import CalibrationOptions
from fgcal.measurements.distance import DISTANCE
from fgcal.measurements.pose import POSE
from fgcal.measurements.setup import BLOCK_KINDS
from fgcal.online.base import _Engine
from fgcal.online.measurement import UpdateReport
from fgcal.online.records import PoseData
from fgcal.online.setup_factors import contact_factor, distance_constraint_factor, joint_gaussian_factor

__all__ = ["ISAM2Engine"]

# A joint variable that moves more (rad, or mm) is relinearised. Leaving a 3e-4 rad move out errs by
# ~(1 m)(3e-4)^2 = 1e-4 mm, 1% of the CMM's noise; measured over 400 poses: the running estimate
# within 0.0025 sigma of the one at 1e-5 rad, for 42% less CPU (fewer Python factor callbacks).
Q_RELINEARISE = 3e-4
BLOCK_SYMBOLS = "suvwxyz"  # the set-up blocks' variables, one symbol per block size (3 entries: s)


class ISAM2Engine(_Engine):
    """Incremental smoothing over the same factors as the batch graph, in segments of ``window`` poses."""

    snapshots = False  # the tree cannot be stored: a resume replays the journal

    def __init__(self, ds, model, options=CalibrationOptions(), names=None, theta_threshold=(0.05, 1e-4),
                 factorization="QR", window: int = 50):
        """``window``: poses (their joint variables and factors) in one tree. When it is full the
        tree is replaced by a new one whose only factor is the parameters' marginal, a Gaussian at
        the current estimate: each pose's information stays, its linearisation is frozen (as a
        marginalised leaf's would be), and each update's cost and the memory stay bounded (measured
        at 300 poses: the running estimate within 5e-4 sigma of one whole tree's, the sigmas within
        3e-5)."""
        import gtsam

        super().__init__(ds, model, options, names)
        self.window = window
        p = gtsam.ISAM2Params()
        p.setFactorization(factorization)
        # The default wildfire threshold (1e-3 in variable units) would leave angle updates below
        # 0.06 deg unpropagated: back-substitute everything the new pose touches.
        p.setOptimizationParams(gtsam.ISAM2GaussNewtonParams(0.0))
        thresholds = gtsam.ISAM2ThresholdMap()
        is_angle = self.params.is_angle
        thresholds.insert(("k", np.where(is_angle, theta_threshold[1], theta_threshold[0])))
        # Relinearising the parameters re-evaluates every factor of every pose: allow it only when
        # they move by 0.05 mm / 1e-4 rad (measured: within 0.003 sigma of the batch solve; at
        # 0.5 mm / 1e-3 rad the systematic second-order error reached 0.14 sigma).
        thresholds.insert(("q", np.full(model.n_joints, Q_RELINEARISE)))
        # A set-up block (a point's x, y, z or a plane's two tilts and offset): the angles' threshold
        # on the first two entries (a point's x and y are relinearised more often: they are cheap).
        thresholds.insert(("s", np.array([theta_threshold[1], theta_threshold[1], theta_threshold[0]])))
        # A block of another shape (a station's three angles and position, a camera's mount and the
        # intrinsics it estimates) has a symbol of its own, with the thresholds of its free entries.
        self._block_symbols: dict[tuple, str] = {(3, *_thresholds(BLOCK_KINDS["plane"], theta_threshold)): "s"}
        for kind, free in _block_shapes(ds):
            shape = _thresholds(kind, theta_threshold)[np.asarray(free, dtype=bool)]
            key = (len(shape), *shape)
            if key not in self._block_symbols and len(self._block_symbols) < len(BLOCK_SYMBOLS):
                c = BLOCK_SYMBOLS[len(self._block_symbols)]
                self._block_symbols[key] = c
                thresholds.insert((c, shape))
        p.setRelinearizeThreshold(thresholds)
        self._theta_threshold = theta_threshold
        p.relinearizeSkip = 1
        self._isam_params = p
        self.t_key = fx.theta_key()
        self._s_keys: dict[str, int] = {}  # free set-up block -> its variable, in the order started
        self._s_sizes: dict[str, int] = {}  # free set-up block -> its free entries
        self._s_symbols: dict[str, str] = {}  # free set-up block -> its variable's symbol
        self._tree(None)
        self._started = False

    def _tree(self, marginal) -> None:
        """A new, empty tree; ``marginal``: ``(x, covariance)`` of the state variables (the
        parameters, the set-up blocks) that its first update adds as a Gaussian, None: the prior."""
        import gtsam

        self.isam = gtsam.ISAM2(self._isam_params)
        self._marginal = marginal
        self._in_tree = 0  # poses in this tree
        self._linpoint: Any = None  # a gtsam.Values once the tree has one
        self._keep: list = []  # the factors' closures reference their arguments: keep them alive
        self._est = None  # (theta, covariance) of the tree as it is

    def _current(self) -> np.ndarray:
        return self.estimate()[0]

    def _covariance(self) -> np.ndarray:
        return self._running()[1]

    def update(self, rec: PoseData) -> UpdateReport:
        # The innovation against the current estimate, at the noise estimated so far.
        theta, cov = self._running()
        m, used, f, reason = self._screen(rec, theta, cov)
        if m is None:
            return self._report(rec, reason)
        self._add(used, m, f)
        return self._report(used, None, m, f)

    def _state_keys(self):
        """The state's variables in its order: the parameters, then each free set-up block."""
        return [self.t_key, *self._s_keys.values()], [len(self.params), *[self._s_sizes[n] for n in self._s_keys]]

    def _add(self, rec: PoseData, m, f: float) -> None:
        """Add an accepted pose's factors (``m``: its measurement), its noise scaled by the factor ``f``."""
        import gtsam

        sig = self.sigmas
        i = rec.pose
        parts = m.parts
        if not m.n_rows:  # only contacts to a plane not started yet: kept pending
            self.setup.commit(m.setup)
            return
        now = self._running()  # the state before the pose: where new blocks' rows are linearised
        if self._in_tree >= self.window:  # the tree is full: its marginal starts the next one
            self._tree(now)
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        if self._in_tree == 0:
            if self._marginal is None:
                start = self.params.nominal()
                graph.add(fx.parameter_prior(self.t_key, start, self.prior_sigma))
                values.insert(self.t_key, start)
            else:
                x, cov = self._marginal
                keys, sizes = self._state_keys()
                if len(keys) == 1:
                    graph.add(gtsam.PriorFactorVector(self.t_key, x, gtsam.noiseModel.Gaussian.Covariance(cov)))
                else:
                    graph.add(joint_gaussian_factor(keys, sizes, x, cov))
                for key, a, b in zip(keys, np.cumsum([0, *sizes[:-1]]), np.cumsum(sizes)):
                    values.insert(key, x[a:b])
        joint_vars = bool(np.all(np.asarray(sig.joint) > 0))
        qargs = ({"q_key": fx.joint_key(i)} if joint_vars else {"q_fixed": rec.q}) | {"chain": self.model.chain}
        if joint_vars:
            graph.add(fx.joint_prior(fx.joint_key(i), rec.q, sig.joint * np.sqrt(f)))
            values.insert(fx.joint_key(i), rec.q.copy())
        # Each ball enters through its (fitted) centre with the fit's full covariance: to first
        # order the same information as its probe points around a centre variable, without the
        # stiff kinematic factor that would need relinearising at every step.
        if parts:
            cov = np.zeros((3 * len(parts), 3 * len(parts)))
            for k, (_, _, c) in enumerate(parts):
                cov[3 * k:3 * k + 3, 3 * k:3 * k + 3] = c * f
            graph.add(fx.ball_centres_factor(self.params.index, self.held, [o for o, _, _ in parts],
                                             [c for _, c, _ in parts], cov, t_key=self.t_key, **qargs))
        # The measurement types' own factors (fgcal.measurements), at the noise factor's sigmas.
        if rec.T is not None:
            graph.add(POSE.factor((rec.T,), self.params.index, self.held, POSE.sigma(sig) * np.sqrt(f),
                                  t_key=self.t_key, **qargs))
        for ball, length in rec.distances:
            graph.add(DISTANCE.factor((self.ds.tooling.balls[ball], length), self.params.index, self.held,
                                      DISTANCE.sigma(sig) * np.sqrt(f), t_key=self.t_key, **qargs))
        for kind, data, n in m.generic:  # the types taken through the protocol: their own factors
            sigma = np.asarray(kind.sigma(sig), dtype=float) * np.sqrt(f)
            for r in range(n):
                graph.add(kind.factor(tuple(np.asarray(d)[r] for d in data), self.params.index, self.held, sigma,
                                      t_key=self.t_key, **qargs))
        if m.setup is not None:
            self._add_setup(m, f, graph, values, qargs, now)
        self._keep.append(graph)
        self.isam.update(graph, values)
        self._linpoint = self.isam.getLinearizationPoint()  # keep a reference (DESIGN.md section 5)
        self._in_tree += 1
        self._est = None
        self._started = True
        self.setup.commit(m.setup)

    def _add_setup(self, m, f: float, graph, values, qargs, now) -> None:
        """The factors of a pose's set-up blocks: the blocks it starts (a variable each, with its
        prior), its contacts, the pending contacts it brings in (their joints constant, their noise
        folded in at the current estimate) and the known distances that enter."""
        import gtsam

        prop = m.setup
        layout = prop.layout
        k = 0
        for name in prop.started:
            fixture = layout.spec.fixtures[name]
            kind = BLOCK_KINDS[fixture.type]
            free = np.asarray(fixture.entries_free(kind.size), dtype=bool)
            size = int(free.sum())
            if fixture.fixed or not size:
                continue
            shape = _thresholds(kind, self._theta_threshold)[free]
            symbol = self._block_symbols.get((size, *shape))
            if symbol is None:
                raise FgcalError(f"set-up block {name}: the iSAM2 engine takes at most {len(BLOCK_SYMBOLS)} "
                                 "shapes of set-up blocks")
            key = gtsam.symbol(symbol, sum(1 for n in self._s_keys if self._s_symbols[n] == symbol))
            self._s_keys[name] = key
            self._s_sizes[name] = size
            self._s_symbols[name] = symbol
            values.insert(key, prop.mean[k:k + size])
            graph.add(gtsam.PriorFactorVector(key, prop.mean[k:k + size],
                                              gtsam.noiseModel.Diagonal.Sigmas(prop.sigma[k:k + size])))
            k += size
        x = prop.augment(*now)[0]
        chain = self.model.chain
        for _e, _J, Jq, group in prop.rows(self, x):
            if group is None:
                continue
            width = group.kind.width
            sigma = group.kind.sigma(self.sigmas)
            for r in range(group.n):
                row = tuple(np.asarray(d)[r:r + 1] for d in group.data)

                if group.current:
                    noise = fx.noise_model(sigma * np.sqrt(f))
                    q = {k_: v for k_, v in qargs.items() if k_ in ("q_key", "q_fixed")}
                else:  # a pending contact of another pose: its joints constant, their noise folded in
                    jq = Jq[r * width:(r + 1) * width]
                    Rj = np.diag(np.broadcast_to(np.asarray(self.sigmas.joint, dtype=float) ** 2, (len(group.q),)))
                    noise = gtsam.noiseModel.Gaussian.Covariance(f * (np.diag(sigma**2) + jq @ Rj @ jq.T))
                    q = {"q_fixed": group.q}
                graph.add(contact_factor(group.kind, row, layout, group.blocks[r], noise, self.params.index,
                                         self.held, chain, t_key=self.t_key, s_keys=self._s_keys, **q))
        for c in prop.constraints:
            graph.add(distance_constraint_factor(c, layout, self._s_keys))

    def restore(self, state, journal) -> None:
        """Rebuild the tree from the journalled poses ``journal`` ((record, entry) pairs, in order):
        each accepted pose is added again as it was taken, without its screening (``state`` unused)."""
        for rec, entry in journal:
            used, m = self._replayed(rec, entry)
            if m is not None:
                self._add(used, m, entry["f"])
                self._report(used, None, m, entry["f"])

    def finish(self) -> None:
        """The final smoothing (see :meth:`_Engine._smooth`); the incremental state stays as it was."""
        if self.seen and self._final is None:
            self._final = self._smooth()

    def _running(self):
        """The tree's ``(x, covariance)`` over the state (the parameters, then the free set-up
        blocks; kept until the next pose is added)."""
        if not self._started:
            return self.params.nominal(), np.diag(self.prior_sigma**2)
        if self._est is None:
            keys, _ = self._state_keys()
            if len(keys) == 1:
                self._est = (self.isam.calculateEstimateVector(self.t_key), self.isam.marginalCovariance(self.t_key))
            else:
                est = self.isam.calculateEstimate()
                self._est = (np.concatenate([est.atVector(k) for k in keys]),
                             self.isam.jointMarginalCovariance(keys).fullMatrix())
        return self._est

    def estimate(self):
        if self._final is not None:
            return self._final
        theta, cov = self._running()
        n = len(self.params)
        return theta[:n].copy(), cov[:n, :n].copy()

    def estimate_all(self):
        if self._final is not None and self._final_setup is not None:
            x, cov, layout = self._final_setup
            return x.copy(), cov.copy(), layout
        if self._final is not None and self.setup.layout is None:  # the final smoothing, as estimate() gives it
            return self._final[0].copy(), self._final[1].copy(), None
        x, cov = self._running()
        return x.copy(), cov.copy(), self.setup.layout


def _thresholds(kind, theta_threshold) -> np.ndarray:
    """A block kind's relinearisation thresholds (size,): angles and a camera's distortion (dimensionless)
    at the angles' threshold, lengths (mm) and a camera's focal lengths and centre (px) at the lengths'."""
    if kind.type == "point":  # a plane's: a point's x and y are relinearised more often (they are cheap)
        kind = BLOCK_KINDS["plane"]
    small = np.asarray(kind.angles, dtype=bool).copy()
    if kind.type == "camera":
        small[10:] = True  # k1, k2, p1, p2, k3
    return np.where(small, theta_threshold[1], theta_threshold[0])


def _block_shapes(ds) -> list:
    """``(kind, free entries)`` of every block shape the engine may start: each kind's whole block,
    and each of the dataset's blocks with only some entries free (a camera's known intrinsics)."""
    out = [(kind, np.ones(kind.size, dtype=bool)) for kind in BLOCK_KINDS.values()]
    for f in getattr(ds.setup, "fixtures", {}).values():
        kind = BLOCK_KINDS[f.type]
        free = np.asarray(f.entries_free(kind.size), dtype=bool)
        if free.any() and not free.all():
            out.insert(0, (kind, free))  # the dataset's own first: a symbol each, before the others'
    return out
