"""The factor graph's value types: the noise of each factor kind, the variables, a linearisation.

Kept apart from :mod:`fgcal.estimation.graph` (which re-exports them) so that the graph's module
holds the graph itself. No I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields, replace

import numpy as np

from fgcal.estimation.column_groups import PoseColumns

__all__ = ["COST_ROUNDING", "Linearisation", "Sigmas", "State", "included"]

# Relative change of the cost below which two costs are the same up to rounding: the residuals
# are differences of coordinates of ~1e3 mm computed to ~1e-13 mm, whitened by sigmas of ~1e-2.
COST_ROUNDING = 1e-10


@dataclass(frozen=True)
class Sigmas:
    """Noise of each factor kind (mm, rad); ``joint`` 0 means the readings are exact.

    ``other`` holds ``(field, sigma)`` pairs of measurement types beyond the built-in ones
    (:meth:`fgcal.measurements.base.KinematicMeasurement.declared_sigmas`); they read as attributes.
    """

    probe: float
    centre: float
    pose_position: float
    pose_rotation: float
    joint: float
    kinematic: float = 1e-4
    distance: float = 0.01
    other: tuple = ()

    def __getattr__(self, name):  # only for names that are not fields
        for field_name, value in object.__getattribute__(self, "other"):
            if field_name == name:
                return value
        raise AttributeError(f"{type(self).__name__} has no sigma {name!r}")

    def replaced(self, **values) -> Sigmas:
        """A copy with the given sigmas changed (fields or ``other`` ones); itself when none are
        given (the same object means the same noise: a linearisation stays valid)."""
        if not values:
            return self
        known = {f.name for f in fields(self)}
        other = dict(self.other)
        other.update({k: v for k, v in values.items() if k not in known})
        return replace(self, **{k: v for k, v in values.items() if k in known}, other=tuple(sorted(other.items())))


@dataclass
class State:
    """The variables: ``theta`` (P,), ``q`` (N, n) rad/mm, ``c`` (Nb, 3) mm."""

    theta: np.ndarray
    q: np.ndarray
    c: np.ndarray

    def copy(self) -> State:
        return State(self.theta.copy(), self.q.copy(), self.c.copy())


@dataclass
class Linearisation:
    """Whitened residuals and Jacobians in per-pose blocks at one state.

    Attributes
    ----------
    r : ndarray, shape (N, m)
    J_stored : ndarray, shape (N, m_theta, P), or (N, m_theta, c) on ``columns``
        The theta Jacobian of the first ``m_theta`` rows of each pose (the others do not depend on
        theta) as the graph formed it: dense, or on each pose's own columns where set-up unknowns
        make most of a dense row zero (no (N, m_theta, P) array of zeros to fill, scan and gather).
    J_local : ndarray, shape (N, m, nz)
    prior_r, prior_J : global rows on theta only, shapes (k,), (k, P)
    cost : float
        Half the (robust) sum of squares.
    raw : dict
        ``{level: (e, s, w)}``: raw errors, whitened norms and weights per factor.
    excluded_rows : list
        The rows of the excluded measurements as they would be included (zero in ``r`` and the
        Jacobians): ``(pose (k, 1), rows (k, w), r, J_local, J_stored rows or None)`` per level, for
        :func:`included`.
    columns : PoseColumns or None
        The pose columns ``J_stored`` is on (:class:`fgcal.estimation.column_groups.PoseColumns`);
        None: it is dense.
    """

    r: np.ndarray
    J_stored: np.ndarray
    J_local: np.ndarray
    prior_r: np.ndarray
    prior_J: np.ndarray
    cost: float
    raw: dict = field(default_factory=dict)
    cache: dict = field(default_factory=dict)  # normal equations, Schur complement, covariance
    excluded_rows: list = field(default_factory=list)
    columns: PoseColumns | None = None

    @property
    def J_theta(self) -> np.ndarray:
        """The dense theta Jacobian (N, m_theta, P) (placed from ``J_stored`` once where it is on
        ``columns``: for the callers that index theta's columns directly)."""
        if self.columns is None:
            return self.J_stored
        if "J_dense" not in self.cache:
            self.cache["J_dense"] = self.columns.place(self.J_stored)
        return self.cache["J_dense"]


def included(lin: Linearisation) -> Linearisation:
    """``lin`` with its excluded measurements' rows put back (the linearisation at the same state with
    nothing excluded, without evaluating the factors again; its ``cost`` is not formed: nan), or
    ``lin`` itself when nothing was excluded."""
    if not lin.excluded_rows:
        return lin
    r, J_stored, J_local = lin.r.copy(), lin.J_stored.copy(), lin.J_local.copy()
    for pose, rows, r_ex, Jz_ex, Jt_ex in lin.excluded_rows:
        r[pose, rows] = r_ex
        J_local[pose, rows] = Jz_ex
        if Jt_ex is not None:
            J_stored[pose, rows] = Jt_ex
    return Linearisation(r, J_stored, J_local, lin.prior_r, lin.prior_J, float("nan"), lin.raw, columns=lin.columns)


def _robust(s, kind, k):
    """Weights and costs of whitened factor norms ``s`` under a robust loss."""
    if kind is None:
        return np.ones_like(s), 0.5 * s**2
    if kind == "huber":
        w = np.where(s <= k, 1.0, k / np.maximum(s, 1e-300))
        return w, np.where(s <= k, 0.5 * s**2, k * (s - 0.5 * k))
    if kind == "cauchy":
        return 1.0 / (1.0 + (s / k) ** 2), 0.5 * k**2 * np.log1p((s / k) ** 2)
    raise ValueError(f"unknown robust loss {kind!r}")
