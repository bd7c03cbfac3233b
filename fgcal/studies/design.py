"""Which poses to measure: observability indices and optimal experiment design.

The information a pose brings about the parameters is the estimator's own (built from its
measurement definitions, :mod:`fgcal.studies.design_info`): probed balls, ball centres or tracker
reflectors, full poses, with the joint readings' noise, which moves all of a pose's measurements
together and is what makes some poses far less informative than their Jacobian alone suggests.
Indices on the information scaled by the expected parameter errors:

* O1 (Borm & Menq): ``(s_1 ... s_L)^(1/L) / sqrt(m)``; O2: ``s_min / s_max``; O3: ``s_min``;
  O4 (noise amplification): ``s_min^2 / s_max``; O5: ``1 / sum(1 / s_i)``;
* ``pred``: the predicted position error RMS (mm) at verification poses drawn like the
  candidates, ``sqrt(trace(W Sigma))``: the accuracy the calibration is for (I-optimality).
  ``Sigma`` is the inverse information, or, when the data's error is not what the estimator
  weighs it by (:func:`fgcal.studies.design_info.information_and_middle`), the sandwich
  ``M^-1 B M^-1``; +inf where the plan does not determine what ``W`` sees, decided in units of
  the expected parameter errors (:mod:`fgcal.studies.design_predict`).

Plans are chosen from a candidate pool by a greedy start and the DETMAX exchange (Mitchell
1974: add the best candidate, remove the worst design point, until nothing improves). No I/O.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from fgcal.errors import FgcalError
from fgcal.estimation.graph import Sigmas
from fgcal.estimation.holding import _hold_order
from fgcal.measurements.dataset import Noise
from fgcal.robots.deviations import Deviations
from fgcal.robots.identifiability import analyse_information
from fgcal.robots.model import ParameterSet, RobotModel
from fgcal.studies.design_info import Layout, information, information_and_middle, layout_from_access
from fgcal.studies.design_predict import low_rank, marginal, marginal_middle, pred_update, predicted_mse, predicted_rms
from fgcal.studies.plans import PLAN_MARGIN_DEG, PLAN_MARGIN_MM

__all__ = [
    "INDICES",
    "Candidates",
    "Design",
    "candidate_pool",
    "design_plan",
    "indices",
    "marginal",
    "pose_information",
    "predicted_rms",
    "random_design_values",
    "verification_weight",
]

log = logging.getLogger(__name__)

INDICES = ("O1", "O2", "O3", "O4", "O5", "pred")


def pose_information(model: RobotModel, q, noise: Noise, params: ParameterSet | None = None, slots=None,
                     n_balls: int = 3, probes_per_ball: int = 4, levels=("probes",)):
    """Per-pose information about the parameters, ``(N, P, P)`` (internal units).

    The ``n_balls`` most accessible balls of each pose are measured at ``levels`` (see
    :mod:`fgcal.studies.design_info`). Also returns ``usable`` (N,) bool: the pose gives measurements.
    """
    layout = layout_from_access(model, q, levels, n_balls, slots, probes_per_ball)
    return information(model, q, layout, noise, params, slots), layout.usable()


def verification_weight(model: RobotModel, q_verify, params: ParameterSet | None = None, slots=None) -> np.ndarray:
    """``W`` (P, P) with ``trace(W Sigma)`` the mean squared tool-position error at ``q_verify``."""
    params = params or model.parameters()
    x = model.nominal if slots is None else np.asarray(slots, dtype=float)
    J = model.chain.jacobians(x, np.atleast_2d(q_verify)).pose_slots[:, :3][:, :, params.index]
    return np.einsum("nrp,nrq->pq", J, J) / len(J)


def indices(info, m: int, scale, W=None, middle=None) -> dict[str, float]:
    """O1-O5 of ``info`` (P, P) scaled by the expected parameter errors ``scale`` (P,), and ``pred``
    (with the sandwich's ``middle`` when given)."""
    s = np.sqrt(np.clip(np.linalg.eigvalsh(info * np.outer(scale, scale)), 0.0, None))[::-1]
    out = {"O1": float(np.exp(np.mean(np.log(np.maximum(s, 1e-300)))) / np.sqrt(m)),
           "O2": float(s[-1] / s[0]) if s[0] > 0 else 0.0, "O3": float(s[-1]),
           "O4": float(s[-1] ** 2 / s[0]) if s[0] > 0 else 0.0,
           "O5": float(1.0 / np.sum(1.0 / np.maximum(s, 1e-300)))}
    if W is not None:
        out["pred"] = predicted_rms(info, W, middle, scale)
    return out


def _scores(infos, scale, index: str, W=None, middles=None, strict: bool = True) -> np.ndarray:
    """Criterion (larger is better) for a batch of information matrices (K, P, P) (and sandwich
    middles, for ``pred``: minus the predicted RMS, -inf where the plan cannot predict it, or with
    ``strict`` False the search's finite score, :func:`fgcal.studies.design_predict.predicted_mse`);
    never NaN."""
    if index == "pred":
        return -np.sqrt(predicted_mse(infos, W, scale, middles, strict))
    s = np.sqrt(np.clip(np.linalg.eigvalsh(infos * np.outer(scale, scale)[None]), 1e-300, None))
    if index == "O1":
        out = np.mean(np.log(s), axis=1)  # log of det^(1/L): same order, no overflow
    elif index == "O2":
        out = s[:, 0] / s[:, -1]
    elif index == "O3":
        out = s[:, 0]
    elif index == "O4":
        out = s[:, 0] ** 2 / s[:, -1]
    elif index == "O5":
        out = 1.0 / np.sum(1.0 / s, axis=1)
    else:
        raise FgcalError(f"unknown index {index!r} ({', '.join(INDICES)})")
    return np.where(np.isfinite(out), out, -np.inf)


@dataclass
class Design:
    """A chosen plan: joint sets (rad), their indices in the pool, and its index values."""

    q: np.ndarray
    chosen: np.ndarray
    values: dict[str, float]
    index: str
    iterations: int


def candidate_pool(model: RobotModel, n: int, rng: np.random.Generator, n_balls: int = 3, levels=("probes",),
                   max_tries: int = 200_000) -> np.ndarray:
    """``n`` random joint sets (n, joints) rad that the instrument measures on the nominal robot,
    with the planning margins (the actual robot is a few mm off).

    At most ``max_tries`` joint sets are drawn; :class:`FgcalError` says so when too few qualify.
    """
    lo, hi = model.joint_limits[:, 0], model.joint_limits[:, 1]
    n_balls = min(n_balls, len(model.tooling.balls)) if model.tooling is not None else 0
    out, found, tries = [], 0, 0
    while found < n:
        if tries >= max_tries:
            raise FgcalError(f"only {found} of {tries} random joint sets of {model.name} let the instrument measure "
                             f"{n_balls} ball(s) ({', '.join(levels)}); {n} candidates asked for: enlarge the "
                             "measuring volume or ask for fewer candidates")
        q = rng.uniform(lo, hi, size=(4 * n, len(lo)))
        tries += len(q)
        good = q[layout_from_access(model, q, levels, n_balls, margin_mm=PLAN_MARGIN_MM,
                                    margin_deg=PLAN_MARGIN_DEG).usable()]
        out.append(good)
        found += len(good)
    return np.vstack(out)[:n]


@dataclass
class Candidates:
    """A candidate pool with each pose's information and the verification weight.

    ``names`` are the parameters designed for: those of the model that the whole pool can
    identify; ``dropped`` names the others (with the parameters each is confused with).
    ``middle`` (N, P, P), when the data's error is not the estimator's weights, the candidates'
    sandwich middles (:func:`fgcal.studies.design_info.information_and_middle`).

    With set-up blocks (contacts: ``layout.setup``), ``info`` and ``middle`` are over the
    parameters and the ``n_setup`` free set-up entries after them, ``prior`` (P + S, P + S) the
    information every plan has about the blocks (their priors, the known distances), ``W`` is
    zero over the set-up entries and ``scale`` one: ``pred`` is the accuracy with the blocks
    marginalised (the Schur complement over their columns), the indices O1-O5 are of that
    marginal information.
    """

    q: np.ndarray
    info: np.ndarray
    usable: np.ndarray
    W: np.ndarray
    scale: np.ndarray
    names: tuple = ()
    dropped: dict = field(default_factory=dict)
    middle: np.ndarray | None = None
    n_setup: int = 0
    prior: np.ndarray | None = None

    @classmethod
    def build(cls, model: RobotModel, candidates, noise: Noise, q_verify=None, deviations: Deviations = Deviations(),
              layout: Layout | None = None, params: ParameterSet | None = None, slots=None,
              sigmas: Sigmas | None = None, actual: Sigmas | None = None, joint_error=0.0, weight=None):
        """Information of every candidate (measured as ``layout`` says; by default the three most
        accessible balls, probed) and the weight of the accuracy at ``q_verify``, linearised at
        ``slots`` (the nominal by default); ``sigmas`` (the graph's noise) replaces ``noise``'s
        declared values, for example with those estimated from a dataset. ``actual`` (the data's
        noise) and ``joint_error`` (rad, an unmodelled joint-space error) make ``pred`` the
        sandwich covariance of the estimator at ``sigmas`` under that error. ``weight`` (P, P) over
        ``params``, when given, is the verification weight instead of the tool positions at
        ``q_verify`` (for contacts, the consistency's: :mod:`fgcal.studies.design_consistency`)."""
        params = params or model.parameters()
        q = np.atleast_2d(np.asarray(candidates, dtype=float))
        layout = layout if layout is not None else layout_from_access(model, q, ("probes",))
        usable = layout.usable()
        if not usable.any():
            raise FgcalError(f"none of the {len(q)} candidate poses gives a measurement "
                             f"({', '.join(layout.levels)}): no ball is accessible at any of them")
        middle = None
        if actual is not None or np.any(np.asarray(joint_error) > 0):
            info, middle = information_and_middle(model, q, layout, noise, params, slots, sigmas, actual, joint_error)
        else:
            info = information(model, q, layout, noise, params, slots, sigmas)
        W = (verification_weight(model, q[usable] if q_verify is None else q_verify, params, slots)
             if weight is None else np.asarray(weight, dtype=float))
        scale = deviations.sigmas(params.names)
        S, P = layout.n_setup, len(params.names)
        prior = np.zeros((P + S, P + S))
        if S and layout.setup is not None:
            prior[P:, P:] = layout.setup.prior_information(layout.setup.start)
        # Of parameters the pool confounds, the estimator holds the tool's angles first: so does the design.
        order = _hold_order(params.names)
        whole = marginal(info[usable].sum(axis=0) + prior, S)
        dropped = analyse_information(whole[np.ix_(order, order)], [params.names[i] for i in order]).redundant
        keep = np.array([n not in dropped for n in params.names])
        if dropped:
            log.warning("not identifiable from any of these %d candidates, so not designed for: %s", usable.sum(),
                        ", ".join(dropped))
        W, scale = W[keep][:, keep], scale[keep]
        if S or dropped:
            keep = np.concatenate([keep, np.ones(S, dtype=bool)])
            info, prior = info[:, keep][:, :, keep], prior[keep][:, keep]
            middle = None if middle is None else middle[:, keep][:, :, keep]
            W = np.pad(W, (0, S))
            scale = np.concatenate([scale, np.ones(S)])
        return cls(q, info, usable, W, scale, tuple(np.array(params.names)[keep[:P]]), dropped, middle, S,
                   prior if S else None)

    def total(self, sel) -> tuple:
        """The information of the plan of candidates ``sel`` (with the set-up blocks' prior) and
        its sandwich middle (None without one)."""
        prior = 0.0 if self.prior is None else self.prior
        return (prior + self.info[sel].sum(axis=0),
                None if self.middle is None else prior + self.middle[sel].sum(axis=0))

    def values(self, sel) -> dict[str, float]:
        """O1-O5 (of the information with the set-up blocks marginalised) and ``pred`` of the plan
        made of candidates ``sel``."""
        total, middle = self.total(sel)
        if not self.n_setup:
            return indices(total, len(sel), self.scale, self.W, middle)
        # A fixture the plan does not visit is undetermined, and irrelevant: the marginal (by a
        # pseudo-inverse over the blocks) leaves it out, of the information and of the sandwich's middle.
        P = len(self.names)
        return indices(marginal(total, self.n_setup), len(sel), self.scale[:P], self.W[:P, :P],
                       marginal_middle(total, middle, self.n_setup))


def design_plan(model: RobotModel, n_poses: int, candidates, noise: Noise, index: str = "pred",
                q_verify=None, deviations: Deviations = Deviations(), max_iterations: int = 200,
                ridge: float = 1e-9, prepared: Candidates | None = None, progress=None, groups=None) -> Design:
    """Choose ``n_poses`` of ``candidates`` (K, joints) rad maximising ``index`` (greedy, then DETMAX).

    ``q_verify`` (default: the candidates) are the poses whose accuracy ``pred`` predicts;
    ``prepared`` reuses a :class:`Candidates` built once for several designs. At most
    ``max_iterations`` exchanges; ``progress(text)`` hears of each step. ``groups`` (K,) int:
    each candidate's placement (a fixture plate; -1: none); with it the plan takes ``n_poses``
    at each placement (the exchanges swap within one). Raises :class:`FgcalError` (one line)
    when there are fewer usable candidates than poses, or when no plan of ``n_poses`` of them can
    identify the parameters.
    """
    if index not in INDICES:
        raise FgcalError(f"unknown index {index!r} ({', '.join(INDICES)})")
    prep = prepared or Candidates.build(model, candidates, noise, q_verify, deviations)
    scale, W, S = prep.scale, prep.W, prep.n_setup
    pool = np.nonzero(prep.usable)[0]
    label = np.zeros(len(pool), dtype=int) if groups is None else np.asarray(groups, dtype=int)[pool]
    quota = {int(g): n_poses for g in np.unique(label) if g >= 0} if groups is not None else {0: n_poses}
    for g, n in quota.items():
        if np.sum(label == g) < n:
            where = f" at placement {g}" if groups is not None else ""
            raise FgcalError(f"only {np.sum(label == g)} usable candidate poses{where} for a plan of {n}: give "
                             "more candidates or ask for fewer poses")
    n_total = sum(quota.values())
    info = prep.info[pool]
    prior = np.zeros_like(info[0]) if prep.prior is None else prep.prior
    n_par = len(scale) - (np.linalg.matrix_rank(prior) if S else 0)
    sv = np.linalg.svd(info * np.outer(scale, scale)[None], compute_uv=False)
    ranks = (sv > 1e-9 * np.maximum(sv[:, :1], 1e-300)).sum(axis=1)
    if np.sort(ranks)[::-1][:n_total].sum() < n_par:
        need = int(np.ceil(n_par / max(ranks.max(initial=0), 1)))
        raise FgcalError(f"{n_total} poses of these candidates cannot identify the {n_par} parameters (each pose "
                         f"gives at most {ranks.max(initial=0)} independent equations): at least {need} poses needed")
    say = progress or (lambda text: None)
    mid = prep.middle[pool] if (prep.middle is not None and index == "pred") else None
    factors = low_rank(info) if index == "pred" and mid is None else None
    P = len(scale) - S

    def criterion(mats, mids=None):
        """Search scores of information matrices (K, P + S, P + S), of their marginal: the indices
        O1-O5, or ``pred`` with the directions at the rounding level counted there (finite)."""
        if S:
            mats, mids, sub = marginal(mats, S), marginal_middle(mats, mids, S), slice(0, P)
            return _scores(mats, scale[sub], index, W[sub, sub], mids, strict=False)
        return _scores(mats, scale, index, W, mids, strict=False)

    def batch(total, sign, members, mtotal=None):
        """Scores of ``total + sign * info[m]`` (sandwich middle ``mtotal + sign * mid[m]``) for
        each candidate m of ``members``."""
        if factors is not None:
            return pred_update(total, factors[members], W, sign, scale)
        return criterion(total[None] + sign * info[members], None if mid is None else mtotal[None] + sign * mid[members])

    # A vanishing ridge (relative to the parameters' expected spread) makes the first, rank
    # deficient steps of the greedy start well defined; it does not change the final choice.
    base = np.diag(ridge / scale**2) + prior
    chosen: list[int] = []
    total, mtotal = base.copy(), base.copy()
    for step in range(n_total):
        scores = batch(total, 1.0, slice(None), mtotal)
        scores[chosen] = -np.inf
        full = [g for g, n in quota.items() if np.sum(label[chosen] == g) >= n]
        scores[np.isin(label, full) | (label < 0)] = -np.inf
        j = int(np.argmax(scores))
        chosen.append(j)
        total = total + info[j]
        mtotal = mtotal + (0.0 if mid is None else mid[j])
        say(f"greedy start: {step + 1} of {n_total} poses")

    def middle_of(sel):
        return None if mid is None else base + mid[sel].sum(axis=0)

    def score_of(sel):
        m = middle_of(sel)
        return float(criterion((base + info[sel].sum(axis=0))[None], None if m is None else m[None])[0])

    best = score_of(chosen)
    it = 0
    for it in range(1, max_iterations + 1):
        # DETMAX excursion of size one: add the best candidate, then drop the weakest point of
        # its placement.
        total, mtotal = base + info[chosen].sum(axis=0), middle_of(chosen)
        add = batch(total, 1.0, slice(None), mtotal)
        add[chosen] = -np.inf
        add[label < 0] = -np.inf
        j = int(np.argmax(add))
        grown = chosen + [j]
        drop = batch(total + info[j], -1.0, grown, None if mid is None else mtotal + mid[j])
        drop[label[grown] != label[j]] = -np.inf
        k = int(np.argmax(drop))
        new = [c for i, c in enumerate(grown) if i != k]
        new_score = score_of(new)
        if not new_score > best + 1e-12 * abs(best):
            break
        chosen, best = new, new_score
        say(f"exchange {it} (at most {max_iterations}): {index} {abs(best):.4g}")
    sel = pool[np.array(chosen)]
    values = prep.values(sel)
    if index == "pred" and not np.isfinite(values["pred"]):
        raise FgcalError(f"no plan of {n_total} of these candidates identifies the {n_par} parameters: "
                         "ask for more poses")
    return Design(prep.q[sel], sel, values, index, it)


def random_design_values(prepared: Candidates, n_poses: int, rng: np.random.Generator, groups=None):
    """A random ``n_poses`` subset of the usable candidates (``n_poses`` at each placement of
    ``groups``, as :func:`design_plan` takes them) and its index values (for comparison)."""
    pool = np.nonzero(prepared.usable)[0]
    if groups is None:
        sel = rng.choice(pool, size=n_poses, replace=False)
    else:
        label = np.asarray(groups, dtype=int)[pool]
        sel = np.concatenate([rng.choice(pool[label == g], size=n_poses, replace=False)
                              for g in np.unique(label) if g >= 0])
    return sel, prepared.values(sel)
