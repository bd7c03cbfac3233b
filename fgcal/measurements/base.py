"""The measurement plug-in protocol: what one measurement type defines, once, for every consumer.

A *kinematic* measurement is a function of the parameters and one pose's joint variables only:
``e(theta, q; data)`` (a ball centre or a tracker reflector, a full pose, a ballbar length). Its
type defines, in its own module,

- the dataset level it fills and its file (name and columns, the parsing of one row, the rows it
  writes);
- its error function and Jacobians (a function of the ``factors`` package), the sigma of each of
  its rows, and its GTSAM factor;
- the graph's data for its observations (which pose, which payload);
- its simulation, its verification metric and its rows in the design information.

The batch graph, the GTSAM graph, the identifiability check, ``design``, ``simulate``, ``verify``
and the dataset files loop over :data:`fgcal.measurements.types.KINEMATIC_TYPES`; adding a type is one
new module plus its line there. Probe points (:mod:`fgcal.measurements.probe`) are the one level with
variables of their own (ball centres) and are handled by the graph directly. No I/O here.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, fields

import numpy as np

__all__ = ["KinematicMeasurement", "NoiseComponent", "ObservationRows", "Terms"]


@dataclass(frozen=True)
class NoiseComponent:
    """A variance component of a measurement type: some of its error rows and the sigma they share.

    Attributes
    ----------
    name : str
        Its name in results (``"poses_rotation"``).
    columns : slice
        Its rows among the type's ``width`` error rows.
    sigma_field : str
        The field of the graph's ``Sigmas`` that holds its sigma.
    unit : str
        The unit a report shows it in; ``to_unit`` converts from internal units (mm, rad).
    """

    name: str
    columns: slice
    sigma_field: str
    unit: str = "mm"
    to_unit: float = 1.0


@dataclass(frozen=True)
class Terms:
    """The factors of one kinematic measurement type in a graph.

    Attributes
    ----------
    pose : ndarray of int, shape (M,)
        Index of each measurement's pose in the graph (not the dataset's pose id).
    data : tuple of ndarray
        The type's payload, each array with M rows (for example ball offsets and measured points).
    """

    pose: np.ndarray
    data: tuple

    def __len__(self):
        return len(self.pose)

    def take(self, rows) -> Terms:
        return Terms(self.pose[rows], tuple(np.asarray(d)[rows] for d in self.data))


class ObservationRows:
    """Per-row arrays of one measurement level (a base of the levels' dataclasses).

    The dataclass has ``pose`` (M,) ids, optionally ``ball`` (M,) names, float arrays whose row
    shapes are in ``ROW_SHAPES`` (``{"xyz": (3,)}``) and ``line`` (M,), the file line (0 when made
    in memory). Converts them, checks their lengths, and gives ``len`` and ``subset``.
    """

    ROW_SHAPES: dict = {}

    def __post_init__(self):
        self.pose = np.asarray(self.pose, dtype=int).reshape(-1)
        if hasattr(self, "ball"):
            self.ball = np.asarray(self.ball, dtype=str).reshape(-1)
        for name, shape in self.ROW_SHAPES.items():
            setattr(self, name, np.asarray(getattr(self, name), dtype=float).reshape((-1, *shape)))
        self.line = np.zeros(len(self.pose), dtype=int) if self.line is None else np.asarray(self.line, dtype=int)
        names = [f.name for f in fields(self)]
        if len({len(getattr(self, n)) for n in names}) > 1:
            raise ValueError(f"{', '.join(names[:-1])} and {names[-1]} must have the same length")

    def __len__(self):
        return len(self.pose)

    def subset(self, mask):
        """The rows selected by ``mask`` (a boolean mask or indices)."""
        return type(self)(**{f.name: getattr(self, f.name)[mask] for f in fields(self)})


class KinematicMeasurement(ABC):
    """One measurement type whose error depends on ``theta`` and one pose's joints only.

    Attributes
    ----------
    level : str
        The dataset attribute and the level name in results (``"centres"``).
    file : str
        The dataset file (``"centres.csv"``).
    columns : tuple of str
        Its header.
    width : int
        Error rows per measurement.
    per_ball : bool
        Whether a pose has one measurement per tool ball (else one per pose).
    title : str
        What a person calls it, for reports.
    noun : str
        One measurement, in messages (``"centre"``).
    noise_components : tuple of NoiseComponent
        Its variance components, estimated from the residuals (:mod:`fgcal.estimation.noise`).
    """

    level: str
    file: str
    columns: tuple
    width: int
    per_ball: bool = True
    title: str = ""
    noun: str = "measurement"
    noise_components: tuple = ()

    # ------------------------------------------------------------------ model
    @abstractmethod
    def error(self, theta, q, data, index, held, chain):
        """Unwhitened error ``(M, width)`` and Jacobians ``(M, width, P)``, ``(M, width, n)``."""

    def declared_sigmas(self, noise) -> dict:
        """Sigmas of a type beyond the built-in ones, ``{field: sigma}`` (mm, rad), from the dataset's
        ``Noise``; the built-in types' are fields of ``Sigmas`` and return nothing."""
        return {}

    @abstractmethod
    def sigma(self, sigmas) -> np.ndarray:
        """The standard deviation of each of its rows ``(width,)`` (mm, rad) from the graph's ``Sigmas``."""

    def reported_sigma(self, sigmas) -> tuple:
        """The sigma a report shows: ``(distance (mm), angle (deg) or None)``, as :meth:`metric` measures."""
        return float(self.sigma(sigmas)[0]), None

    @abstractmethod
    def terms(self, obs, tooling, row_of_pose) -> Terms:
        """The graph's terms of the observations ``obs``; ``row_of_pose`` maps a pose id to its index."""

    def factor(self, data_row, index, held, sigma, *, t_key, q_key=None, q_fixed=None, chain=None):
        """The GTSAM factor of one measurement (``data_row``: one row of each payload array): its
        :meth:`error` as a :func:`factors.gtsam_factors.kinematic_factor` with the noise ``sigma`` (width,)."""
        import factors as fx

        data = tuple(np.asarray(d)[None] for d in data_row)
        n_geo = len(index)

        def error_fn(theta, q, i, h, c):
            # theta may go on past the geometry (a joint-error block, set-up entries): no part of this error
            e, J_t, J_q = self.error(theta[:n_geo], q, data, i, h, c)
            if len(theta) > n_geo:
                J_t = np.concatenate([J_t, np.zeros(J_t.shape[:2] + (len(theta) - n_geo,))], axis=2)
            return e, J_t, J_q

        return fx.kinematic_factor(error_fn, fx.noise_model(sigma), index, held, t_key=t_key, q_key=q_key,
                                   q_fixed=q_fixed, chain=chain)

    def world_points(self, terms: Terms) -> dict:
        """Tool-frame points and where they were measured, per graph pose ``{i: (offsets (k, 3), world (k, 3))}``,
        for the rigid fit of the starting base; empty for types that do not place points."""
        return {}

    # ------------------------------------------------------------------ design
    @abstractmethod
    def design_data(self, forward, offsets) -> tuple:
        """A payload at which the error's Jacobians are those of a noiseless measurement.

        ``forward`` (M, 4, 4): the tool poses of the M measurements; ``offsets`` (M, 3): their
        balls (ignored by per-pose types).
        """

    # ------------------------------------------------------------------ data
    @abstractmethod
    def simulate(self, T, offsets, rng: np.random.Generator, noise) -> np.ndarray:
        """Noisy measurements of the true tool poses ``T`` (M, 4, 4) and balls ``offsets`` (M, 3), as
        the values (M, k) :meth:`parse` gives for a file row; ``noise`` is the dataset's ``Noise``."""

    @abstractmethod
    def parse(self, where: str, record: dict, balls: dict) -> tuple:
        """One file row (a dict of column to text; its pose is read by the caller) as
        ``(ball or "", values (k,))``; raises ``DatasetError`` naming ``where``."""

    @abstractmethod
    def observations(self, pose, ball, values, line=None):
        """The level's observations from rows: pose ids (M,), balls (M,), values (M, k), file lines (M,)."""

    @abstractmethod
    def rows(self, obs):
        """The file rows of ``obs`` (without the header), in order."""

    @abstractmethod
    def metric(self, e):
        """Verification metric of errors ``e`` (M, width): ``(distance (M,) mm, angle (M,) deg or None)``."""

    @abstractmethod
    def residual_summary(self, e) -> dict:
        """Named residual lists (mm, deg) of its errors ``e`` (M, width), for the result."""
