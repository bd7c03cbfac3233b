"""A study trial's measurements, vectorised: simulated CMM probing and the verification's pose fits.

:func:`simulate_probes` is :func:`fgcal.studies.simulate.measure` for probe points (the same random
stream, the same points); :meth:`ProbedPoses.measured_poses` is what
:func:`fgcal.estimation.verification.measured_poses` does with probe data (sphere fits of known radius, a
rigid fit per pose, the same checks), for all poses at once. A study trial spends its time in
its calibration, not here. Units: mm, rad. No I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ProbedPoses", "rigid_fits", "simulate_probes"]

def _cross(a, b):
    """Row-wise cross products of ``(..., 3)`` arrays, in :func:`fgcal.studies.simulate._cap_directions`'s order."""
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1], a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


@dataclass
class ProbedPoses:
    """Simulated CMM probing of a set of poses, every pose with the same number of balls and points.

    Attributes
    ----------
    pose_ids : ndarray of int, shape (K,)
        The poses kept (those with enough reachable balls on the actual robot), 1-based.
    joints_deg : ndarray, shape (K, n)
        Controller readings in file units (deg; mm for prismatic joints).
    ball_names : ndarray of str, shape (K, B)
        The probed balls of each pose, in the tool's order.
    points : ndarray, shape (K, B, P, 3)
        Probe points in the world (mm).
    """

    pose_ids: np.ndarray
    joints_deg: np.ndarray
    ball_names: np.ndarray
    points: np.ndarray

    def dataset(self, model, noise):
        """The probes as a :class:`~fgcal.measurements.dataset.Dataset` (by pose, ball, point, as ``measure``)."""
        from fgcal.measurements.dataset import Dataset, PointObservations

        K, B, P, _ = self.points.shape
        probes = PointObservations(np.repeat(self.pose_ids, B * P), np.repeat(self.ball_names.reshape(-1), P),
                                   self.points.reshape(-1, 3))
        return Dataset(robot=model.name, tooling=model.tooling, noise=noise, provenance={}, pose_ids=self.pose_ids,
                       joints_deg=self.joints_deg, probes=probes)

    def measured_poses(self, tooling, sigma: float):
        """Tool poses measured as :func:`fgcal.estimation.verification.measured_poses` measures probe data.

        Sphere fits of known radius with the residual check (as
        :func:`fgcal.measurements.spherefit.fit_spheres_checked`), then a least-squares rigid fit of
        each pose's three or more good balls with its chi-square check, all vectorised. Returns the rows
        (into ``pose_ids``) of the accepted poses, ``(K',)``,
        and their poses ``(K', 4, 4)``.
        """
        from fgcal.measurements.posefit import rigid_fit
        from fgcal.measurements.spherefit import fit_sphere, fit_spheres_arrays

        K, B, P, _ = self.points.shape
        if K == 0:
            return np.zeros(0, dtype=int), np.zeros((0, 4, 4))
        pts = self.points.reshape(K * B, P, 3)
        centre, _, _, cov, good = fit_spheres_arrays(pts, tooling.radius, sigma)
        var = np.trace(cov, axis1=1, axis2=2) / 3
        for i in np.nonzero(~good)[0]:  # fit_spheres_checked's path: the full diagnosis decides
            fit = fit_sphere(pts[i], radius=tooling.radius, sigma=sigma)
            good[i], centre[i], var[i] = fit.ok, fit.centre, np.trace(fit.covariance) / 3
        good, centre, var = good.reshape(K, B), centre.reshape(K, B, 3), var.reshape(K, B)
        names, which = np.unique(self.ball_names, return_inverse=True)
        tool = tooling.offsets(names)[which.reshape(K, B)]
        T = np.full((K, 4, 4), np.nan)
        ok = np.zeros(K, dtype=bool)
        whole = good.all(axis=1)
        if B >= 3 and whole.any():
            ok[whole], T[whole] = rigid_fits(tool[whole], centre[whole], np.sqrt(var[whole].mean(axis=1)))
        for k in np.nonzero(~whole & (good.sum(axis=1) >= 3))[0]:  # a ball failed its check: the other balls
            g = good[k]
            rigid = rigid_fit(tool[k, g], centre[k, g], sigma=float(np.sqrt(var[k, g].mean())))
            ok[k], T[k] = rigid.ok, rigid.T
        rows = np.nonzero(ok)[0]
        return rows, T[rows]


def rigid_fits(tool, world, sigma):
    """:func:`fgcal.measurements.posefit.rigid_fit` (Kabsch, its collinearity and chi-square checks), many poses.

    Parameters
    ----------
    tool, world : ndarray, shape (K, n, 3)
        Ball centres in the tool frame and as measured in the world (mm), n >= 3.
    sigma : ndarray, shape (K,)
        Per-coordinate noise of each pose's centres (mm).

    Returns
    -------
    ok : ndarray of bool, shape (K,)
    T : ndarray, shape (K, 4, 4)
    """
    from fgcal.measurements.spherefit import FALSE_ALARM, MIN_THRESHOLD_MM, chi2_quantile

    K, n, _ = tool.shape
    pc, wc = tool.mean(axis=1), world.mean(axis=1)
    H = np.einsum("kni,knj->kij", tool - pc[:, None], world - wc[:, None])
    U, S, Vt = np.linalg.svd(H)
    V, Ut = np.swapaxes(Vt, 1, 2), np.swapaxes(U, 1, 2)
    D = np.ones((K, 3))
    D[:, 2] = np.sign(np.linalg.det(V @ Ut))
    R = (V * D[:, None, :]) @ Ut
    t = wc - np.einsum("kij,kj->ki", R, pc)
    resid = world - (tool @ np.swapaxes(R, 1, 2) + t[:, None])
    rms = np.sqrt(np.mean(np.sum(resid**2, axis=2), axis=1))
    bound = float(np.sqrt(chi2_quantile(1 - FALSE_ALARM, 3 * n - 6) / n))
    threshold = np.where(sigma <= 0, MIN_THRESHOLD_MM, np.maximum(MIN_THRESHOLD_MM, sigma * bound))
    ok = (S[:, 1] >= 1e-9 * np.maximum(S[:, 0], 1e-300)) & (rms <= threshold)
    T = np.zeros((K, 4, 4))
    T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = R, t, 1.0
    return ok, T


def simulate_probes(model, slots, q_commanded, rng: np.random.Generator, tooling, noise, volume=None,
                    n_balls: int = 3, probes_per_ball: int = 4) -> ProbedPoses:
    """:func:`fgcal.studies.simulate.measure` of probe points (no outliers), vectorised.

    The same random stream as ``measure`` (the arm's landing error, then per probed ball the cap's
    uniform draws and the points' CMM noise), so the same points to rounding; only the per-ball
    random draws remain a loop.

    Parameters
    ----------
    slots : ndarray, shape (S,)
        The actual robot (mm, rad).
    q_commanded : array_like, shape (N, n)
        Commanded joints (rad, mm).
    """
    from fgcal.studies.plans import UP, ball_access

    q = np.atleast_2d(np.asarray(q_commanded, dtype=float))
    q_actual = q + rng.normal(size=q.shape) * model.joints_to_internal(np.full(model.n_joints, noise.repeatability))
    reading = model.joints_to_file_units(q)
    if noise.joint_resolution > 0:
        reading = np.round(reading / noise.joint_resolution) * noise.joint_resolution
    T = model.forward(slots, q_actual)
    ok, upness, centres = ball_access(T, tooling, volume)
    keep = np.nonzero(ok.sum(axis=1) >= n_balls)[0]
    # The most upward-facing reachable balls (stable among equals), in the tool's order.
    balls = np.sort(np.argsort(np.where(ok, -upness, np.inf), axis=1, kind="stable")[keep, :n_balls], axis=1)
    K, B, P = len(keep), n_balls, probes_per_ball
    n_ring = P - 1
    u = np.empty((K, B, 2 * n_ring + 1))
    g = np.empty((K, B, P, 3))
    for k in range(K):
        for b in range(B):
            u[k, b] = rng.random(2 * n_ring + 1)  # = uniform(0, 2 pi), then (uniform(45, 75), uniform(-0.2, 0.2))
            g[k, b] = rng.normal(size=(P, 3))
    names = np.array(tooling.names)
    unit = np.array([tooling.balls[nm] / np.linalg.norm(tooling.balls[nm]) for nm in names])[balls]  # (K, B, 3)
    outward = np.einsum("kij,kbj->kbi", T[keep, :3, :3], unit)
    axis = outward + UP
    axis = axis / np.linalg.norm(axis, axis=2, keepdims=True)
    helper = np.where((np.abs(axis[..., 0]) < 0.9)[..., None], np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    e1 = _cross(axis, helper)
    e1 = e1 / np.linalg.norm(e1, axis=2, keepdims=True)
    e2 = _cross(axis, e1)
    start = 0.0 + 2 * np.pi * u[..., :1]
    polar = np.radians(45.0 + 30.0 * u[..., 1::2])
    az = start + 2 * np.pi * np.arange(n_ring) / max(n_ring, 1) + (-0.2 + 0.4 * u[..., 2::2])
    ring = (np.cos(polar)[..., None] * axis[:, :, None]
            + np.sin(polar)[..., None] * (np.cos(az)[..., None] * e1[:, :, None]
                                          + np.sin(az)[..., None] * e2[:, :, None]))
    dirs = np.concatenate([axis[:, :, None], ring], axis=2)[:, :, :P]
    c = centres[keep[:, None], balls]  # (K, B, 3)
    points = c[:, :, None] + tooling.radius * dirs + g * noise.cmm_sigma
    return ProbedPoses(np.arange(1, len(q) + 1)[keep], reading[keep], names[balls], points)
