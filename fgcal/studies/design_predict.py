"""A plan's predicted accuracy, where the plan determines it, and +inf where it does not.

``pred`` is ``sqrt(trace(W Sigma))`` (mm), ``Sigma`` the inverse information ``M^-1`` or the
sandwich ``M^-1 B M^-1``, ``W`` the verification weight. It is finite exactly when the predicted
quantity (the tool positions at the verification poses, the range of ``W``) is determined by the
plan: when ``range(W)`` lies in ``range(M)``. The inverse of a near-singular ``M`` answers that
question with garbage (``1e5`` mm, or ``0`` from a negative trace), so it is asked numerically:

* in the units of the expected parameter errors ``scale`` (``Ms = D M D``, ``Ws = D W D``,
  ``D = diag(scale)``): ``trace(W Sigma) = trace(Ws Ms^-1 (D B D) Ms^-1)``, a scaling that any
  change of a parameter's unit (mm to m, rad to deg, with its ``scale``) leaves as it is;
* the eigen-decomposition of ``Ms``: a direction with an eigenvalue at most ``RANK_RTOL`` times
  the largest is not determined (the normal matrices' rounding is ``1e-16`` of the largest; the
  undetermined directions of the Schur complements of 12-pose contact plans come out at ``1e-14``
  or below, the determined ones of the plans in the tests at ``1e-6`` or above);
* the plan predicts if ``W``'s share on the undetermined directions, ``trace(V_0^T Ws V_0) /
  trace(Ws)``, is at most ``SEEN_RTOL`` (a share of rounding size: ``W`` does not see them, like an
  unvisited station's frame); the prediction is then the pseudo-inverse's over the determined
  directions (``inv``'s when none is cut), else ``+inf``.

Set-up blocks (fixtures, stations) are marginalised first (:func:`marginal`, the Schur complement
with a pseudo-inverse over the blocks: a block no pose of the plan touches drops out), with the
sandwich's middle carried the same way (:func:`marginal_middle`): decision and value are those
of the whole information, the blocks' entries taken for parameters that ``W`` does not see. The search (``strict=False``, the scores of
:func:`fgcal.studies.design.design_plan`) needs a finite, graded score for the rank-deficient
plans of its greedy start: there the information carries the designer's vanishing ridge, and a
ridge at ``ROUNDING_RTOL`` of the largest scaled information (the rounding level, below which an
inverse gave a negative trace, clipped to a perfect 0) is added, the same for all the plans
compared at once.
No I/O.
"""
from __future__ import annotations

import numpy as np

__all__ = ["RANK_RTOL", "ROUNDING_RTOL", "SEEN_RTOL", "low_rank", "marginal", "marginal_middle", "pred_update", "predicted_mse",
           "predicted_rms", "quantiles"]

RANK_RTOL = 1e-10  # eigenvalue of the scaled information, over its largest, below which a direction is undetermined
SEEN_RTOL = 1e-8  # share of trace(Ws) on the undetermined directions below which W does not see them
ROUNDING_RTOL = 1e-13  # below this over the largest, an eigenvalue of the scaled information is rounding


def marginal(info, n_setup: int):
    """The information (..., P, P) about the parameters of information (..., P + S, P + S) whose
    last ``n_setup`` entries (set-up blocks estimated with them) are marginalised: the Schur
    complement ``A - B C^+ B^T``."""
    if not n_setup:
        return info
    A, B, C = info[..., :-n_setup, :-n_setup], info[..., :-n_setup, -n_setup:], info[..., -n_setup:, -n_setup:]
    return A - B @ np.linalg.pinv(C, hermitian=True) @ np.swapaxes(B, -1, -2)


def marginal_middle(info, middle, n_setup: int):
    """The sandwich middle (..., P, P) of the parameters' marginal: with ``G = [I, -B C^+]`` (from
    ``info``), the parameter block of ``info^-1 middle info^-1`` is ``S^-1 (G middle G^T) S^-1``,
    ``S`` the Schur complement (:func:`marginal`). ``middle`` None stays None."""
    if middle is None or not n_setup:
        return middle
    B, C = info[..., :-n_setup, -n_setup:], info[..., -n_setup:, -n_setup:]
    BC = B @ np.linalg.pinv(C, hermitian=True)
    eye = np.broadcast_to(np.eye(B.shape[-2]), BC.shape[:-1] + (B.shape[-2],))
    G = np.concatenate([eye, -BC], axis=-1)
    return G @ middle @ np.swapaxes(G, -1, -2)


def predicted_mse(info, W, scale=None, middle=None, strict: bool = True) -> np.ndarray:
    """Predicted mean squared position error (mm^2) at the verification poses of ``W`` (P, P) for
    each information matrix ``info`` (K, P, P) (and sandwich middle (K, P, P)), the parameters in
    units of ``scale`` (P,) (default: each parameter's own information, ``1 / sqrt(M_ii)``).

    ``strict``: +inf where the plan does not determine what ``W`` sees (see the module's text);
    otherwise (the search's score) with a ridge at the rounding level (``ROUNDING_RTOL`` times the
    batch's largest scaled diagonal entry), no eigen-decomposition.
    Never NaN, never negative.
    """
    info = np.asarray(info, dtype=float)
    K, P = info.shape[0], info.shape[-1]
    if scale is None:
        diag = np.diagonal(info, axis1=1, axis2=2)
        d = np.where(diag > 0, 1.0 / np.sqrt(np.where(diag > 0, diag, 1.0)), 1.0)
    else:
        d = np.broadcast_to(np.asarray(scale, dtype=float), (K, P))
    finite = np.isfinite(info.sum(axis=(1, 2)))
    if not finite.all():
        info = np.where(finite[:, None, None], info, 0.0)
    W = np.asarray(W, dtype=float)
    if not strict:  # the search: a ridge at the rounding level of the batch's largest scaled information
        ridge = max(ROUNDING_RTOL * float(np.max(np.diagonal(info, axis1=1, axis2=2) * d**2, initial=0.0)), 1e-300)
        ridged = info.copy()
        ridged[:, np.arange(P), np.arange(P)] += ridge / d**2
        out = _trace(ridged, W, middle)
        return np.where(finite & np.isfinite(out), np.maximum(out, 0.0), np.inf)
    outer = d[:, :, None] * d[:, None, :]
    Ms, Ws = info * outer, W[None] * outer
    Bs = None if middle is None else np.asarray(middle, dtype=float) * outer
    lam = np.linalg.eigvalsh(Ms)  # the eigenvectors only where a direction is cut: they cost 50x more
    top = lam[:, -1]
    floor = RANK_RTOL * top
    out = np.zeros(K)
    clean = (lam[:, 0] > floor) & (top > 0)
    if clean.any():  # every direction determined: the inverse
        out[clean] = _trace(Ms[clean], Ws[clean], None if Bs is None else Bs[clean])
    if not clean.all():
        rest = ~clean
        out[rest] = _cut(Ms[rest], Ws[rest], None if Bs is None else Bs[rest], floor[rest])
    return np.where(finite & np.isfinite(out), np.maximum(out, 0.0), np.inf)


def _trace(M, W, B) -> np.ndarray:
    """``trace(W M^-1)`` or ``trace(W M^-1 B M^-1)`` (K,) of invertible ``M`` (K, P, P); ``W`` (P, P)
    or (K, P, P)."""
    cov = np.linalg.inv(M)
    if B is not None:
        cov = cov @ B @ cov
    return np.einsum("kpq,kqp->k", np.broadcast_to(W, cov.shape), cov)


def _cut(Ms, Ws, Bs, floor) -> np.ndarray:
    """:func:`predicted_mse` (K,) of scaled information ``Ms`` (K, P, P) with directions at or below
    ``floor`` (K,): left out (the pseudo-inverse) where ``W`` does not see them, else +inf."""
    lam, V = np.linalg.eigh(Ms)
    kept = lam > floor[:, None]
    Wt = np.swapaxes(V, 1, 2) @ Ws @ V  # W in the eigenbasis: its diagonal is W's share on each direction
    seen = np.einsum("kii->ki", Wt)
    inv = np.where(kept, 1.0 / np.where(kept, lam, 1.0), 0.0)
    if Bs is None:
        out = np.einsum("ki,ki->k", seen, inv)
    else:
        Bt = np.swapaxes(V, 1, 2) @ Bs @ V
        out = np.einsum("kij,kj,kji,ki->k", Wt, inv, Bt, inv)
    whole = np.maximum(np.einsum("kii->k", Ws), 0.0)
    blind = (np.sum(np.where(kept, 0.0, np.abs(seen)), axis=1) <= SEEN_RTOL * whole) & (lam[:, -1] > 0)
    return np.where(blind, out, np.where(whole > 0, np.inf, 0.0))


def predicted_rms(info, W, middle=None, scale=None) -> float:
    """Predicted position error RMS (mm) at the verification poses of ``W`` (P, P), given
    information ``info`` (P, P) (and the sandwich's middle ``B``: covariance ``info^-1 B info^-1``),
    decided in units of ``scale`` (P,); +inf where the information does not determine what ``W``
    sees (:func:`predicted_mse`)."""
    mids = None if middle is None else np.asarray(middle, dtype=float)[None]
    return float(np.sqrt(predicted_mse(np.asarray(info, dtype=float)[None], W, scale, mids)[0]))


def low_rank(info, rtol: float = 1e-12):
    """Factors ``L`` (K, P, r) with ``info[k] = L[k] L[k]^T``, or None when the poses' information
    is not of low rank (then a rank-r update is no cheaper than an inverse)."""
    w, V = np.linalg.eigh(info)
    r = int((w > rtol * np.maximum(w[:, -1:], 1e-300)).sum(axis=1).max(initial=0))
    if r == 0 or 2 * r > info.shape[1]:
        return None
    return V[:, :, -r:] * np.sqrt(np.clip(w[:, None, -r:], 0.0, None))


def pred_update(total, L, W, sign: float, scale=None) -> np.ndarray:
    """Search score (minus the predicted RMS, :func:`predicted_mse` with ``strict=False``) of
    ``total + sign L_k L_k^T`` for every k, by the Woodbury identity: ``tr(W (T + s L L^T)^-1) =
    tr(W C) - s tr((I + s L^T C L)^-1 L^T C W C L)`` with ``C`` the inverse of ``total`` (with the
    ridge at the rounding level); r-by-r solves instead of P-by-P inverses."""
    P = total.shape[-1]
    d = np.ones(P) if scale is None else np.asarray(scale, dtype=float)
    ridge = max(ROUNDING_RTOL * float(np.max(np.diag(total) * d**2, initial=0.0)), 1e-300)
    C = np.linalg.inv(total + np.diag(ridge / d**2))
    CL = C @ L
    G = np.swapaxes(L, 1, 2) @ CL
    H = np.swapaxes(CL, 1, 2) @ W @ CL
    eye = np.eye(L.shape[2])[None]
    try:
        change = np.einsum("kii->k", np.linalg.solve(eye + sign * G, H))
    except np.linalg.LinAlgError:
        mats = total[None] + sign * L @ np.swapaxes(L, 1, 2)
        return -np.sqrt(predicted_mse(mats, W, scale, strict=False))
    out = -np.sqrt(np.clip(np.trace(W @ C) - sign * change, 0.0, None))
    return np.where(np.isfinite(out), out, -np.inf)


def quantiles(values, percents) -> tuple[float, ...]:
    """Percentiles of ``values`` in which +inf (a plan that cannot predict) may be: one beyond the
    largest finite value is inf (the interpolation between two infinities is not NaN)."""
    values = np.asarray(values, dtype=float)
    big = np.finfo(float).max
    finite = values[np.isfinite(values)]
    top = finite.max() if len(finite) else -np.inf
    out = np.percentile(np.minimum(values, big), percents)
    return tuple(float(v) if v <= top else float("inf") for v in out)
