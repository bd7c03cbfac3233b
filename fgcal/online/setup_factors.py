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


def contact_factor(kind, data, layout, names, noise, index, held, chain, *, t_key, s_keys, q_key=None,
                   q_fixed=None):
    """One row of a set-up type (``data``: one row of the type's terms over ``layout``: a contact,
    a centre from a station, a corner's pixel) as a ``gtsam.CustomFactor`` on the parameters
    ``t_key``, the joints (``q_key``, or the constant ``q_fixed``) and the variables of the blocks
    ``names`` it depends on (``s_keys``: block -> its variable, which holds the block's free
    entries; a block without one is fixed at the layout's values)."""
    import gtsam

    if (q_key is None) == (q_fixed is None):
        raise ValueError("give exactly one of q_key and q_fixed")
    index, held = np.array(index, dtype=int), np.array(held, dtype=float)
    q_const = None if q_fixed is None else np.array(q_fixed, dtype=float).reshape(1, -1)
    s0 = layout.start.copy()
    blocks = []  # (variable, the block's free entries' indices in s)
    for name in dict.fromkeys(names):
        if name in s_keys:
            k = layout.offset[name]
            size = len(layout.block(layout.start, name))
            blocks.append((s_keys[name], k + np.nonzero(layout.free[k:k + size])[0]))
    keys = [t_key] + ([q_key] if q_key is not None else []) + [key for key, _ in blocks]
    first = len(keys) - len(blocks)

    def error(this, values, H):
        q = q_const if q_key is None else values.atVector(q_key)[None]
        s = s0.copy()
        for key, idx in blocks:
            s[idx] = values.atVector(key)
        e, J_t, J_q, J_s, cols = kind.setup_error(values.atVector(t_key), q, data, s, index, held, chain)
        if H is not None:
            H[0] = J_t[0]
            if q_key is not None:
                H[1] = J_q[0]
            for b, (_, idx) in enumerate(blocks):
                # the columns of the type's J_s that are this block's free entries
                hit = cols[0][:, None] == idx[None, :]
                H[first + b] = J_s[0] @ hit.astype(float)
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
