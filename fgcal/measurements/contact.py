"""Contacts: the tool ball seated at a fixture point or touching a plane (DESIGN.md 8.2).

File ``contacts.csv``: ``pose,ball,fixture``. At this pose the centre of tool ball ``ball`` sits at
fixture point ``fixture`` (a socket, a cone, a pivot), or the ball touches plane ``fixture`` (its
centre ``tool.radius`` from the plane on the side the normal points to). The fixtures are set-up
unknowns (:mod:`fgcal.measurements.setup`); one file holds both kinds, and the dataset keeps them
as two levels, ``contacts`` (points: 3 rows ``FK offset - p``, mm) and ``plane_contacts`` (1 row
``n . (FK offset) - d - r``, mm), each with its own noise component.

The errors depend on the parameters, one pose's joints and one fixture's block:
:meth:`SetupMeasurement.setup_error` gives their Jacobians with respect to all three.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from fgcal.errors import FgcalError
from fgcal.measurements.base import KinematicMeasurement, NoiseComponent, ObservationRows, Terms
from fgcal.measurements.setup import plane_normal
from fgcal.robots.kinematics import tool_points

__all__ = [
    "CONTACT",
    "CONTACT_COLUMNS",
    "CONTACT_FILE",
    "PLANE_CONTACT",
    "ContactObservations",
    "PlaneContact",
    "PointContact",
    "SetupMeasurement",
]

CONTACT_FILE = "contacts.csv"
PLANE_MIN_SPREAD = 5.0  # mm (RMS) of a plane's contacts in their narrower direction: a tilt needs an area
CONTACT_COLUMNS = ("pose", "ball", "fixture")


@dataclass
class ContactObservations(ObservationRows):
    """Contacts, one row each: pose ids (M,), balls (M,), fixture names (M,), file lines (M,)."""

    pose: np.ndarray
    ball: np.ndarray
    fixture: np.ndarray
    line: np.ndarray | None = None

    def __post_init__(self):
        self.fixture = np.asarray(self.fixture, dtype=str).reshape(-1)
        super().__post_init__()


class SetupMeasurement(KinematicMeasurement):
    """A kinematic measurement that also depends on a set-up block (a fixture, a plane).

    ``terms`` takes the solve's :class:`~fgcal.measurements.setup.SetupLayout`; ``setup_error``
    returns, besides the error and its Jacobians in the parameters and the joints, those in the
    block: ``J_s`` (M, width, 3) for the entries ``cols`` (M, 3) of the layout's vector.
    """

    uses_setup = True
    file = CONTACT_FILE
    columns: tuple[str, ...] = CONTACT_COLUMNS
    fixture_type = ""
    noise_key: str | None = "contact_sigma"
    noun = "contact"

    sigma_field = "contact"

    def declared_sigmas(self, noise) -> dict:
        value = dict(noise.extra).get(self.noise_key)
        return {self.sigma_field: float(value if value is not None else noise.cmm_sigma)}

    def sigma(self, sigmas) -> np.ndarray:
        return np.full(self.width, getattr(sigmas, self.sigma_field))

    def error(self, theta, q, data, index, held, chain):
        """The error at given set-up values: ``data`` is the graph's payload followed by the set-up
        vector ``s`` (S,) (as :meth:`design_data` gives it); the Jacobians in theta and the joints
        of :meth:`setup_error` (the one in ``s`` is left out)."""
        *payload, s = data
        return self.setup_error(theta, q, tuple(payload), np.asarray(s, dtype=float), index, held, chain)[:3]

    def setup_error(self, theta, q, data, s, index, held, chain):
        raise NotImplementedError

    def _payload(self, offsets, fixture, layout, radius) -> tuple:
        raise NotImplementedError  # each contact type's

    def observations(self, pose, ball, values, line=None):
        return ContactObservations(pose, ball, values, line)

    def rows(self, obs: Any):
        return ([int(p), b, f] for p, b, f in zip(obs.pose, obs.ball, obs.fixture))

    def parse(self, where, record, balls):
        raise NotImplementedError("contacts.csv is read with the dataset's fixtures (fgcal.io.dataset_io)")

    def design_data(self, forward, offsets, fixture=None, setup=None, radius: float = 0.0) -> tuple:
        """The graph's payload of M contacts followed by the set-up vector: ``(*payload, s)``.

        A contact's Jacobians depend on its fixture's block, so the fixture names ``fixture`` (M,)
        and the set-up layout ``setup`` (:class:`~fgcal.measurements.setup.SetupLayout`) are
        needed; ``s`` is the layout's start, which the caller builds at the geometry designed for
        (fixture points at the mean of the predicted ball centres, planes fitted to them: at the
        true geometry the measurement is noiseless). ``forward`` is not needed (the error is
        evaluated from the joints); ``radius`` (mm) is the tool's.
        """
        if fixture is None or setup is None:
            raise ValueError(f"the design payload of {self.title} needs each contact's fixture and the set-up layout")
        fixture = np.asarray(fixture, dtype=str).reshape(-1)
        return (*self._payload(np.asarray(offsets, dtype=float).reshape(-1, 3), fixture, setup, radius), setup.start)

    def factor(self, data_row, index, held, sigma, *, t_key, q_key=None, q_fixed=None, chain=None, setup=None,
               setup_column=None):
        """The GTSAM factor of one contact on the parameter vector ``t_key`` (and ``q_key``).

        The set-up blocks are entries of the parameter vector (they close ``theta``, as in the
        batch graph): ``setup`` is the layout and ``setup_column`` the column of its first free
        entry in ``theta`` (geometry, then a joint-error block, then the set-up entries). The
        Jacobian is :meth:`setup_error`'s: the geometric columns, then ``J_s`` scattered at the
        free entries of the contact's block (the geometry is ``theta[:len(index)]``).
        """
        import factors as fx

        if setup is None or setup_column is None:
            raise ValueError(f"the GTSAM factor of {self.title} needs the set-up layout and its column in theta")
        data = tuple(np.asarray(d)[None] for d in data_row)
        column = setup.column()
        n_geo = len(index)

        def error_fn(theta, q, i, h, c):
            s = setup.full(theta[setup_column:])
            e, J_t, J_q, J_s, cols = self.setup_error(theta[:n_geo], q, data, s, i, h, c)
            J = np.zeros(J_t.shape[:2] + (len(theta),))
            J[:, :, :n_geo] = J_t
            where = column[cols[0]]
            free = where >= 0
            J[0][:, setup_column + where[free]] += J_s[0][:, free]
            return e, J, J_q

        return fx.kinematic_factor(error_fn, fx.noise_model(sigma), index, held, t_key=t_key, q_key=q_key,
                                   q_fixed=q_fixed, chain=chain)

    def simulate(self, T, offsets, rng, noise) -> np.ndarray:
        raise NotImplementedError(f"fgcal's simulator does not simulate {self.title}")

    def blocks_of(self, obs) -> np.ndarray:
        """The set-up block of each observation (M,) (names in ``dataset.yaml``)."""
        return obs.fixture

    def block_starts(self, obs, T, tooling, unknown, where) -> dict:
        """Start values of the blocks in ``unknown`` that ``obs`` uses, from the tool poses ``T`` (M, 4, 4)
        at the start geometry: a fixture point at the mean of its predicted ball centres, a plane
        fitted to them with its normal towards the tool."""
        pts = tool_points(T, tooling.offsets(obs.ball)[:, None, :])[:, 0]
        out = {}
        # each fixture's rows, in their order, from one sort (a comparison of every row's name per
        # fixture: 0.28 ms at 66 sockets and 1,000 contacts)
        names, first, inverse = np.unique(obs.fixture, return_index=True, return_inverse=True)
        order = np.argsort(inverse.ravel(), kind="stable")
        cuts = np.cumsum(np.bincount(inverse.ravel(), minlength=len(names)))[:-1]
        rows_of = dict(zip(names.tolist(), np.split(order, cuts)))
        for f in names[np.argsort(first)].tolist():  # in the order of first appearance
            if f not in unknown:
                continue
            sel = rows_of[f]
            c = pts[sel]
            if self.fixture_type == "point":
                out[f] = c.mean(axis=0)
                continue
            # one thin SVD for the spread and the normal (the full one formed a (k, k) U: 1000 contacts, 8 MB)
            sv, vt = np.linalg.svd(c - c.mean(0), full_matrices=False)[1:] if len(c) >= 3 else (None, None)
            spread = sv[1] / np.sqrt(len(c)) if sv is not None else 0.0
            if vt is None or spread < PLANE_MIN_SPREAD:
                raise FgcalError(f"{where}: plane {f} needs contacts at three or more points spread over an area, "
                                 f"not near one point or one line (it has {len(c)}, {spread:.3g} mm across (RMS) "
                                 f"in its narrower direction; at least {PLANE_MIN_SPREAD:g})")
            n = vt[2]
            if np.mean((T[sel, :3, 3] - c) @ n) < 0:
                n = -n
            out[f] = (n, float(np.mean(c @ n)) - tooling.radius)
        return out

    def _ball_points(self, theta, q, offset, index, held, chain):
        from factors.errors import ball_centre_error

        return ball_centre_error(theta, q, offset, np.zeros((len(offset), 3)), index, held, chain)


class PointContact(SetupMeasurement):
    """The ball centre at a fixture point: 3 rows ``FK offset - p`` (mm)."""

    level = "contacts"
    fixture_type = "point"
    measures_length = False  # at unknown points: scaling the robot and the points scales the errors alike
    width = 3
    title = "contacts at fixture points"
    noise_components = (NoiseComponent("contacts", slice(0, 3), "contact"),)

    def terms(self, obs: ContactObservations, tooling, row_of_pose, layout=None) -> Terms:
        pose = np.array([row_of_pose[p] for p in obs.pose.tolist()], dtype=int)
        return Terms(pose, self._payload(tooling.offsets(obs.ball).reshape(-1, 3), obs.fixture, layout,
                                         tooling.radius))

    def _payload(self, offsets, fixture, layout, radius) -> tuple:
        """Ball offsets (M, 3) and each fixture's first entry in ``s`` (M,)."""
        return offsets, _per_row(fixture, lambda f: layout.offset[f]).astype(int)

    def setup_error(self, theta, q, data, s, index, held, chain):
        offset, start = data
        cols = start[:, None] + np.arange(3)
        p, J_t, J_q = self._ball_points(theta, q, offset, index, held, chain)
        J_s = np.broadcast_to(-np.eye(3), (len(start), 3, 3))
        return p - s[cols], J_t, J_q, J_s, cols

    def metric(self, e):
        return np.linalg.norm(e, axis=1), None

    def residual_summary(self, e) -> dict:
        return {"contacts_mm": np.asarray(e).ravel().tolist()}


class PlaneContact(SetupMeasurement):
    """The ball touching a plane: 1 row ``n . (FK offset) - d - radius`` (mm)."""

    level = "plane_contacts"
    fixture_type = "plane"
    measures_length = False  # on unknown planes: scaling the robot and the offsets scales the errors alike
    width = 1
    title = "contacts on planes"
    sigma_field = "plane_contact"  # declared as contact_sigma, estimated apart from the points'
    noise_components = (NoiseComponent("plane_contacts", slice(0, 1), "plane_contact"),)

    def terms(self, obs: ContactObservations, tooling, row_of_pose, layout=None) -> Terms:
        pose = np.array([row_of_pose[p] for p in obs.pose.tolist()], dtype=int)
        return Terms(pose, self._payload(tooling.offsets(obs.ball).reshape(-1, 3), obs.fixture, layout,
                                         tooling.radius))

    def _payload(self, offsets, fixture, layout, radius) -> tuple:
        """Ball offsets (M, 3), each plane's first entry in ``s`` (M,), its reference normal (M, 3)
        and the tool's radius (M,)."""
        start = _per_row(fixture, lambda f: layout.offset[f]).astype(int)
        n0 = _per_row(fixture, lambda f: layout.reference[f]).reshape(-1, 3)
        return offsets, start, n0, np.full(len(start), float(radius))

    def setup_error(self, theta, q, data, s, index, held, chain):
        from factors.errors import ball_centre_along

        offset, start, n0, radius = data
        m = len(start)
        n_all = np.empty((m, 3))
        # Rows share a plane: its normal is computed once per plane.
        planes = []
        for k in np.unique(start):
            rows = np.nonzero(start == k)[0]
            n, dn = plane_normal(n0[rows[0]], s[k:k + 2])
            n_all[rows] = n
            planes.append((k, rows, n, dn))
        # One row a contact: the kinematics give n . (the point's Jacobians), not the (m, 3, P) ones.
        p, J_t, J_q = ball_centre_along(theta, q, offset, n_all, index, held, chain)
        e = np.empty((m, 1))
        J_s = np.empty((m, 1, 3))
        for k, rows, n, dn in planes:
            e[rows, 0] = p[rows] @ n - s[k + 2] - radius[rows]
            J_s[rows, 0, :2] = p[rows] @ dn
            J_s[rows, 0, 2] = -1.0
        cols = start[:, None] + np.arange(3)
        return e, J_t, J_q, J_s, cols

    def metric(self, e):
        return np.abs(np.asarray(e)[:, 0]), None

    def residual_summary(self, e) -> dict:
        return {"plane_contacts_mm": np.asarray(e)[:, 0].tolist()}


def _per_row(fixture, value) -> np.ndarray:
    """``value(f)`` of each row's fixture ``f`` (M, ...): once per distinct fixture, then spread over the rows."""
    names, which = np.unique(np.asarray(fixture).astype(str), return_inverse=True)
    return np.array([value(f) for f in names.tolist()])[which.ravel()]


CONTACT = PointContact()
PLANE_CONTACT = PlaneContact()
