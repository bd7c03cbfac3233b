"""Validation that respects time: later poses predicted from earlier ones, drift named, and a model
choice that does not trade the mean for the maximum.

Random (and blocked) folds predict each pose from poses on both sides of it in time: on a session
whose error drifts they are optimistic (on a UR10 tracker series 0.10 mm cross-validated against
0.25-0.30 mm at the later poses). :func:`forward_errors` fits each model to the first
:data:`FORWARD_FRACTION` of the training poses in time (pose id) order and predicts the rest, on the
linearised problem of :func:`fgcal.estimation.cross_validation.cv_problem`; :func:`drift_sentences`
compares that with the random folds' error at the same poses; :func:`recommend` chooses a model
by the errors that predict new poses, among the models whose largest error is no worse than
each simpler model's. No I/O here.
"""
from __future__ import annotations

import re

import numpy as np

from fgcal.estimation.joint_errors import JointErrorSpec, ModelKind

__all__ = ["FORWARD_FRACTION", "MAX_TOLERANCE", "FoldSums", "drift_sentences", "forward_errors", "forward_errors_many", "forward_sums",
           "harmonic", "later_poses", "model_columns", "recommend"]

FORWARD_FRACTION = 0.6  # the earlier share of the training poses that predicts the rest
DRIFT_RATIO = 1.25  # later poses predicted this much worse than interleaved ones (and beyond noise): drift
MAX_TOLERANCE = 0.05  # a largest error within this share of a simpler model's counts as no worse
_CHUNK = 2000  # poses per block of work in the fold sums (bounds the temporaries)
_PREDICT_CHUNK = 256  # poses per product of the held-out predictions (a block that stays in cache)


def harmonic(name: str) -> int:
    """The harmonic number ending a map parameter's name (``map.j2.c3`` -> 3)."""
    found = re.search(r"(\d+)$", name)
    return int(found.group(1)) if found else 0


class FoldSums:
    """Normal equations per fold, over all columns, so that any column subset is cheap."""

    def __init__(self, prob, fold: np.ndarray, k: int):  # prob: a cross_validation.CVProblem
        self.prob, self.fold, self.k = prob, fold, k
        P = prob.J.shape[2]
        self.A = np.zeros((k, P, P))
        self.b = np.zeros((k, P))
        # In chunks of poses, each row once: no copy of a fold's Jacobian (the cost is linear in the poses).
        for lo in range(0, len(fold), _CHUNK):
            c = slice(lo, lo + _CHUNK)
            J, r, fc = prob.J[c], prob.r[c], fold[c]
            for f in np.unique(fc):
                Jf = J[fc == f].reshape(-1, P)  # a chunk's share of the fold: a bounded copy
                self.A[f] += Jf.T @ Jf
                self.b[f] += Jf.T @ r[fc == f].reshape(-1)
        self.A_all, self.b_all = self.A.sum(0), self.b.sum(0)
        # each pose's rows that the error is measured on (the unit's scale applied)
        self._metric = np.take_along_axis(prob.r, prob.metric_rows, axis=1) * prob.metric_scale
        first = prob.metric_rows[:, :1]
        same = bool(len(first)) and np.all(prob.metric_rows == first[0] + np.arange(prob.metric_rows.shape[1]))
        self._rows = slice(int(first[0, 0]), int(first[0, 0]) + prob.metric_rows.shape[1]) if same else None

    def _metric_jacobian(self, c: slice) -> np.ndarray:
        """(n, 3, P) the metric rows' Jacobian of the poses ``c``: a view where every pose has them at
        the same rows, else gathered."""
        J = self.prob.J[c]
        if self._rows is not None:
            return J[:, self._rows]
        return np.take_along_axis(J, self.prob.metric_rows[c][:, :, None], axis=1)

    def fit_without(self, f: int, cols, prior_sigma) -> np.ndarray:
        """The increment (len(cols),) fitted to every fold but ``f``, priors of ``prior_sigma`` about zero."""
        cols = np.asarray(cols)
        lam = np.where(np.isfinite(prior_sigma), 1.0 / np.asarray(prior_sigma, dtype=float) ** 2, 0.0)
        A = (self.A_all - self.A[f])[np.ix_(cols, cols)]
        b = (self.b_all - self.b[f])[cols]
        d = np.sqrt(np.maximum(np.diag(A), 1e-300))
        with np.errstate(over="ignore"):  # a column no pose sees, under a prior: an infinite diagonal, its fit 0
            As = A / np.outer(d, d) + np.diag(lam / d**2) + 1e-10 * np.eye(len(cols))
        return -np.linalg.solve(As, b / d) / d

    def held_out_errors(self, cols, prior_sigma) -> np.ndarray:
        """(N,) error of each pose predicted by the fit to the other folds (columns ``cols``)."""
        return self.held_out_errors_many([(cols, prior_sigma)])[0]

    def held_out_errors_many(self, candidates) -> list[np.ndarray]:
        """:meth:`held_out_errors` of each ``(cols, prior_sigma)`` of ``candidates``, in one pass over
        the Jacobian: each chunk of poses times every candidate's fold fits as one matrix product (the
        pass reads 80 MB at 8,400 poses of a 392-column map: one per candidate was bound by that read,
        10 ms each; a grid of 20 in one pass is 4x faster), each pose then taking its own fold's
        prediction."""
        prob = self.prob
        P = prob.J.shape[2]
        X = np.zeros((P, len(candidates), self.k))  # each candidate's fold fits over all columns (zero outside its cols)
        for j, (cols, prior_sigma) in enumerate(candidates):
            cols = np.asarray(cols)
            for f in range(self.k):
                X[cols, j, f] = self.fit_without(f, cols, prior_sigma)
        X2 = X.reshape(P, -1)
        pos = np.repeat(self._metric[None], len(candidates), axis=0)  # (C, N, 3)
        for lo in range(0, len(self.fold), _PREDICT_CHUNK):
            c = slice(lo, lo + _PREDICT_CHUNK)
            Jm = self._metric_jacobian(c)  # (n, 3, P)
            n, w = Jm.shape[:2]
            pred = (Jm.reshape(-1, P) @ X2).reshape(n, w, len(candidates), self.k)
            pos[:, c] += pred[np.arange(n), :, :, self.fold[c]].transpose(2, 0, 1) * prob.metric_scale
        return list(np.linalg.norm(pos, axis=2))


def model_columns(prob, kind: str, spec_kw: dict | None = None) -> tuple[list, list]:
    """Columns of ``prob`` (a :class:`~fgcal.estimation.cross_validation.CVProblem`) and their prior sigmas
    for the model ``kind`` (the map's ``harmonics`` and ``map_sigma`` in ``spec_kw``)."""
    geo = list(range(prob.n_geometric))
    cols, sig = geo, [np.inf] * len(geo)
    if ModelKind(kind).order >= ModelKind.COMPLIANCE.order:
        comp = [i for i, n in enumerate(prob.names) if n.endswith(".compliance")]
        cols, sig = cols + comp, sig + [JointErrorSpec().compliance_sigma] * len(comp)
    if ModelKind(kind) is ModelKind.COMPLIANCE_MAP and spec_kw:
        mp = [i for i, n in enumerate(prob.names) if n.startswith("map.") and harmonic(n) <= spec_kw["harmonics"]]
        cols, sig = cols + mp, sig + [float(spec_kw["map_sigma"])] * len(mp)
    return cols, sig


def later_poses(pose_ids, fraction: float = FORWARD_FRACTION) -> np.ndarray:
    """Mask (N,) of the poses after the first ``fraction`` in pose id (time) order."""
    rank = np.argsort(np.argsort(np.asarray(pose_ids), kind="stable"), kind="stable")
    return rank >= int(np.ceil(fraction * len(rank)))


def forward_errors(prob, cols, prior_sigma, later, sums: FoldSums | None = None) -> np.ndarray:
    """(N,) errors; at the ``later`` poses each predicted by the fit to the earlier ones, NaN elsewhere.

    ``sums``: the fold sums of ``later`` (:func:`forward_sums`), shared by every model compared
    (forming them is the cost: a pass over the whole Jacobian)."""
    return forward_errors_many(prob, [(cols, prior_sigma)], later, sums)[0]


def forward_errors_many(prob, candidates, later, sums: FoldSums | None = None) -> list[np.ndarray]:
    """:func:`forward_errors` of each ``(cols, prior_sigma)`` of ``candidates``, in one pass over the
    Jacobian (:meth:`FoldSums.held_out_errors_many`)."""
    if sums is None:
        sums = forward_sums(prob, later)
    return [np.where(later, e, np.nan) for e in sums.held_out_errors_many(candidates)]


def forward_sums(prob, later) -> FoldSums:
    """The normal equations of the earlier (fold 0, fitted) and the ``later`` poses (fold 1, predicted)."""
    return FoldSums(prob, np.asarray(later, dtype=int), 2)


def drift_sentences(forward: dict, interleaved: dict, later, unit: str = "mm",
                    fraction: float = FORWARD_FRACTION) -> list[str]:
    """Whether a model's error at later poses (``forward[model]`` (N,), NaN at the earlier poses)
    exceeds that of the same poses predicted from interleaved folds (``interleaved[model]`` (N,)),
    beyond noise and by :data:`DRIFT_RATIO`: a drift, said for the model it shows most in, with
    how much; an empty list where no model shows one."""
    worst = None
    for kind in forward:
        f, c = np.asarray(forward[kind])[later], np.asarray(interleaved[kind])[later]
        if len(f) < 3:
            return []
        d = f - c
        se = d.std(ddof=1) / np.sqrt(len(d))
        if d.mean() > 2 * se and f.mean() > DRIFT_RATIO * c.mean():
            if worst is None or f.mean() / c.mean() > worst[1].mean() / worst[2].mean():
                worst = (kind, f, c)
    if worst is None:
        return []
    kind, f, c = worst
    change = float(np.sqrt(max(f.mean() ** 2 - c.mean() ** 2, 0.0)))
    return [f"the data drift: fitted to the first {fraction:.0%} of the training poses in time, the {kind} "
            f"model predicts the {len(f)} later ones at {f.mean():.3g} {unit} mean error (max {f.max():.3g}), "
            f"against {c.mean():.3g} {unit} for the same poses predicted from interleaved folds: the robot or the "
            f"set-up changed by about {change:.2g} {unit} during the session. Expect errors like the later ones "
            "at poses measured after the calibration; the models are compared on them"]


def recommend(errors: dict, what: str = "cross-validated error") -> tuple[str, str]:
    """``(model, reason)``: the simplest model within noise (two standard errors of the per-pose
    difference) of the best mean error among the admissible ones, a model being admissible when its
    largest error is no worse (to :data:`MAX_TOLERANCE`) than every simpler model's: a lower mean
    bought with a worse maximum is not an improvement. ``errors``: model -> per-pose errors (N,),
    the same poses for every model; ``what`` names them in the reason."""
    kinds = [k for k in (m.value for m in ModelKind) if k in errors]
    admissible: list[tuple[str, list]] = []
    refused: list[tuple[str, list]] = []
    for i, k in enumerate(kinds):
        worse = [j for j in kinds[:i] if errors[k].max() > (1 + MAX_TOLERANCE) * errors[j].max()]
        (refused if worse else admissible).append((k, worse))
    best = min((k for k, _ in admissible), key=lambda k: errors[k].mean())
    note = "".join(f"; {k} not chosen: its largest error {errors[k].max():.3g} is above {w[0]}'s "
                   f"{errors[w[0]].max():.3g}" for k, w in refused)
    for k, _ in admissible:
        d = errors[k] - errors[best]
        se = d.std(ddof=1) / np.sqrt(len(d)) if len(d) > 1 else 0.0
        if d.mean() <= 2 * se:
            why = "the best" if k == best else (f"within noise of {best} ({d.mean():.3g} above, standard error "
                                                f"{se:.2g})")
            return k, f"{k}: the simplest model within noise of the best {what} ({why}){note}"
    return best, best + note
