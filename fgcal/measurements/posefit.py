"""Tool poses from ball centres (the paper's eqs. 11-15 and 18-21, and a least-squares fit).

Two methods:

* :func:`paper_pose`: ``T = P' P^-1`` with a fictitious fourth ball from the cross product of
  eq. (15). The fourth column is taken as a direction (homogeneous coordinate 0), which keeps
  eq. (15) consistent under translation. Under noise ``T``'s rotation part is not orthonormal;
  :func:`homogeneity_errors` measures by how much (eqs. 19-21).
* :func:`rigid_fit`: the least-squares rigid transform (SVD, Kabsch) from three or more balls,
  with the pose covariance and a chi-square test of the fit.

Units: mm, rad. No I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgcal.measurements.spherefit import FALSE_ALARM, MIN_THRESHOLD_MM, chi2_quantile

__all__ = ["RigidFit", "check_homogeneous", "homogeneity_errors", "nearest_rotation", "paper_pose", "rigid_fit",
           "rigid_fits_at_pooled_noise"]


def _check_pair(tool_points, world_points, minimum: int):
    P = np.asarray(tool_points, dtype=float)
    W = np.asarray(world_points, dtype=float)
    if P.ndim != 2 or P.shape[1] != 3 or P.shape != W.shape:
        raise ValueError(f"tool and world points must both have shape (n, 3), got {P.shape} and {W.shape}")
    if len(P) < minimum:
        raise ValueError(f"need at least {minimum} balls, got {len(P)}")
    return P, W


def paper_pose(tool_points, world_points) -> np.ndarray:
    """The paper's pose ``T = P' P^-1`` (4, 4) from exactly three balls.

    Parameters
    ----------
    tool_points, world_points : array_like, shape (3, 3)
        Ball centres in the tool frame and as measured in the world (mm), same order.
    """
    P, W = _check_pair(tool_points, world_points, 3)
    if len(P) != 3:
        raise ValueError(f"the paper's method takes exactly 3 balls, got {len(P)}")

    def homogeneous(X):
        M = np.zeros((4, 4))
        M[:3, :3] = X.T
        M[3, :3] = 1.0
        M[:3, 3] = np.cross(X[2] - X[0], X[1] - X[0])  # eq. (15), a direction
        return M

    Pm = homogeneous(P)
    if abs(np.linalg.det(Pm)) < 1e-9 * np.linalg.norm(Pm) ** 4:
        raise ValueError("the three balls are collinear: no pose")
    return homogeneous(W) @ np.linalg.inv(Pm)


def homogeneity_errors(T) -> dict[str, float]:
    """Deviations from a proper transform ``[n o a p]`` (eqs. 19-21).

    Returns ``{"norm": max |x.x - 1| over n, o, a, "n_oxa": |n - o x a|, "o_axn": |o - a x n|}``.
    """
    T = np.asarray(T, dtype=float)
    n, o, a = T[:3, 0], T[:3, 1], T[:3, 2]
    return {"norm": float(max(abs(n @ n - 1), abs(o @ o - 1), abs(a @ a - 1))),
            "n_oxa": float(np.linalg.norm(n - np.cross(o, a))),
            "o_axn": float(np.linalg.norm(o - np.cross(a, n)))}


def check_homogeneous(T, tolerance: float) -> str:
    """``"ok"`` if every error of :func:`homogeneity_errors` is within ``tolerance``, else why not."""
    errs = homogeneity_errors(T)
    bad = [f"{k} {v:.3g}" for k, v in errs.items() if v > tolerance]
    labels = {"norm": "column length (eq. 19)", "n_oxa": "n = o x a (eq. 20)", "o_axn": "o = a x n (eq. 21)"}
    if not bad:
        return "ok"
    worst = max(errs, key=lambda k: errs[k])
    return f"not a rigid transform: {labels[worst]} off by {errs[worst]:.3g} (tolerance {tolerance:.3g})"


def nearest_rotation(M) -> np.ndarray:
    """The rotation matrix nearest to ``M`` (3, 3) in the Frobenius norm (polar decomposition)."""
    U, _, Vt = np.linalg.svd(np.asarray(M, dtype=float))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


@dataclass
class RigidFit:
    """Result of :func:`rigid_fit`.

    Attributes
    ----------
    T : ndarray, shape (4, 4)
    residuals : ndarray, shape (n, 3)
        Measured minus fitted ball centres (mm).
    rms : float
        RMS distance of the residuals (mm).
    covariance : ndarray, shape (6, 6)
        Of ``[w, v]``: world-frame rotation vector (rad) and tool-origin translation (mm),
        for centres with per-coordinate ``sigma``.
    ok : bool
    status : str
    """

    T: np.ndarray
    residuals: np.ndarray
    rms: float
    covariance: np.ndarray
    ok: bool
    status: str


def rigid_fit(tool_points, world_points, sigma: float = 0.01, threshold: float | None = None) -> RigidFit:
    """Least-squares rigid transform from three or more ball centres (Kabsch), with checks.

    The fit is flagged when the RMS residual exceeds the chi-square bound for ``3n - 6``
    degrees of freedom at 0.1% false alarm (or ``threshold`` mm): the measured centres then do
    not match the tool's geometry (a wrong ball name, a bad centre).
    """
    P, W = _check_pair(tool_points, world_points, 3)
    pc, wc = P.mean(axis=0), W.mean(axis=0)
    H = (P - pc).T @ (W - wc)
    U, S, Vt = np.linalg.svd(H)
    if S[1] < 1e-9 * max(S[0], 1e-300):
        T = np.eye(4)
        return RigidFit(T, np.zeros_like(P), np.inf, np.full((6, 6), np.nan), False, "balls are collinear: no pose")
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    t = wc - R @ pc
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    fitted = P @ R.T + t
    resid = W - fitted
    rms = float(np.sqrt(np.mean(np.sum(resid**2, axis=1))))
    # d(R b + t) = -[R b]x w + v
    b = P @ R.T
    J = np.zeros((len(P), 3, 6))
    zero = np.zeros(len(P))
    J[:, :, :3] = -np.stack([np.stack([zero, -b[:, 2], b[:, 1]], 1), np.stack([b[:, 2], zero, -b[:, 0]], 1),
                             np.stack([-b[:, 1], b[:, 0], zero], 1)], 1)
    J[:, :, 3:] = np.eye(3)
    J2 = J.reshape(-1, 6)
    cov = np.linalg.inv(J2.T @ J2) * sigma**2
    dof = 3 * len(P) - 6
    if threshold is None:
        threshold = MIN_THRESHOLD_MM if sigma <= 0 else max(
            MIN_THRESHOLD_MM, sigma * float(np.sqrt(chi2_quantile(1 - FALSE_ALARM, dof) / len(P))))
    if rms > threshold:
        worst = int(np.argmax(np.linalg.norm(resid, axis=1)))
        return RigidFit(T, resid, rms, cov, False,
                        f"ball centres do not fit the tool: RMS {rms:.4g} mm above {threshold:.4g} mm "
                        f"(worst: ball {worst + 1}, {np.linalg.norm(resid[worst]):.4g} mm)")
    return RigidFit(T, resid, rms, cov, True, "ok")


MIN_POOLED_DOF = 5  # degrees of freedom below which a pooled noise estimate is too uncertain to use


def rigid_fits_at_pooled_noise(pairs, declared: float) -> tuple[list[RigidFit], float | None]:
    """:func:`rigid_fit` of several poses, each judged at the noise the other poses' fits show.

    A pose's ball triangle is tested against the chi-square limit at the sigma pooled over the
    other poses' fits (their squared residuals over their ``3n - 6`` degrees of freedom): the
    tracker's noise as these poses measure it, which a declared sigma may understate, and which
    one gross pose cannot inflate for itself. Where the other poses have fewer than
    :data:`MIN_POOLED_DOF` degrees of freedom, the ``declared`` sigma is used.

    Parameters
    ----------
    pairs : sequence of (tool_points, world_points)
        Per pose, arrays (n, 3) mm with n >= 3.
    declared : float
        The declared per-coordinate sigma of a centre (mm).

    Returns
    -------
    fits : list of RigidFit
        In the order of ``pairs``.
    pooled : float or None
        The sigma pooled over all poses (mm), None when too few degrees of freedom.
    """
    free = [rigid_fit(P, W, sigma=declared, threshold=np.inf) for P, W in pairs]
    ssq = np.array([float(np.sum(f.residuals**2)) if np.isfinite(f.rms) else 0.0 for f in free])
    dof = np.array([max(3 * len(P) - 6, 0) if np.isfinite(f.rms) else 0 for (P, _), f in zip(pairs, free)])
    pooled = float(np.sqrt(ssq.sum() / dof.sum())) if dof.sum() >= MIN_POOLED_DOF else None
    fits = []
    for k, (P, W) in enumerate(pairs):
        others = dof.sum() - dof[k]
        sigma = float(np.sqrt((ssq.sum() - ssq[k]) / others)) if others >= MIN_POOLED_DOF else declared
        fits.append(rigid_fit(P, W, sigma=sigma))
    return fits, pooled
