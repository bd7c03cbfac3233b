"""The parameters of a solve with set-up unknowns: the robot's (and a joint-error block's) then the
free entries of a :class:`~fgcal.measurements.setup.SetupLayout` (fixture points, planes).

Duck-types :class:`~fgcal.robots.model.ParameterSet` as :class:`~fgcal.estimation.joint_errors.BlockParameters`
does: ``index`` and ``full`` concern the robot's slots only; ``names``, ``units``, ``nominal``,
``take`` and the unit conversions cover everything. No I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from fgcal.measurements.setup import SetupLayout

__all__ = ["SetupParameters", "is_setup_name"]


def is_setup_name(name: str) -> bool:
    """Whether ``name`` is a set-up unknown's parameter (``fixture.A.x``, ``plane.T.d``, ``station.B.phi``,
    or a registered block kind's prefix)."""
    from fgcal.measurements.setup import BLOCK_KINDS

    first = name.split(".", 1)[0]
    return any(k.prefix == first for k in BLOCK_KINDS.values())


@dataclass(frozen=True)
class SetupParameters:
    """``inner`` (a ParameterSet or BlockParameters) followed by the layout's free entries."""

    inner: Any  # a ParameterSet or BlockParameters (duck-typed alike)
    layout: SetupLayout

    @property
    def model(self):
        return self.inner.model

    @property
    def n_inner(self) -> int:
        return len(self.inner)

    @property
    def n_geometric(self) -> int:
        return getattr(self.inner, "n_geometric", len(self.inner))

    @property
    def geometric(self):
        return getattr(self.inner, "geometric", self.inner)

    @property
    def block(self):
        return getattr(self.inner, "block", None)

    @property
    def names(self) -> tuple:
        return tuple(self.inner.names) + tuple(self.layout.names())

    @property
    def index(self) -> np.ndarray:
        return self.inner.index

    @property
    def units(self) -> list[str]:
        return list(self.inner.units) + ["deg" if a else "mm" for a in self.layout.is_angle()]

    def __len__(self) -> int:
        return self.n_inner + self.layout.n_free

    def nominal(self) -> np.ndarray:
        return np.concatenate([self.inner.nominal(), self.layout.start[self.layout.free]])

    def full(self, values, held=None) -> np.ndarray:
        return self.inner.full(np.asarray(values, dtype=float)[: self.n_inner], held)

    def take(self, slots) -> np.ndarray:
        return np.concatenate([self.inner.take(slots), self.layout.start[self.layout.free]])

    def setup_vector(self, values) -> np.ndarray:
        """The layout's whole vector (fixed entries included) for parameter values ``values``."""
        return self.layout.full(np.asarray(values, dtype=float)[self.n_inner:])

    def _scale(self) -> np.ndarray:
        return np.where(self.layout.is_angle(), np.degrees(1.0), 1.0)

    def to_file_units(self, values) -> np.ndarray:
        values = np.asarray(values, dtype=float)
        return np.concatenate([self.inner.to_file_units(values[..., : self.n_inner]),
                               values[..., self.n_inner:] * self._scale()], axis=-1)

    def from_file_units(self, values) -> np.ndarray:
        values = np.asarray(values, dtype=float)
        return np.concatenate([self.inner.from_file_units(values[..., : self.n_inner]),
                               values[..., self.n_inner:] / self._scale()], axis=-1)

    def covariance_to_file_units(self, cov) -> np.ndarray:
        k = self.n_inner
        eye = np.eye(k)
        inner_scale = np.diag(self.inner.covariance_to_file_units(eye)) ** 0.5  # a diagonal unit scaling
        s = np.concatenate([inner_scale, self._scale()])
        return np.asarray(cov) * np.outer(s, s)
