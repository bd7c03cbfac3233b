"""The paper's two-stage method, as a baseline: sphere fits, then least squares on the centres.

Stage 1 fits each ball's probe points (:func:`fgcal.measurements.measure.measure_probes`); stage 2 fits the
parameters to the good centres with ``scipy.optimize.least_squares``, treating the joint readings
as exact, as the paper did. Its covariance is ``sigma^2 (J^T J)^-1`` with the centres' noise.
No I/O here.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import csr_matrix

from fgcal.measurements.dataset import Dataset
from fgcal.measurements.measure import measure_probes
from fgcal.robots.kinematics import jacobians
from fgcal.robots.model import RobotModel

__all__ = ["two_stage"]


def two_stage(ds: Dataset, model: RobotModel, names=None):
    """Identify the parameters from fitted centres; returns ``(slots (37,), covariance (P, P), names)``.

    Units: internal (mm, rad). Starts from the nominal model.
    """
    params = model.parameters() if names is None else type(model.parameters())(model, tuple(names))
    m = measure_probes(ds)
    centres = m.centres
    rows = ds.row_of(centres.pose)
    q = ds.joints_rad[rows]
    offsets = np.array([ds.tooling.balls[b] for b in centres.ball]).reshape(-1, 1, 3)
    idx = params.index
    sigma = float(np.sqrt(np.mean(np.trace(m.centre_covariance, axis1=1, axis2=2) / 3)))

    def residual(theta):
        jac = jacobians(params.full(theta), q, offsets)
        return (jac.points[:, 0] - centres.xyz).ravel()

    def jac(theta):
        j = jacobians(params.full(theta), q, offsets)
        return csr_matrix(j.point_slots[:, 0][:, :, idx].reshape(-1, len(idx)))

    sol = least_squares(residual, params.nominal(), jac=jac, method="trf", x_scale="jac", xtol=1e-12, ftol=1e-12,
                        gtol=1e-12, tr_solver="lsmr")
    J = jac(sol.x).toarray()
    cov = sigma**2 * np.linalg.inv(J.T @ J)
    return params.full(sol.x), cov, list(params.names)
