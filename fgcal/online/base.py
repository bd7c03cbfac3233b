"""What the online engines share: the screening of a pose (checks, mirror images, the innovation
gate at the estimated noise, single bad probe points), the journal of what was taken, and the final
smoothing by the batch solve. No I/O here."""
from __future__ import annotations

import logging
from typing import Any

import numpy as np

import factors as fx
from fgcal.errors import FgcalError
from fgcal.estimation.build import _sigmas
from fgcal.estimation.graph import Sigmas
from fgcal.estimation.holding import unseen_parameters
from fgcal.estimation.options import WEAK_PRIOR, CalibrationOptions
from fgcal.estimation.setup_params import is_setup_name
from fgcal.measurements.dataset import Dataset
from fgcal.online.centres import _good_centres, smoothing_fits
from fgcal.online.measurement import NoiseTracker, PoseMeasurement, UpdateReport
from fgcal.online.records import PoseData, _variant, records_dataset
from fgcal.online.setup_blocks import OnlineSetup
from fgcal.online.smoothing import batch_held, gauge_names, measured
from fgcal.robots.kinematics import chain_for, jacobians_one
from fgcal.robots.model import ParameterSet, RobotModel

__all__ = ["weak_prior"]

log = logging.getLogger(__name__)

WARM_START_SHARE = 0.9  # share of the poses seen the engine must have taken for its estimate to start the smoothing


def weak_prior(params: ParameterSet) -> np.ndarray:
    """Standard deviations (P,) of the weak prior, internal units."""
    return WEAK_PRIOR.sigmas(params.names)


class _Engine:
    def __init__(self, ds: Dataset, model: RobotModel, options: CalibrationOptions = CalibrationOptions(),
                 names=None):
        self.ds = ds
        self.model = model
        self.options = options
        # What the measurement type can never see (a reflector: the tool's orientation) is held from
        # the start, as the batch holds it; what these poses cannot separate besides, the final
        # smoothing decides by the batch's rule (:meth:`_smooth`). Given ``names`` are taken as they are.
        self.unseen: dict[str, list[str]] = {}
        # Unseen at the nominal geometry but not redundant at every geometry (a ball on the last
        # joint's axis at nominal): estimated with a prior of its typical deviation, as the batch does.
        self.typical_prior: dict[str, float] = {}
        # The gauge: with contacts to unknown fixtures only, nothing fixes the world frame and the
        # base is held at nominal, as the batch holds it (a stream, whose measurements are not
        # known yet, leaves it to the final smoothing).
        self.gauge: list[str] = []
        self._gauge_reasons: dict[str, str] = {}
        if names is None:
            names = model.parameters().names
            self._gauge_reasons = gauge_names(ds, model, names)
            self.gauge = list(self._gauge_reasons)
            names = [n for n in names if n not in self.gauge]
            self.unseen = unseen_parameters(model, names, measured(ds))
            if self.unseen and ds.n_poses and ds.levels():
                from fgcal.estimation.calibrate import split_held

                free = [n for n in names if n not in self.unseen]
                try:
                    self.unseen, self.typical_prior = split_held(model, free, self.unseen, ds, options)
                except FgcalError as exc:  # too few poses to tell: hold them, the final smoothing decides
                    log.info("weakly identifiable parameters not tested: %s", exc)
            names = [n for n in names if n not in self.unseen]
            if self.unseen:
                log.info("held from the start (never seen by these measurements): %s", ", ".join(self.unseen))
        self.final_held: dict[str, list[str]] = {}  # held by the final smoothing besides
        self.params = ParameterSet(model, tuple(names))
        self.index = self.params.index  # slot of each parameter (P,) (a property that builds it anew)
        self.is_angle = self.params.is_angle.astype(float)  # (P,) 1 for an angle, 0 for a length
        self.held = model.nominal.copy()
        self.sigmas: Sigmas = _sigmas(ds, model, options)
        self.prior_sigma = self._prior_sigma()
        self.n_accepted = 0
        self.noise = NoiseTracker()
        self.records: list[PoseData] = []  # the accepted poses (as taken: a bad probe point left out)
        self.seen: dict[int, PoseData] = {}  # every pose fed with measurements, for the final smoothing
        self._final = None
        self._final_setup = None  # (x, covariance, layout) of the final smoothing with set-up blocks
        self._kinematics: dict = {}
        self.setup = OnlineSetup(ds.setup)  # the set-up blocks in the state (fgcal.online.setup_blocks)

    def _prior_sigma(self) -> np.ndarray:
        """The weak prior, and the typical deviation where a parameter is weakly identifiable."""
        sd = weak_prior(self.params)
        for k, n in enumerate(self.params.names):
            if n in self.typical_prior:
                sd[k] = min(sd[k], self.typical_prior[n])
        return sd

    def _use_names(self, names) -> None:
        """Estimate ``names`` (a restored snapshot's); the others of the model's are held as unseen."""
        self.params = ParameterSet(self.model, tuple(names))
        self.index = self.params.index
        self.is_angle = self.params.is_angle.astype(float)
        self.prior_sigma = self._prior_sigma()
        self.unseen = {n: self.unseen.get(n, []) for n in self.model.parameters().names
                       if n not in names and n not in self.gauge}
        self._kinematics = {}

    def estimate(self):
        """``(theta (P,), covariance (P, P))`` in internal units (the robot's parameters)."""
        raise NotImplementedError

    def estimate_all(self):
        """``(x, covariance, layout)``: the robot's parameters then the set-up blocks' free entries
        of ``layout`` (None without set-up blocks), internal units."""
        raise NotImplementedError

    def _current(self) -> np.ndarray:
        raise NotImplementedError

    def _ball_kinematics(self, theta, q, offsets):
        """``(FK(theta, q) offsets (B, 3), J_theta (B, 3, P), J_q (B, 3, n))``, kept for the last few
        arguments: the prediction, the innovation and the filter's first linearisation share one."""
        key = (np.asarray(theta, dtype=float).tobytes(), q.tobytes(), offsets.tobytes())
        hit = self._kinematics.get(key)
        if hit is None:
            if len(self._kinematics) >= 8:
                self._kinematics.clear()
            hit = self._kinematics[key] = _ball_rows(theta, q, offsets, self.index, self.held, self.model.chain)
        return hit

    def _covariance(self) -> np.ndarray:
        """The parameters' covariance (P, P) now (before the next pose)."""
        raise NotImplementedError

    def _prediction(self, rec: PoseData, theta) -> tuple[dict, dict]:
        """Where ``theta`` puts each probed ball (ball -> xyz, mm), and the standard deviation of
        that prediction from the parameters' uncertainty (ball -> mm, the root of the trace)."""
        balls = [b for b, _ in rec.probes]
        if not balls:
            return {}, {}
        n_p = len(self.params)
        h, jt, _ = self._ball_kinematics(theta[:n_p], rec.q, np.array([self.ds.tooling.balls[b] for b in balls]))
        rows = jt.reshape(-1, jt.shape[-1])
        var = np.sum((rows @ self._covariance()[:n_p, :n_p]) * rows, axis=1).reshape(len(balls), -1).sum(axis=1)
        return dict(zip(balls, h)), dict(zip(balls, np.sqrt(np.maximum(var, 0.0))))

    def _measurement(self, rec: PoseData, flip=(), search: bool = False):
        """``(PoseMeasurement, None)`` or ``(None, reason)``, at the current estimate's prediction."""
        sig = self.sigmas
        parts, ambiguous = [], []
        if rec.probes:
            good, ambiguous, reason = _good_centres(rec, self.ds.tooling, self.ds.noise.cmm_sigma,
                                                    *self._prediction(rec, self._current()), flip=flip,
                                                    search=search)
            if good is None:
                return None, reason
            parts += [(self.ds.tooling.balls[b], c, cov) for b, c, cov in good]
        parts += [(self.ds.tooling.balls[b], xyz, np.eye(3) * sig.centre**2) for b, xyz in rec.centres]
        if not parts and rec.T is None and not rec.distances and not rec.contacts and not rec.generic \
                and not rec.block_rows:
            return None, "no measurements"
        taken = {k: v for k, v in (("flip", list(flip)), ("search", search)) if v}
        setup = self.setup.propose(self, rec, self._current()[:len(self.params)])
        return PoseMeasurement(self, rec, parts, ambiguous, taken, setup), None

    def _screen(self, rec: PoseData, theta, cov):
        """The pose's measurement if it passes the checks and the innovation gate at the current
        ``theta`` and its covariance ``cov``; else the variant (mirror images of ambiguous balls,
        then, as the batch solve excludes single probe points, one probe point left out) that
        passes with the smallest innovation. Returns ``(measurement, record used, noise factor,
        None)`` or ``(None, rec, f, reason)``."""
        if rec.measured():
            self.seen[rec.pose] = rec
            self._final = None

        def statistic(r, flip=(), search=False):
            m, why = self._measurement(r, flip, search)
            if m is None:
                return None, why, None
            x, C = m.augment(theta, cov)  # with the set-up blocks the pose starts
            e, H, R = m(x)
            PHt = C @ H.T
            m.gate = (x, C, PHt, H @ PHt)  # the filter's first iteration is at the same point (kalman)
            return m, None, (-e, m.gate[3], R)

        m, reason, vAR = statistic(rec)
        if m is not None and not m.n_rows:  # only contacts to a plane not started yet: kept pending
            self.noise.last = None
            return m, rec, self.noise.factor(), None
        f = self.noise.observe(*vAR) if vAR is not None else self.noise.factor()
        if m is not None:
            reason = NoiseTracker.implausible(vAR[0], vAR[1] + f * vAR[2])
            if reason is None:
                return m, rec, f, None
        # Where the prediction is still poor (early poses), a ball's mirror image may be the
        # consistent one: search them all, and try them; then single probe points left out. The
        # passing variant with the smallest innovation is taken.
        from itertools import combinations

        def best_of(variants):
            best = None
            for variant, flip, drop in variants:
                m_k, _, vAR_k = statistic(variant, flip, search=True)
                if m_k is None:
                    continue
                v, A, R = vAR_k
                d2 = float(v @ np.linalg.solve(A + f * R, v))
                if NoiseTracker.implausible(v, A + f * R) is None and (best is None or d2 < best[0]):
                    if drop is not None:
                        m_k.taken["drop"] = list(drop)
                    best = (d2, m_k, variant)
            return best

        def without_one(rec):
            for j, (_ball, pts) in enumerate(rec.probes):
                for k in range(len(pts) if len(pts) >= 4 else 0):
                    yield _variant(rec, {"drop": (j, k)}), (), (j, k)

        searched = self._measurement(rec, search=True)[0] if rec.probes else m
        amb = searched.ambiguous if searched is not None else []
        flips = ((rec, flip, None) for n in range(len(amb) + 1) for flip in combinations(amb, n))
        best = best_of(flips) or best_of(without_one(rec))
        if best is not None:
            return best[1], best[2], f, None
        return None, rec, f, reason

    def _report(self, rec: PoseData, reason=None, m: PoseMeasurement | None = None, f: float = 1.0) -> UpdateReport:
        """The pose's report (accepted when ``reason`` is None), with what a replay needs: the
        noise estimate the pose added, and for an accepted pose its noise factor and how it was taken."""
        journal: dict[str, Any] = {} if self.noise.last is None else {"noise": list(self.noise.last)}
        if reason is not None:
            return UpdateReport(rec.pose, False, reason, journal)
        self.records.append(rec)
        self.n_accepted += 1
        self._final = None
        journal["f"] = f
        if m is not None:
            journal.update(m.taken)
        return UpdateReport(rec.pose, True, "ok", journal)

    def _replayed(self, rec: PoseData, entry: dict, measure: bool = True):
        """Book-keeping of a journalled pose (noise, poses seen); for an accepted one, the record as
        taken and (``measure``) its measurement at the current estimate; ``(None, None)`` for a
        refused one."""
        self.noise.last = None
        if entry.get("noise"):
            self.noise.add(*entry["noise"])
        if rec.measured():
            self.seen[rec.pose] = rec
        self._final = None
        if not entry["accepted"]:
            return None, None
        used = _variant(rec, entry)
        if not measure:
            return used, None
        m, reason = self._measurement(used, entry.get("flip", ()), entry.get("search", False))
        if m is None:
            raise FgcalError(f"restoring pose {rec.pose}: {reason}")
        return used, m

    def _smooth(self):
        """The final smoothing: one batch solve over every pose fed (weak prior, noise estimated and
        gross errors excluded as in ``calibrate``), so that the end depends neither on the order
        the poses came in nor on what the running estimate refused on the way (a pose refused
        against an early, poor estimate is judged again, as the batch judges it). The solve starts
        from the running estimate when the engine took at least :data:`WARM_START_SHARE` of the
        poses (the same optimum as from the nominal start, in fewer steps). Of the engine's
        parameters it holds what the batch would hold on these poses (:func:`~fgcal.online.smoothing.batch_held`, kept
        in :attr:`final_held`) and estimates the rest. Returns ``(theta, covariance)`` in
        internal units over the engine's parameters (a held one at its value, with zero
        variance), or None while the poses cannot determine the parameters (the running estimate
        stands then)."""
        from dataclasses import replace

        from fgcal.estimation.calibrate import solution_covariance, solve_calibration

        ident = self.model.identifiable_names()
        names = list(self.params.names)
        seen = records_dataset(self.ds, list(self.seen.values()), self.model)
        # The running estimate is a start only when it fits what came: an engine that refused a
        # tenth of the poses (a ballbar's pivot unknown at first) may be far off, and a solve
        # started there can end in another minimum; the batch's own start is taken then. A plane's
        # tilts are about the normal fitted at the start: the batch's own start gives the batch's.
        trusted = self.n_accepted >= WARM_START_SHARE * len(self.seen) and not self.setup.has_references
        n_p = len(self.params)
        start = self.params.full(self._current()[:n_p], self.held) if trusted else None
        # a stream learns only now what fixes the frames and the scale (chosen among every parameter:
        # one held from the start is the scale's length still)
        reasons = gauge_names(seen, self.model, [*self.gauge, *names])
        self._gauge_reasons = {**reasons, **self._gauge_reasons}
        gauge = [n for n in reasons if n in names]
        # the sphere fits both builds of ``seen`` share (fgcal.estimation.build.build_graph), from the engine's own
        fits: dict = smoothing_fits(self.seen.values(), self.ds.tooling.radius)
        try:
            held, priors = batch_held(self, seen, [n for n in names if n not in gauge], fits)
            held = {**{n: [] for n in gauge}, **held}
            free = [n for n in names if n not in held]
            if start is not None and held:  # held where the batch holds them: at their start values
                idx = [self.model.slot(n) for n in held]
                start[idx] = self.held[idx]
            options = replace(self.options, prior="weak", extra=tuple(n for n in free if n not in ident),
                              exclude=tuple(n for n in ident if n not in free))
            sol = solve_calibration(seen, self.model, options, start=start, decide_held=False,
                                    priors={**self.typical_prior, **priors}, fits=fits)
            cov = solution_covariance(sol)
        except FgcalError as exc:  # too few poses for the batch solve yet: the running estimate stands
            log.info("final smoothing skipped: %s", exc)
            return None
        robot = [n for n in sol.graph.params.names if not is_setup_name(n)]
        if robot != free:
            raise FgcalError(f"final smoothing: the batch solve estimates {', '.join(sol.graph.params.names)}")
        self.final_held = held
        self._final_gauge = gauge
        self._final_refused = list(sol.refused)  # rows refused before the solve (a corner behind a camera)
        # In the engine's parameters: a held one at its value, with no variance.
        self._final_slots = sol.graph.params.full(sol.state.theta, sol.graph.held)
        self.final_pose_ids = [int(p) for p in sol.pose_ids]  # every pose the smoothing judged (and took)
        theta = self.params.take(self._final_slots)
        keep = [names.index(n) for n in free]
        full_cov = np.zeros((len(names), len(names)))
        full_cov[np.ix_(keep, keep)] = cov[:len(free), :len(free)]
        self._final_setup = None
        layout = sol.graph.setup
        if layout is not None:  # the set-up blocks as the batch has them (its order, its references)
            n_s = layout.n_free
            x = np.concatenate([theta, sol.state.theta[len(sol.state.theta) - n_s:]])
            at = keep + list(range(n_p, n_p + n_s))
            cov_all = np.zeros((n_p + n_s, n_p + n_s))
            cov_all[np.ix_(at, at)] = cov
            self._final_setup = (x, cov_all, layout)
        return theta, full_cov

    def held_info(self) -> list[dict]:
        """The held parameters as a batch result lists them: ``{"name", "value" (file units), "reason"}``,
        those never seen by the measurements first, then those the final smoothing held."""
        slots = self.held if getattr(self, "_final_slots", None) is None else self._final_slots
        values = self.model.slots_to_file_units(slots)
        gauge = list(dict.fromkeys([*self.gauge, *getattr(self, "_final_gauge", [])]))
        # every gauge name has its reason: set with it at the start or by the final smoothing
        out = [{"name": n, "value": float(values[self.model.slot(n)]), "reason": self._gauge_reasons[n]}
               for n in gauge]
        for n, partners in (*self.unseen.items(), *self.final_held.items()):
            if n in gauge:
                continue
            reason = ("cannot be separated from " + ", ".join(partners)) if partners else "no data constrains it"
            out.append({"name": n, "value": float(values[self.model.slot(n)]), "reason": reason})
        return out

    def setup_info(self) -> dict:
        """The result's ``setup`` section, as the batch writes it (``{}`` without set-up blocks)."""
        from fgcal.estimation.gauge import GAUGE_REASON

        x, _, layout = self.estimate_all()
        if layout is None:
            return {}
        out = {**layout.spec.to_dict(), "estimated": layout.describe(layout.full(x[len(self.params):]))}
        if any(h["reason"] == GAUGE_REASON for h in self.held_info()):
            out["gauge"] = GAUGE_REASON
        if self._final is not None and getattr(self, "_final_refused", None):  # named, as the batch names them
            out["refused"] = list(self._final_refused)
        return out


def _ball_rows(theta, q, offsets, index, held, chain):
    """:func:`factors.pose_ball_centres_error` at zero centres, ``(FK(theta, q) offsets (B, 3),
    J_theta (B, 3, P), J_q (B, 3, n))``, from the single-pose kinematics directly: the same values,
    without the checks of a general call (read-only arrays)."""
    x = fx.slots_of(theta, index, held)
    jac = jacobians_one(chain_for(x, chain), x, q, offsets)
    return jac.points[0], jac.point_slots[0][:, :, index], jac.point_joints[0]
