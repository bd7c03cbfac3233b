"""One GTSAM factor per pose for its balls: every probe point on its ball's sphere and every ball
centre at the forward kinematics, in one Python callback (:func:`pose_balls_factor`), and
:class:`PoseBallRows`, the rows of all these factors evaluated at once for a loop that owns its values.

The rows are those of :func:`~factors.gtsam_factors.probe_factor` and
:func:`~factors.gtsam_factors.ball_centre_factor` (the same unwhitened errors, Jacobians and
sigmas): a pose of 3 balls and 12 probe points is one callback per linearisation instead of 15.
Keep a reference to every factor's arguments: the error closures capture them.
"""
from __future__ import annotations

from functools import lru_cache
from typing import Any

import gtsam
import numpy as np

from .errors import pose_ball_centres_error, probe_error
from .gtsam_factors import PoseKinematics

__all__ = ["PoseBallRows", "pose_balls_factor"]

# A factor's rows: ``(e (r,), [its Jacobian blocks in the order of its keys: J_theta (r, P), J_q (r, n)
# if the joints are a variable, J_c (r, 3) per centre])``.
Rows = tuple[np.ndarray, list[np.ndarray]]


@lru_cache(maxsize=64)
def _noise(n_probe: int, n_centre: int, sigma_probe: float, sigma_kinematic: float):
    """The diagonal noise model of ``n_probe`` probe rows then ``3 n_centre`` centre rows (one object
    for the many factors of the same shape: GTSAM shares it)."""
    sigmas = np.r_[np.full(n_probe, sigma_probe), np.full(3 * n_centre, sigma_kinematic)]
    return gtsam.noiseModel.Diagonal.Sigmas(sigmas)


def _assemble(e_p, J_p, owner, e_k, J_t, J_q, balls, n_balls: int, joints: bool) -> Rows:
    """A pose factor's rows (probe rows first, then 3 per kinematic ball) from its parts.

    Parameters
    ----------
    e_p : (n,) mm; J_p : (n, 3), d e_p / d (its centre); owner : (n,)
    e_k : (K, 3) mm; J_t : (K, 3, P); J_q : (K, 3, nq); balls : (K,), the centre of each
    joints : whether the joints are a variable (their block is one of the factor's)
    """
    n, K = len(e_p), len(balls)
    r = n + 3 * K
    Ht = np.zeros((r, J_t.shape[-1]))
    Ht[n:] = J_t.reshape(3 * K, -1)
    blocks = [Ht]
    if joints:
        Hq = np.zeros((r, J_q.shape[-1]))
        Hq[n:] = J_q.reshape(3 * K, -1)
        blocks.append(Hq)
    for b in range(n_balls):
        Hc = np.zeros((r, 3))
        mine = owner == b
        Hc[:n][mine] = J_p[mine]
        for k in np.flatnonzero(balls == b):  # its centre rows: e = FK offset - c
            Hc[n + 3 * k:n + 3 * k + 3] = -np.eye(3)
        blocks.append(Hc)
    return np.concatenate([e_p, e_k.ravel()]), blocks


def pose_balls_factor(index, held, c_keys, offsets, points, owner, radius: float, sigma_probe: float,
                      sigma_kinematic: float, *, t_key: int, q_key: int | None = None, q_fixed=None, kinematic=None,
                      chain=None, shared: tuple | None = None) -> gtsam.CustomFactor:
    """The balls of one pose in one factor (not robust): each probe point on the sphere of
    ``radius`` around its ball's centre variable, then each ball centre at FK(theta, q) times its offset.

    Parameters
    ----------
    index, held : see :func:`factors.errors.slots_of`.
    c_keys : sequence of int, length B
        The pose's ball-centre variables (Vector 3, mm).
    offsets : array_like, shape (B, 3)
        Each ball's centre in the tool frame (mm).
    points : array_like, shape (n, 3)
        Probe points (mm, world).
    owner : array_like of int, shape (n,)
        The index in ``c_keys`` of each point's ball.
    radius : float
        The probe's ball radius (mm).
    sigma_probe, sigma_kinematic : float
        The sigmas (mm) of a probe row and of a centre's rows.
    t_key, q_key, q_fixed, chain : see :func:`~factors.gtsam_factors.pose_centres_factor`.
    kinematic : array_like of bool, shape (B,), optional
        The balls whose centre rows are in the factor (all by default; the outlier handling may
        exclude some).
    shared : ``(PoseBallRows, pose, slots (B,), centres (B,))``, optional
        Lay this factor's rows out in a :class:`PoseBallRows` its optimiser fills: the pose's row
        of its kinematics, each ball's tool point there and each centre's index among the filled centres.

    Returns
    -------
    gtsam.CustomFactor
        On ``[t_key, q_key (a variable only), *c_keys]``; error ``[|p - c| - radius (n,); FK offset - c (3K,)]`` mm.
    """
    if (q_key is None) == (q_fixed is None):
        raise ValueError("give exactly one of q_key and q_fixed")
    c_keys = [int(k) for k in c_keys]
    B = len(c_keys)
    points = np.array(points, dtype=float).reshape(-1, 3)
    owner = np.array(owner, dtype=int).reshape(-1)
    offsets = np.array(offsets, dtype=float).reshape(-1, 3)
    if len(offsets) != B or len(owner) != len(points) or (len(owner) and not 0 <= owner.min() <= owner.max() < B):
        raise ValueError(f"{B} centre keys, {len(offsets)} offsets; {len(points)} points, owners {owner}")
    balls = np.arange(B) if kinematic is None else np.flatnonzero(np.asarray(kinematic, dtype=bool))
    index = np.array(index, dtype=int)
    held = np.array(held, dtype=float)
    q_const = None if q_fixed is None else np.array(q_fixed, dtype=float).reshape(-1)
    keys = [t_key] + ([q_key] if q_key is not None else []) + c_keys
    cache, handle = None, 0
    if shared is not None:
        cache = shared[0]
        handle = cache.add(shared[1], shared[3], shared[2], points, owner, balls, q_key is not None)

    def own(values) -> Rows:
        theta = values.atVector(t_key)
        q = values.atVector(q_key) if q_const is None else q_const
        centres = np.array([values.atVector(k) for k in c_keys])
        e_p, J_p = probe_error(centres[owner], points, radius)
        if len(balls):
            e_k, J_t, J_q = pose_ball_centres_error(theta, q, offsets[balls], centres[balls], index, held, chain)
        else:
            e_k, J_t, J_q = np.zeros((0, 3)), np.zeros((0, 3, len(theta))), np.zeros((0, 3, len(q)))
        return _assemble(e_p[:, 0], J_p[:, 0], owner, e_k, J_t, J_q, balls, B, q_key is not None)

    def error(this, values, H):
        rows = None if cache is None else cache.rows(handle, values)
        e, blocks = own(values) if rows is None else rows
        if H is not None:
            for i, h in enumerate(blocks):
                H[i] = h
        return e

    return gtsam.CustomFactor(_noise(len(points), len(balls), float(sigma_probe), float(sigma_kinematic)), keys,
                              error)


class PoseBallRows:
    """The rows of every :func:`pose_balls_factor` of a graph, evaluated at once (vectorised over
    the poses) for a loop that owns its ``gtsam.Values`` (fgcal's
    :func:`~fgcal.estimation.gtsam_graph.gtsam_levenberg_marquardt`).

    The loop calls :meth:`fill` with the values it is about to linearise at; a factor's callback
    given that very ``gtsam.Values`` object then only reads its cached blocks (GTSAM passes the
    caller's object to the callbacks, and the object is held here, so no other takes its
    identity); given any other values (another optimiser, a copy) it evaluates its own rows. The
    numbers are the same to rounding (~1e-13 relative) either way. The loop must not change a
    ``gtsam.Values`` once filled (fgcal's moves by ``retract``, which makes a new one).

    Parameters
    ----------
    kinematics : PoseKinematics
        The tool points of every pose (its ``offsets`` (N, B, 3)).
    radius : float
        The probe's ball radius (mm).
    """

    def __init__(self, kinematics: PoseKinematics, radius: float):
        self.kinematics = kinematics
        self.radius = float(radius)
        self._added: list[tuple] = []  # (pose, centres, slots, points, owner, balls, joints) per factor
        self._tables: dict = {}
        self._values = None  # the gtsam.Values last filled

    def add(self, pose: int, centres, slots, points, owner, balls, joints: bool) -> int:
        """Lay out one factor's rows (:func:`pose_balls_factor` calls it); its handle for :meth:`rows`.

        Parameters
        ----------
        pose : int
            The pose (the row of the kinematics' offsets).
        centres : array_like of int, shape (B,)
            The index of each of the factor's centre variables among the ``centres`` of :meth:`fill`.
        slots : array_like of int, shape (B,)
            Each ball's tool point in ``kinematics.offsets[pose]``.
        points : ndarray, shape (n, 3); owner : ndarray of int, shape (n,)
            The factor's probe points (mm) and the index in ``centres`` of each one's ball.
        balls : ndarray of int, shape (K,)
            The balls (indices in ``centres``) with centre rows.
        joints : bool
            Whether the factor's joints are a variable (their Jacobian block is one of its blocks).
        """
        self._added.append((int(pose), np.array(centres, dtype=int).reshape(-1), np.array(slots, dtype=int).reshape(-1),
                            points, owner, balls, bool(joints)))
        self._tables, self._values = {}, None  # laid out again, and filled again, before any rows are read
        return len(self._added) - 1

    def _layout(self) -> dict:
        """Every factor's rows in one flat table (factor f's at ``span[f]``): where each probe row and
        each centre's three rows go; the constant entries (zeros, a centre row's -I) set here once."""
        added = self._added
        start = np.concatenate([[0], np.cumsum([len(a[3]) + 3 * len(a[5]) for a in added])]).astype(int)
        b_max = max((len(a[1]) for a in added), default=0)
        parts: dict[str, list] = {k: [] for k in ("p_row", "p_var", "p_key", "p_xyz", "k_row", "k_pose", "k_slot",
                                                  "k_var", "k_key")}
        for (pose, centres, slots, points, owner, balls, _), a in zip(added, start[:-1]):
            n = len(points)
            parts["p_row"].append(a + np.arange(n))
            parts["p_var"].append(centres[owner])
            parts["p_key"].append(owner)
            parts["p_xyz"].append(points)
            parts["k_row"].append(a + n + 3 * np.arange(len(balls)))
            parts["k_pose"].append(np.full(len(balls), pose))
            parts["k_slot"].append(slots[balls])
            parts["k_var"].append(centres[balls])
            parts["k_key"].append(balls)
        t: dict[str, Any] = {k: np.concatenate(v) if v else np.zeros(0, dtype=int) for k, v in parts.items()}
        t["p_xyz"] = t["p_xyz"].reshape(-1, 3).astype(float)
        t["k_rows"] = t["k_row"][:, None] + np.arange(3)  # (K, 3): a centre's three rows
        R, kin = int(start[-1]), self.kinematics
        t["span"], t["E"], t["Ht"] = start, np.zeros(R), np.zeros((R, len(kin.index)))
        t["Hq"] = None  # (R, n): made by the first fill, which knows the joints' count
        t["Hc"] = np.zeros((b_max, R, 3))  # by the factor's centre: a row's other centres' entries stay 0
        t["Hc"][t["k_key"][:, None], t["k_rows"]] = -np.eye(3)
        return t

    def fill(self, values, theta, q, centres) -> None:
        """Evaluate every factor's rows at ``theta`` (P,), every pose's joints ``q`` (N, n) and the
        centre variables ``centres`` (C, 3) mm: the entries of ``values`` (a ``gtsam.Values``, left
        unchanged while its rows are read), whose factors' callbacks then read them."""
        if not self._tables:
            self._tables = self._layout()
        t, kin = self._tables, self.kinematics
        self._values = None  # (until the rows are whole)
        kin.fill(theta, q)
        C = np.asarray(centres, dtype=float).reshape(-1, 3)
        if t["Hq"] is None:
            t["Hq"] = np.zeros((len(t["E"]), kin.J_q.shape[-1]))
        e, J = probe_error(C[t["p_var"]], t["p_xyz"], self.radius)
        t["E"][t["p_row"]] = e[:, 0]
        t["Hc"][t["p_key"], t["p_row"]] = J[:, 0]
        rows, at = t["k_rows"], (t["k_pose"], t["k_slot"])
        t["E"][rows] = kin.points[at] - C[t["k_var"]]
        t["Ht"][rows] = kin.J_theta[at]
        t["Hq"][rows] = kin.J_q[at]
        if "views" not in t:  # each factor's blocks: views of the tables, which every fill updates in place
            span = t["span"]
            t["views"] = [(t["E"][a:z], [t["Ht"][a:z]] + ([t["Hq"][a:z]] if joints else [])
                           + [t["Hc"][b, a:z] for b in range(len(centres))])
                          for (_, centres, _, _, _, _, joints), a, z in zip(self._added, span[:-1], span[1:])]
        self._values = values

    def rows(self, handle: int, values) -> Rows | None:
        """The factor ``handle``'s ``(e (r,), [J_theta (r, P), J_q (r, n) if its joints are a
        variable, J_c (r, 3) per centre])`` when ``values`` is the ``gtsam.Values`` object last
        filled, else None."""
        if values is not self._values or values is None:
            return None
        return self._tables["views"][handle]
