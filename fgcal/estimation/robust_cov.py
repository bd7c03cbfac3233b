"""The covariance of a regularised (MAP) estimate as the scatter of the estimate: sandwich forms.

A joint-error map is estimated with a zero-mean prior on each coefficient (:mod:`fgcal.estimation.joint_errors`),
chosen by cross-validation. The posterior covariance ``C = (F + P)^-1`` (``F`` the data's
information, ``P`` the prior's) is the uncertainty about a coefficient drawn from the prior; the
scatter of the estimate over repeated measurements of one robot is the sandwich ``C F C`` (for
white residuals at the estimated noise), or, with the data's own scatter of scores,
``C M C`` with ``M = sum_g s_g s_g^T`` over clusters ``g`` of poses (``s_g`` the whitened
residuals' score of the cluster's poses): robust to residuals that are neither white nor equally
large. No I/O here.
"""
from __future__ import annotations

import numpy as np

__all__ = ["pose_scores", "sandwich", "score_covariance"]


def pose_scores(graph, lin) -> np.ndarray:
    """Each pose's contribution to the reduced gradient of theta, ``(N, P)``.

    ``J_theta^T r - B D^-1 g_z`` per pose (whitened units; the per-pose variables eliminated as in
    the solve); at the optimum ``g_z`` is zero and the second term vanishes. Excluded measurements
    have zero weight in ``lin`` and contribute nothing.
    """
    _, B, _, _, g_z = graph.normal_equations(lin)
    _, Dinv = graph._reduced_at(lin)
    mt = lin.J_theta.shape[1]
    s = np.einsum("nmp,nm->np", lin.J_theta, lin.r[:, :mt])
    if graph.nz:
        s -= np.einsum("npz,nz->np", B, np.einsum("nzy,ny->nz", Dinv, g_z))
    return s


def score_covariance(scores, clusters=None) -> np.ndarray:
    """``M = sum_g s_g s_g^T`` (P, P) of per-pose ``scores`` (N, P) summed within ``clusters`` (N,)."""
    s = np.asarray(scores, dtype=float)
    if clusters is not None:
        _, inv = np.unique(np.asarray(clusters), return_inverse=True)
        g = np.zeros((int(inv.max()) + 1, s.shape[1]))
        np.add.at(g, inv, s)
        s = g
    return s.T @ s


def sandwich(cov, information) -> np.ndarray:
    """``C M C`` (P, P), symmetrised: ``cov`` the posterior covariance, ``information`` ``M`` or ``F``."""
    out = cov @ information @ cov
    return 0.5 * (out + out.T)


JACKKNIFE_GROUPS = 30  # groups of poses left out in turn (29 degrees of freedom per variance)


def jackknife_variances(prob, cols, prior_sigma, groups: int = JACKKNIFE_GROUPS, order=None) -> np.ndarray:
    """Delete-a-group jackknife variances (len(cols),) of the linearised MAP estimate, internal units.

    ``prob`` is a :class:`~fgcal.estimation.cross_validation.CVProblem`; its poses are dealt into
    ``groups`` groups (repeated configurations together; at random, seeded, or ``order``
    ``blocked``: contiguous stretches in pose id order) and the estimate is recomputed with each
    group left out: ``(K-1)/K sum_k (x_k - mean)**2``. This is the scatter of the estimate as the
    data show it, unequal and non-Gaussian residuals included, which ``C F C`` assumes away. On
    Series B stretches in time over-count it (the drift between stretches: 0.67 of the scatter over
    disjoint random subsets against 0.98 for random groups), hence random groups by default.
    """
    from fgcal.estimation.cross_validation import FoldOrder, _folds
    from fgcal.estimation.time_validation import FoldSums

    k = int(min(groups, len(np.unique(prob.groups))))
    order = FoldOrder.RANDOM if order is None else FoldOrder(order)
    fold = _folds(prob.groups, k, np.random.default_rng(0), order)
    sums = FoldSums(prob, fold, k)
    x = np.array([sums.fit_without(f, cols, prior_sigma) for f in range(k)])
    return (k - 1) / k * np.sum((x - x.mean(axis=0)) ** 2, axis=0)


def _file_scale(unit: str) -> float:
    """Internal -> file units of one parameter: deg from rad, urad (per N m) from rad, mm as is."""
    return float(np.degrees(1.0)) if unit == "deg" else 1e6 if unit.startswith("urad") else 1.0


def scatter_covariance(ds, model, result, options, order=None) -> dict:
    """Put ``result``'s (a joint-error model's) covariance at the scatter its estimate shows.

    The posterior covariance ``C`` of a MAP estimate counts the prior's uncertainty, which is not
    scatter (on a real UR10 series the map's terms are ~95% prior-determined: their posterior
    sigmas are 2x the scatter of the estimates over disjoint subsets); ``C F C`` (``F`` the data's
    information) is the scatter for white residuals, half of what real residuals give there. The
    covariance becomes ``D (C F C) D`` with ``D`` per map term the ratio of its delete-a-group
    jackknife sigma (:func:`jackknife_variances`, on the problem linearised at the solution, the
    calibration's gross errors left out) to its ``C F C`` one (1 for the data-determined geometry
    and compliances): the jackknife's variances, the estimate's correlations. ``result`` is
    changed in place; returns what is recorded in ``result.joint_errors["covariance"]``.
    """
    from types import SimpleNamespace

    from fgcal.estimation.cross_validation import cv_problem
    from fgcal.estimation.joint_errors import JointErrorSpec, is_block_name

    spec = JointErrorSpec.from_dict(result.joint_errors["spec"])
    names = list(result.names)
    units = [p.unit for p in result.parameters]
    typical = (result.options or {}).get("typical_deviation_priors") or {}
    sd_file = np.array([(spec.compliance_sigma if n.endswith(".compliance") else spec.map_sigma) * 1e6
                        if is_block_name(n) else float(typical.get(n, np.inf)) for n in names])
    geo_like = SimpleNamespace(names=[n for n in names if not is_block_name(n)], options=result.options,
                               slot_vector=result.slot_vector)
    gross = {o.pose for o in result.outliers}  # excluded by the calibration: not in its estimate's scatter
    if gross:
        ds = ds.select(ds.pose_ids[~np.isin(ds.pose_ids, sorted(gross))])
    prob = cv_problem(ds, model, geo_like, spec, options)
    index = {n: i for i, n in enumerate(prob.names)}
    mine = [i for i, n in enumerate(names) if n in index]
    cols = [index[names[i]] for i in mine]
    scale = np.array([_file_scale(units[i]) for i in mine])
    jk = jackknife_variances(prob, cols, sd_file[mine] / scale, order=order) * scale**2
    C = np.asarray(result.covariance, dtype=float)
    P = np.where(np.isfinite(sd_file), 1.0 / sd_file**2, 0.0)
    Cs = C - (C * P) @ C
    Cs = 0.5 * (Cs + Cs.T)
    D = np.ones(len(names))
    v = np.diag(Cs)[mine]
    # the map's terms only: the geometry and the compliances are data-determined (C F C is their
    # scatter; on Series B 0.75 of it against the jackknife's 0.69, which over-counts theirs)
    ok = (v > 0) & np.isfinite(jk) & np.array([names[i].startswith("map.") for i in mine], dtype=bool)
    D[np.asarray(mine)[ok]] = np.sqrt(jk[ok] / v[ok])
    cov = Cs * np.outer(D, D)
    result.covariance = 0.5 * (cov + cov.T)
    sigma = np.sqrt(np.clip(np.diag(result.covariance), 0.0, None))
    for p, s in zip(result.parameters, sigma):
        p.sigma = float(s)
    block = np.array([n.startswith("map.") for n in names])
    info = {"kind": "jackknife", "groups": int(min(JACKKNIFE_GROUPS, len(np.unique(prob.groups)))),
            "order": "random" if order is None else str(getattr(order, "value", order)),
            "note": "the MAP estimate's scatter: the delete-a-group jackknife's variances with the correlations "
                    "of C F C (not the posterior, whose prior share is not scatter)",
            "factor_median_map": float(np.median(D[block])) if block.any() else None}
    result.joint_errors = {**result.joint_errors, "covariance": info}
    return info
