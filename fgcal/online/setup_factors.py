"""GTSAM factors of the set-up blocks for the iSAM2 engine: a contact (the measurement type's
``setup_error``, with its analytic Jacobians in the parameters, the joints and the block), a known
distance between two fixture points, and a Gaussian over several vector variables (the marginal
that starts a new tree). One vector variable per free block (a point's x, y, z; a plane's tilts
and offset; a station's three angles and position); a fixed block is a constant. Keep a
reference to every factor: the closures capture their arguments."""
from __future__ import annotations

import numpy as np

from fgcal.measurements.setup import distance_error

__all__ = ["contact_factor", "distance_constraint_factor", "joint_gaussian_factor"]


def contact_factor(kind, data, layout, name, noise, index, held, chain, *, t_key, s_key=None, q_key=None,
                   q_fixed=None):
    """One contact (``data``: one row of the type's terms over ``layout``) as a ``gtsam.CustomFactor``
    on the parameters ``t_key``, the joints (``q_key``, or the constant ``q_fixed``) and the block
    ``s_key`` of fixture ``name`` (None: the block is fixed at the layout's values)."""
    import gtsam

    if (q_key is None) == (q_fixed is None):
        raise ValueError("give exactly one of q_key and q_fixed")
    index, held = np.array(index, dtype=int), np.array(held, dtype=float)
    q_const = None if q_fixed is None else np.array(q_fixed, dtype=float).reshape(1, -1)
    k = layout.offset[name]
    size = len(layout.block(layout.start, name))
    s0 = layout.start.copy()
    keys = [t_key] + ([q_key] if q_key is not None else []) + ([s_key] if s_key is not None else [])

    def error(this, values, H):
        q = q_const if q_key is None else values.atVector(q_key)[None]
        s = s0.copy()
        if s_key is not None:
            s[k:k + size] = values.atVector(s_key)
        e, J_t, J_q, J_s, _ = kind.setup_error(values.atVector(t_key), q, data, s, index, held, chain)
        if H is not None:
            H[0] = J_t[0]
            if q_key is not None:
                H[1] = J_q[0]
            if s_key is not None:
                H[len(keys) - 1] = J_s[0]
        return e[0]

    return gtsam.CustomFactor(noise, keys, error)


def distance_constraint_factor(constraint, layout, keys: dict):
    """A known distance between fixture points ``constraint.a`` and ``constraint.b``; ``keys``:
    fixture name -> its variable (a fixed one absent: the layout's value)."""
    import gtsam

    names = [n for n in (constraint.a, constraint.b) if n in keys]
    fixed = {n: layout.point(layout.start, n).copy() for n in (constraint.a, constraint.b) if n not in keys}

    def error(this, values, H):
        p = {n: values.atVector(keys[n]) for n in names} | fixed
        err, u = distance_error(p[constraint.a], p[constraint.b], constraint.distance)
        if H is not None:
            for i, n in enumerate(names):
                H[i] = (u if n == constraint.a else -u)[None, :]
        return np.array([err])

    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([float(constraint.sigma)]))
    return gtsam.CustomFactor(noise, [keys[n] for n in names], error)


def joint_gaussian_factor(keys, sizes, mean, covariance):
    """A Gaussian ``N(mean, covariance)`` over the stacked vector variables ``keys`` (sizes ``sizes``)."""
    import gtsam

    mean = np.array(mean, dtype=float)
    edges = np.concatenate([[0], np.cumsum(sizes)]).astype(int)

    def error(this, values, H):
        x = np.concatenate([values.atVector(k) for k in keys])
        if H is not None:
            eye = np.eye(len(mean))
            for i in range(len(keys)):
                H[i] = eye[:, edges[i]:edges[i + 1]]
        return x - mean

    return gtsam.CustomFactor(gtsam.noiseModel.Gaussian.Covariance(np.array(covariance, dtype=float)), list(keys),
                              error)
