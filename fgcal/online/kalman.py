"""The Kalman engines over the parameter vector: an iterated EKF (numpy) and filterpy's UKF."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgcal.errors import FgcalError
from fgcal.estimation.options import CalibrationOptions
from fgcal.online.base import _Engine
from fgcal.online.measurement import NoiseTracker, PoseMeasurement, UpdateReport
from fgcal.online.records import PoseData

__all__ = ["LINEAR_ENOUGH", "FilterState", "KalmanEngine"]

# A step whose second-order effect on the measurement is below this share of its noise is not
# relinearised: the relinearised update would move the estimate by about as little, in posterior
# sigmas (the whitened error bounds the change; on the PUMA bench it stayed within 1e-4 sigma).
LINEAR_ENOUGH = 1e-3


@dataclass
class FilterState:
    """A filter's state: the parameters ``x`` (P,), their covariance ``P`` (P, P) and the
    random-walk process noise ``Q`` (P, P) added before each pose (internal units)."""

    x: np.ndarray
    P: np.ndarray
    Q: np.ndarray


class KalmanEngine(_Engine):
    """A Kalman filter over the parameter vector: iterated EKF (``ekf``, its update in numpy in
    filterpy's Joseph form: filterpy's import alone costs more than a thousand updates) or
    filterpy's unscented filter (``ukf``)."""

    snapshots = True  # the state is small: a resume restores the last snapshot and replays after it
    share_gate = True  # the update's first iteration takes the gate's products (False: formed again)
    linear_enough = LINEAR_ENOUGH  # 0: relinearise by the step's size alone

    def __init__(self, ds, model, options=CalibrationOptions(), names=None, kind="ekf", drift=None,
                 max_iterations=20):
        super().__init__(ds, model, options, names)
        if kind not in ("ekf", "ukf"):
            raise FgcalError(f"unknown filter {kind!r} (ekf, ukf)")
        self.kind = kind
        # drift: (P,) per estimated parameter, or per parameter of model.parameters() (the held dropped)
        drift = np.zeros(len(self.params)) if drift is None else np.asarray(drift, dtype=float)
        every = model.parameters().names
        if drift.shape == (len(every),) and len(every) != len(self.params):
            drift = drift[[every.index(n) for n in self.params.names]]
        self._drift = dict(zip(self.params.names, drift.tolist()))
        self.kf = FilterState(self.params.nominal().copy(), np.diag(self.prior_sigma**2), np.diag(drift**2))
        self.max_iterations = max_iterations
        self._ukf = None

    def _current(self) -> np.ndarray:
        return self.kf.x

    def _covariance(self) -> np.ndarray:
        return self.kf.P + self.kf.Q

    def update(self, rec: PoseData) -> UpdateReport:
        x0 = self.kf.x.copy()
        P0 = self.kf.P + self.kf.Q  # random-walk prediction
        m, used, f, reason = self._screen(rec, x0, P0)  # f: the measurement noise estimated so far
        if m is None:
            return self._report(rec, reason)
        # the set-up blocks the pose starts, at their starts and priors (as the gate had them)
        x0, P0 = m.gate[:2] if m.gate is not None else m.augment(x0, P0)
        if not m.n_rows:
            pass  # contacts kept pending (a plane not started yet): nothing to update
        elif self.kind == "ekf":
            reason = self._iterated_update(m, x0, P0, f, m.gate[2:] if self.share_gate and m.gate else None)
            if reason:
                return self._report(rec, reason)
        else:
            self._unscented_update(m, x0, P0, f)
        self._commit(m)
        return self._report(used, None, m, f)

    def _commit(self, m: PoseMeasurement) -> None:
        """Take the set-up blocks of an accepted pose: the state grows by those it starts (no drift)."""
        self.setup.commit(m.setup)
        n, k = len(self.kf.Q), len(self.kf.x)
        if k > n:
            Q = np.zeros((k, k))
            Q[:n, :n] = self.kf.Q
            self.kf.Q = Q

    def _iterated_update(self, m: PoseMeasurement, x0, P0, f: float, gate=None) -> str | None:
        """The iterated EKF's update of ``(x0, P0)`` by ``m`` at noise factor ``f``; a reason when
        the innovation at the iterated point is implausible (the state is then untouched).

        ``gate``: ``(P0 H', H P0 H')`` at ``x0`` as the innovation gate formed them (the first
        iteration is at ``x0``: the same products), or None to form them here."""
        x = x0.copy()
        sigma0 = np.sqrt(np.diag(P0))
        for it in range(self.max_iterations):
            e, H, R = m(x)
            if it == 0 and gate is not None:  # at x0: what the gate formed, and the innovation it judged
                innovation = -e
                PHt, HPHt = gate
                S = HPHt + f * R
            else:
                innovation = -e - H @ (x0 - x)
                PHt = P0 @ H.T
                S = H @ PHt + f * R
            K = np.linalg.solve(S, PHt.T).T
            x_new = x0 + K @ innovation
            # Relinearise while the step is a noticeable fraction of the prior's spread (the error
            # of a linearisation that far off is second order, ~1e-2 of a sigma) and bends the
            # measurement noticeably: a step of a thousandth of the spread, once the prior is
            # tight, can be a tenth of a sigma and still move the predictions linearly.
            if np.max(np.abs(x_new - x) / sigma0) < 0.1 or m.bend(x_new - x, H, R) < self.linear_enough:
                break
            x = x_new
        # At x0 the gate has judged this innovation with this S (the same f); else judged here.
        reason = None if it == 0 and gate is not None else NoiseTracker.implausible(innovation, S)
        if reason:
            return reason
        # Joseph form, linearised at the iterated point: (I - K H) P0 (I - K H)' + K f R K', for any
        # gain K, symmetric and positive whatever the rounding; its products by the thin factors
        # (P0 H' is PHt: (I - K H) P0 = P0 - K PHt'), not by the (P, P) I - K H.
        left = P0 - K @ PHt.T
        self.kf.x = x0 + K @ innovation
        self.kf.P = left - (left @ H.T) @ K.T + (K @ (f * R)) @ K.T
        return None

    def _unscented_update(self, m: PoseMeasurement, x0, P0, f: float) -> None:
        from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

        e0, _, R = m(x0)
        n = len(x0)
        if self._ukf is None or self._ukf._dim_x != n:  # one filter, reused: each pose brings its own hx, R and size
            points = MerweScaledSigmaPoints(n, alpha=0.1, beta=2.0, kappa=3.0 - n)
            self._ukf = UnscentedKalmanFilter(dim_x=n, dim_z=len(e0), dt=1.0, fx=lambda s, dt: s,
                                              hx=None, points=points)
        ukf = self._ukf
        ukf.x, ukf.P, ukf.Q = x0.copy(), P0.copy(), np.zeros((n, n))
        ukf.predict()
        ukf.update(np.zeros(len(e0)), R=f * R, hx=lambda s: m(s)[0])
        self.kf.x, self.kf.P = ukf.x.copy(), 0.5 * (ukf.P + ukf.P.T)

    def finish(self) -> None:
        """The final smoothing (see :meth:`_Engine._smooth`) when the parameters do not drift: the
        filter's state becomes the smoothed one, whatever the order the poses came in."""
        if self.seen and self._final is None and not np.any(self.kf.Q):
            self._final = self._smooth()
            if self._final is not None and self._final_setup is not None:  # the batch's blocks replace ours
                x, P, layout = self._final_setup
                self.kf.x, self.kf.P, self.kf.Q = x.copy(), P.copy(), np.zeros_like(P)
                self.setup.adopt(layout)
            elif self._final is not None:
                self.kf.x, self.kf.P = self._final[0].copy(), self._final[1].copy()

    def estimate(self):
        n = len(self.params)
        return self.kf.x[:n].copy(), self.kf.P[:n, :n].copy()

    def estimate_all(self):
        return self.kf.x.copy(), self.kf.P.copy(), self.setup.layout

    def state(self) -> dict:
        """The filter's state (a snapshot: its size does not grow with the poses, only with the set-up blocks)."""
        return {"x": self.kf.x.tolist(), "P": self.kf.P.tolist(), "names": list(self.params.names),
                "setup": self.setup.to_json()}

    def restore(self, state: dict, journal) -> None:
        """The state of a snapshot taken after the journalled poses ``journal`` ((record, entry)
        pairs, in order), whose book-keeping (noise, poses seen and taken) is rebuilt from them."""
        for rec, entry in journal:
            used, _ = self._replayed(rec, entry, measure=False)
            if used is not None:
                self._report(used, None, None, entry["f"])
        if state.get("names", list(self.params.names)) != list(self.params.names):
            # held from the start on what the dataset measured then (a session begun on an empty dataset)
            self._use_names(state["names"])
            self.kf.Q = np.diag(np.array([self._drift.get(n, 0.0) for n in self.params.names]) ** 2)
        self.kf.x = np.array(state["x"], dtype=float)
        self.kf.P = np.array(state["P"], dtype=float)
        self.setup.restore(state.get("setup", {}))
        n, k = len(self.kf.Q), len(self.kf.x)
        if k > n:  # the set-up blocks have no drift
            Q = np.zeros((k, k))
            Q[:n, :n] = self.kf.Q
            self.kf.Q = Q
