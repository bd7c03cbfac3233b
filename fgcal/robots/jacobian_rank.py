"""The rank of an identification Jacobian: which parameters a set of poses can tell apart.

:func:`analyse` (a Jacobian) and :func:`analyse_information` (an information matrix) name the
parameters that are combinations of earlier ones; :func:`slot_jacobian` stacks a chain's
Jacobian for chosen slots, and :func:`minimal_parameters` prunes a model's candidate parameters
to an independent set with them (what :meth:`fgcal.robots.model.RobotModel.identifiable_names`
uses). :mod:`fgcal.robots.identifiability` gives the same on a
:class:`~fgcal.robots.model.ParameterSet`. No I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Identifiability", "ScaledSpectrum", "analyse", "analyse_information", "minimal_parameters", "slot_jacobian"]


def slot_jacobian(chain, x, q, idx, measurement="pose", orientation_scale: float = 100.0) -> np.ndarray:
    """Stacked Jacobian of the measurements with respect to the slots ``idx`` (P,) of ``chain``
    (a :class:`fgcal.robots.kinematics.Chain`) at slot vector ``x`` (S,; mm, rad) and joint
    readings ``q`` (N, n); ``measurement`` and ``orientation_scale`` as in
    :func:`fgcal.robots.identifiability.identification_jacobian`. Returns (M, P), mm per internal unit.
    """
    q = chain.check_joints(q)
    x = np.asarray(x, dtype=float)
    idx = np.asarray(idx, dtype=int)
    if isinstance(measurement, str):
        jac = chain.jacobians(x, q)
        J = jac.pose_slots[:, :, idx]
        if measurement == "pose":
            J = J * np.array([1, 1, 1, orientation_scale, orientation_scale, orientation_scale])[None, :, None]
        elif measurement == "position":
            J = J[:, :3]
        else:
            raise ValueError(f"measurement must be 'pose', 'position' or (B, 3) points, got {measurement!r}")
        return J.reshape(-1, len(idx))
    if np.ndim(measurement) == 2:  # the same points at every pose: only their slot columns
        return chain.point_slot_jacobian(x, q, measurement, idx)
    jac = chain.jacobians(x, q, offsets=measurement)
    return jac.point_slots[..., idx].reshape(-1, len(idx))


@dataclass
class Identifiability:
    """What a pose set can identify.

    Attributes
    ----------
    names : list of str
        Parameter names, in the order of the Jacobian's columns.
    singular_values : ndarray, shape (P,)
        Of the column-scaled Jacobian, descending.
    rank : int
        Numerical rank.
    condition_number : float
        Largest over smallest singular value (inf when rank deficient).
    redundant : dict of str to list of str
        Each parameter that is a combination of earlier ones, with those it depends on.
    """

    names: list[str]
    singular_values: np.ndarray
    rank: int
    condition_number: float
    redundant: dict[str, list[str]]

    @property
    def identifiable(self) -> list[str]:
        return [n for n in self.names if n not in self.redundant]

    def summary(self) -> str:
        lines = [f"rank {self.rank} of {len(self.names)}; condition number {self.condition_number:.4g}"]
        for name, others in self.redundant.items():
            lines.append(f"  {name} cannot be separated from: {', '.join(others) or '(zero column)'}")
        return "\n".join(lines)


def analyse(J, names, scale=None, rtol: float = 1e-7) -> Identifiability:
    """Rank, singular values and redundant parameters of an identification Jacobian.

    Parameters
    ----------
    J : array_like, shape (M, P)
    names : sequence of str, length P
        Column names; a column is blamed only when it is a combination of *earlier* columns, so
        put the parameters you trust first.
    scale : array_like, shape (P,), optional
        Column scales (for example expected parameter errors in internal units); the columns are
        normalised to unit length when omitted.
    rtol : float
        Relative tolerance for a singular value, and for a column's residual after projection on
        the earlier columns, to count as zero.
    """
    J = np.asarray(J, dtype=float)
    names = list(names)
    if J.ndim != 2 or J.shape[1] != len(names):
        raise ValueError(f"J must have shape (M, {len(names)}), got {J.shape}")
    if scale is None:
        norms = np.linalg.norm(J, axis=0)
        scale = np.where(norms > 0, 1.0 / np.where(norms > 0, norms, 1.0), 1.0)
    Js = J * np.asarray(scale, dtype=float)[None, :]
    sv = np.linalg.svd(Js, compute_uv=False)
    rank = int(np.sum(sv > rtol * sv[0])) if sv.size and sv[0] > 0 else 0
    cond = float(sv[0] / sv[-1]) if rank == len(names) else float("inf")

    # Gram-Schmidt in column order: a column with no component outside the span of the accepted
    # ones is redundant; its least-squares coefficients say with which parameters.
    redundant: dict[str, list[str]] = {}
    accepted: list[int] = []
    col_norms = np.linalg.norm(Js, axis=0)
    ref = max(col_norms.max(initial=0.0), 1e-300)
    for k in range(len(names)):
        col = Js[:, k]
        if col_norms[k] <= rtol * ref:
            redundant[names[k]] = []
            continue
        if accepted:
            A = Js[:, accepted]
            coef, *_ = np.linalg.lstsq(A, col, rcond=None)
            resid = np.linalg.norm(col - A @ coef)
            if resid <= np.sqrt(rtol) * col_norms[k]:
                weight = np.abs(coef) * np.linalg.norm(A, axis=0)
                partners = [names[accepted[i]] for i in np.argsort(-weight) if weight[i] > 1e-3 * col_norms[k]]
                redundant[names[k]] = partners
                continue
        accepted.append(k)
    return Identifiability(names=names, singular_values=sv, rank=rank, condition_number=cond, redundant=redundant)


class ScaledSpectrum:
    """The eigenvalues of a symmetric ``S`` (P, P) scaled to unit diagonal, its vectors on demand.

    Scaled by ``1 / sqrt(diag(S))`` where the diagonal is live (above ``1e-12`` of the largest
    square root), by 0 where it is not (such a parameter is its own null direction). The values
    alone (``numpy.linalg.eigvalsh``) cost a third of the decomposition with vectors (1.5 ms against
    4.2 ms at P = 228, a contact dataset's 198 socket coordinates beside the robot's): the vectors are
    computed, with the values again from the same decomposition, only when a caller needs them (a
    weak direction to name).

    Parameters
    ----------
    S : array_like, shape (P, P)
        A symmetric information matrix.
    floor : float
        The share of the largest square root of the diagonal below which a parameter is not live
        (0: every parameter with a positive diagonal is scaled by it).
    """

    def __init__(self, S, floor: float = 1e-12) -> None:
        S = np.asarray(S, dtype=float)
        d = np.sqrt(np.maximum(np.diag(S), 0.0))
        self.live = d > floor * max(d.max(initial=0.0), 1e-300)
        self.scale = np.where(self.live, 1.0 / np.where(self.live, d, 1.0), 0.0)
        self._scaled = S * np.outer(self.scale, self.scale)
        self.values = np.linalg.eigvalsh(self._scaled)  # ascending
        self._vectors: np.ndarray | None = None

    @property
    def vectors(self) -> np.ndarray:
        """The eigenvectors (P, P), columns in the order of :attr:`values` (which they replace with the
        values of the same decomposition)."""
        if self._vectors is None:
            self.values, self._vectors = np.linalg.eigh(self._scaled)
        return self._vectors


def analyse_information(S, names, rtol: float = 1e-6, spectrum: ScaledSpectrum | None = None) -> Identifiability:
    """Identifiability from an information matrix ``S`` (P, P), for example a Schur complement.

    ``S`` is scaled to unit diagonal; eigenvalues below ``rtol`` times the largest span the
    unidentifiable directions. For each such direction the *last* parameter (in ``names``'
    order) taking part in it is blamed, with the others in it as its partners; put the
    parameters you trust first. ``rtol`` is on eigenvalues (squared singular values): a Schur
    complement computed in floating point is only good to about 1e-8 of its largest eigenvalue.
    ``spectrum``: the :class:`ScaledSpectrum` of ``S`` when the caller has it already.
    """
    names = list(names)
    spectrum = ScaledSpectrum(S) if spectrum is None else spectrum
    live = spectrum.live
    top = max(spectrum.values.max(initial=0.0), 1e-300)
    null = np.zeros((len(names), 0))
    if (spectrum.values < rtol * top).any():  # directions to name: the vectors
        eigvec = spectrum.vectors
        top = max(spectrum.values.max(initial=0.0), 1e-300)
        null = eigvec[:, spectrum.values < rtol * top]
    eigval = spectrum.values
    redundant: dict[str, list[str]] = {n: [] for n, ok in zip(names, live) if not ok}
    for dead in np.nonzero(~live)[0]:  # a parameter nothing constrains is its own null direction
        null = null - np.outer(np.eye(len(names))[dead], null[dead])
    while null.shape[1]:
        u, s, _ = np.linalg.svd(null, full_matrices=False)
        null = u[:, s > 1e-6]
        if not null.shape[1]:
            break
        weight = np.linalg.norm(null, axis=1)
        candidates = [i for i in range(len(names)) if weight[i] > 0.1 * weight.max() and names[i] not in redundant]
        i = int(candidates[-1])
        v = null @ null[i] / np.linalg.norm(null[i])
        v /= np.linalg.norm(v)
        order = np.argsort(-np.abs(v))
        redundant[names[i]] = [names[j] for j in order if j != i and abs(v[j]) > 0.05 * abs(v[i])]
        # keep only null directions without parameter i
        _, _, vt = np.linalg.svd(null[i][None, :])
        null = null @ vt[1:].T
    sv = np.sqrt(np.clip(eigval, 0.0, None))[::-1]
    rank = len(names) - len(redundant)
    cond = float(sv[0] / sv[rank - 1]) if rank == len(names) and sv[rank - 1] > 0 else float("inf")
    return Identifiability(names=names, singular_values=sv, rank=rank, condition_number=cond, redundant=redundant)


def minimal_parameters(model, candidates, n_configurations: int = 64, rtol: float = 1e-8):
    """Prune ``candidates`` (slot names, in order of preference) to an independent set.

    The full-pose identification Jacobian at ``n_configurations`` joint sets spread over the
    joint limits (a fixed seed: the answer depends on the model only) is scaled column by column;
    a candidate whose column lies in the span of the kept ones is dropped. Slots outside
    ``candidates`` are not checked: the rule that proposes them says why they are left out.

    Parameters
    ----------
    model : fgcal.robots.model.RobotModel
        Its chain, nominal slots and joint limits are used (unannotated: the model module imports
        this one to name its identifiable parameters).
    candidates : sequence of str
        Slot names, in order of preference.
    n_configurations : int
        Joint sets sampled.
    rtol : float
        As in :func:`analyse`.

    Returns
    -------
    names : tuple of str
        The kept parameters, in ``candidates`` order.
    dropped : dict of str to str
        Each dropped candidate with the reason (the parameters it cannot be separated from).
    """
    rng = np.random.default_rng(20260101)
    lo, hi = model.joint_limits[:, 0], model.joint_limits[:, 1]
    # Wide (+-360 deg) limits sample the same set as +-180: keep revolute samples in one turn.
    span = np.where(model.joint_is_angle, np.minimum(hi - lo, 2 * np.pi), hi - lo)
    q = lo + rng.uniform(0.0, 1.0, size=(n_configurations, model.n_joints)) * span
    names = tuple(candidates)
    reach = max(float(np.sum(np.abs(model.nominal[~model.slot_is_angle]))), 100.0)
    J = slot_jacobian(model.chain, model.nominal, q, [model.slot(n) for n in names], "pose", reach)
    found = analyse(J, names, rtol=rtol)
    dropped = {n: ("cannot be separated from " + ", ".join(p) if p else "no motion of the chain moves it")
               for n, p in found.redundant.items()}
    return tuple(n for n in names if n not in found.redundant), dropped
