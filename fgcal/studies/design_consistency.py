"""The verification weight of a contacts design: what the consistency at a fixture sees.

A contacts user verifies a calibration by its consistency (:mod:`fgcal.estimation.consistency`):
at each fixture, the ball centres the calibrated model predicts are refitted to their mean (a
point) or to a plane, and the RMS distance from it is the metric. A parameter error ``delta``
moves the centre of contact ``i`` by ``J_i delta``; the refit takes out what is common to a
fixture's contacts (for a point its mean motion, for a plane the motion along the normal that a
tilted, shifted plane absorbs), so the squared consistency grows by ``delta^T W_c delta`` with

    ``W_c = (1/N) sum_f (P_f J_f)^T (P_f J_f)``,

``J_f`` the stacked centre Jacobians of fixture ``f``'s contacts (along the normal for a plane)
and ``P_f`` the projector off the refit's span (the constant for a point, the constant and the
in-plane coordinates for a plane). Its expected value under a plan's covariance is ``tr(W_c Sigma)``,
at the dataset's own contacts (new placements of the same fixtures visited as the dataset visits
them). The position weight of :func:`fgcal.studies.design.verification_weight` counts, in addition,
each fixture's common motion, which no consistency sees: a plan chosen for it spends its poses on
the absolute position at the fixture, not on the spread of the configurations. No I/O here.
"""
from __future__ import annotations

import numpy as np

from fgcal.estimation.gauge import gauge_holds
from fgcal.measurements.dataset import Dataset
from fgcal.robots.model import RobotModel
from fgcal.studies.design import Candidates
from fgcal.studies.design_floor import weigh_by_misfit

__all__ = ["candidates_of", "consistency_weight", "contacts_only"]


def candidates_of(ds: Dataset, model: RobotModel, q, layout, found, misfit_weights: bool = True) -> Candidates:
    """The candidates' information (:class:`~fgcal.studies.design.Candidates`) for a design from
    ``ds``: at joints ``q`` (N, joints) internal units measured as ``layout`` says, the noise and
    linearisation point of ``found`` (:class:`~fgcal.studies.design_dataset.DesignNoise`).

    The parameters are those the batch estimates: the gauges held as it holds them
    (:func:`fgcal.estimation.gauge.gauge_holds`: the base where nothing fixes the world frame, the
    tool where cameras see it only through an unknown pose, the longest link where nothing fixes
    the scale). The verification weight is the consistency's (:func:`consistency_weight`) for
    contacts alone, else the tool positions at the candidates. ``misfit_weights``: the candidates are
    ``ds``'s own poses, weighed by ``found.misfit`` (:mod:`fgcal.studies.design_floor`).
    """
    params = model.parameters()
    params = type(params)(model, tuple(gauge_holds(ds, model, list(params.names), layout.levels)[0]))
    weight = consistency_weight(model, q, layout, params, found.slots) if contacts_only(layout) else None
    prep = Candidates.build(model, q, ds.noise, layout=layout, params=params, slots=found.slots,
                            sigmas=found.sigmas, actual=found.actual, joint_error=found.joint_error, weight=weight)
    if misfit_weights and found.misfit:
        prep = weigh_by_misfit(prep, np.array([found.misfit.get(int(p), 1.0) for p in ds.pose_ids]))
    return prep


def contacts_only(layout) -> bool:
    """Whether every level of ``layout`` is a contact type (blocks, no instrument): such data are
    verified by their consistency, not by positions an instrument measures."""
    return bool(layout.contacts) and layout.setup is not None and set(layout.contacts) == set(layout.levels)


def consistency_weight(model: RobotModel, q, layout, params, slots=None) -> np.ndarray | None:
    """``W_c`` (P, P) over ``params`` with ``tr(W_c Sigma)`` the expected rise of the squared contact
    consistency (mm^2) at the contacts of ``layout`` (each ball at the fixture it touches), joints
    ``q`` (N, joints) internal units, linearised at ``slots`` (default the nominal); None when
    ``layout`` has no contacts."""
    if not layout.contacts or layout.setup is None or model.tooling is None:
        return None
    x = model.nominal if slots is None else np.asarray(slots, dtype=float)
    q = np.atleast_2d(np.asarray(q, dtype=float))
    offsets = model.tooling.offsets()
    spec = layout.setup.spec
    P = len(params.index)
    acc, n = np.zeros((P, P)), 0
    for fixtures in layout.contacts.values():
        for name in sorted(set(fixtures[fixtures != ""].tolist())):
            rows, balls = np.nonzero(fixtures == name)
            jac = model.chain.jacobians(x, q[rows], offsets[balls][:, None, :])
            J = jac.point_slots[:, 0][:, :, params.index]  # (m, 3, P)
            pts = jac.points[:, 0]
            kind = spec.fixtures[name].type if name in spec.fixtures else "point"
            centred = pts - pts.mean(axis=0)
            if kind == "point" or len(rows) < 3:
                A = np.ones((len(rows), 1))
                Jr = J.transpose(1, 0, 2)  # (3, m, P): each coordinate refitted alone
            else:
                _, _, Vt = np.linalg.svd(centred, full_matrices=False)
                A = np.column_stack([np.ones(len(rows)), centred @ Vt[0], centred @ Vt[1]])
                Jr = np.einsum("r,mrp->mp", Vt[2], J)[None]  # (1, m, P): the distance from the plane
            proj = np.eye(len(rows)) - A @ np.linalg.pinv(A)
            Jc = np.einsum("ij,rjp->rip", proj, Jr)
            acc += np.einsum("rip,riq->pq", Jc, Jc)
            n += len(rows)
    return acc / n if n else None
