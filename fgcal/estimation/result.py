"""Calibration results (``fgcal-result/1``, JSON): a typed dataclass, saved and loaded atomically."""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np

from fgcal.errors import FgcalError
from fgcal.estimation.noise import LevelNoise, Outlier
from fgcal.estimation.result_json import dumps as _dumps
from fgcal.estimation.result_json import json_float as _float
from fgcal.estimation.result_json import json_safe as _json_safe  # noqa: F401 (re-exported for the tests)
from fgcal.estimation.result_setup import check_setup
from fgcal.estimation.result_tooling import check_tooling
from fgcal.robots.model import SLOT_NAMES, slots_from_file_units
from fgcal.util.numbers import finite_number
from fgcal.util.yamlio import atomic_write_text

__all__ = [
    "FORMAT",
    "CalibrationResult",
    "LevelSummary",
    "ParameterEstimate",
    "PoseResidual",
    "ResidualSummary",
    "load_result",
    "save_result",
]

FORMAT = "fgcal-result/1"
MAX_RESULT_BYTES = 1 << 30


@dataclass
class ParameterEstimate:
    """One identified parameter in file units (mm or deg)."""

    name: str
    unit: str
    nominal: float
    estimate: float
    sigma: float


@dataclass
class LevelSummary:
    """Residuals of one measurement level after the solve.

    ``rms`` is in ``unit`` (mm; for poses the position part, with ``rms_rotation_deg`` beside);
    ``sigma`` is the noise assumed; ``variance_factor`` is the sum of squared whitened residuals
    over the level's redundancy: near 1 when the assumed noise is right.
    """

    n: int
    rms: float
    unit: str
    sigma: float
    variance_factor: float
    redundancy: float
    rms_rotation_deg: float | None = None
    sigma_rotation_deg: float | None = None


@dataclass
class ResidualSummary:
    """RMS residual of one level over ``n`` measurements (``unit``; poses also in rotation)."""

    n: int
    rms: float
    unit: str
    rms_rotation_deg: float | None = None


@dataclass
class PoseResidual:
    """What the calibrated model misses at one calibration pose (mm; deg for rotations).

    The position residuals of a pose are its probe points' distances off their spheres, its
    measured centres' and poses' position errors (vector lengths) and its ballbar length errors.

    Attributes
    ----------
    pose : int
        Pose id.
    n : int
        Measurements of the pose that entered the solve.
    rms_mm : float
        RMS of those residuals with the joints at their readings and the ball centres on the
        kinematics: the training error a user of the readings sees.
    moved_mm : float
        The same after the joint variables moved to absorb the readings' noise (equal to
        ``rms_mm`` when the readings are exact).
    nominal_mm : float
        At the readings with the nominal geometry (the base fitted to the data: the solve's start).
    max_mm : float
        The largest single residual at the readings.
    excluded : int
        Measurements of the pose excluded as gross errors (named in ``outliers``).
    rotation_deg : float or None
        RMS rotation error of the pose's measured orientations at the readings.
    """

    pose: int
    n: int
    rms_mm: float
    moved_mm: float
    nominal_mm: float
    max_mm: float
    excluded: int = 0
    rotation_deg: float | None = None


@dataclass
class CalibrationResult:
    """What a calibration found, and how far to trust it.

    Attributes
    ----------
    robot : str
        Model reference as the dataset named it.
    n_poses : int
    parameters : list of ParameterEstimate
        The identified parameters in DESIGN.md order.
    covariance : ndarray, shape (P, P)
        Joint covariance in file units.
    slots : dict of str to float
        All 37 slots of the calibrated chain (file units), held ones included.
    held : list of dict
        Parameters the data could not identify: ``{"name", "value", "reason"}``.
    levels : dict of str to LevelSummary
    singular_values : list of float
        Of the information matrix scaled to unit diagonal (square roots of its eigenvalues).
    residuals : dict of str to list of float
        Unwhitened residuals at the solution, per level: ``probes_mm`` (signed distance off the
        sphere), ``centres_mm`` and ``poses_position_mm`` (per coordinate), ``poses_rotation_deg``
        (per rotation-vector component), ``joints_deg`` (joint minus reading).
    tool_xyz : list of [x, y, z]
        Calibrated tool origin at each pose used (mm, world), for plots of where the poses were.
    robot_model : dict
        The nominal robot model (``fgcal-robot/1`` as a mapping), so a result stands on its own.
    joint_errors : dict
        The non-geometric joint-error block, if any (:mod:`fgcal.estimation.joint_errors`): ``spec``,
        ``names``, ``map_terms``, ``joint_ranges_deg`` (the region a map is valid in), ``validity``
        and, after a model comparison, ``selection`` (:mod:`fgcal.estimation.model_select`). Empty for the
        geometric model.
    setup : dict
        The set-up unknowns (DESIGN.md 8.1), if any: ``fixtures`` (the dataset's definitions, as in
        ``dataset.yaml``), ``constraints`` and ``estimated`` (each fixture's calibrated value: a
        point's ``position`` (mm), a plane's unit ``normal`` and ``offset`` (mm)), and ``gauge`` (how
        the world frame was fixed, when nothing in the data fixes it). Their parameters
        (``fixture.NAME.x``, ``plane.NAME.d``, ...) are rows of ``parameters``.
    tooling : dict
        The tooling the data used (:func:`fgcal.estimation.result_tooling.tooling_record`): ``radius`` (mm), ``balls`` (name ->
        centre in the tool frame, mm) and ``tool_ball``, the ball that made every contact (the
        tool point of a contact calibration: ``export --urdf`` puts its link ``tool`` there), or None.
    noise_mode : str
        ``estimated`` (each level's noise from the residuals where the redundancy allows) or
        ``declared``.
    noise : dict of str to LevelNoise
        Per variance component (``probes``, ``centres``, ``poses``, ``poses_rotation``, ``joints``):
        declared, estimated and used sigma, redundancy, and the test of the declared sigma.
    noise_groups : dict of str to LevelNoise
        Each noise group within a component (``pixels.CAMERA``: a camera's own pixel noise), as
        ``noise`` has it (:mod:`fgcal.estimation.group_noise`).
    outliers : list of Outlier
        Measurements excluded as gross errors (pose, ball, line of the file).
    fit_test : dict
        Global test of the declared noise: ``statistic`` (sum of squared residuals at the declared
        sigmas), ``redundancy``, ``p_value``.
    at_readings : dict of str to ResidualSummary
        Residuals with the joints at their readings (before the joint variables moved): the
        training error a user of the readings sees. ``levels`` holds those after they moved.
    pose_residuals : list of PoseResidual
        Per calibration pose (``pose_ids`` order): the residuals at the readings, after the joints
        moved and with the nominal geometry, so that a report can show them and name the outliers.
    """

    robot: str
    n_poses: int
    parameters: list[ParameterEstimate]
    covariance: np.ndarray
    slots: dict[str, float]
    held: list[dict] = field(default_factory=list)
    levels: dict[str, LevelSummary] = field(default_factory=dict)
    iterations: int = 0
    converged: bool = True
    cost: float = 0.0
    singular_values: list[float] = field(default_factory=list)
    condition_number: float = float("nan")
    pose_ids: list[int] = field(default_factory=list)
    options: dict = field(default_factory=dict)
    dataset: str | None = None
    fgcal_version: str = ""
    residuals: dict[str, list[float]] = field(default_factory=dict)
    tool_xyz: list[list[float]] = field(default_factory=list)
    robot_model: dict = field(default_factory=dict)
    joint_errors: dict = field(default_factory=dict)
    setup: dict = field(default_factory=dict)
    tooling: dict = field(default_factory=dict)
    noise_mode: str = "declared"
    noise: dict[str, LevelNoise] = field(default_factory=dict)
    # each noise group's share of a component (``pixels.CAMERA``: a camera's pixel noise), beside ``noise``
    noise_groups: dict[str, LevelNoise] = field(default_factory=dict)
    outliers: list[Outlier] = field(default_factory=list)
    fit_test: dict = field(default_factory=dict)
    at_readings: dict[str, ResidualSummary] = field(default_factory=dict)
    pose_residuals: list[PoseResidual] = field(default_factory=list)

    def save(self, path) -> None:
        """Write this result as ``fgcal-result/1`` JSON, atomically (:func:`save_result`)."""
        save_result(self, path)

    @classmethod
    def load(cls, path) -> CalibrationResult:
        """Read a result file (:func:`load_result`)."""
        return load_result(path)

    @property
    def names(self) -> list[str]:
        return [p.name for p in self.parameters]

    @property
    def estimate(self) -> np.ndarray:
        return np.array([p.estimate for p in self.parameters])

    @property
    def sigma(self) -> np.ndarray:
        return np.array([p.sigma for p in self.parameters])

    def slot_vector(self, model=None) -> np.ndarray:
        """The calibrated slot vector (S,) in internal units (mm, rad), in ``model``'s slot order.

        ``model`` is the result's own (:meth:`model`) by default.
        """
        names = (model or self.model()).slot_names if (model is not None or self.robot_model) else SLOT_NAMES
        missing = [n for n in names if n not in self.slots]
        if missing:
            raise FgcalError(f"result of {self.robot}: no value for slot(s) {', '.join(missing[:5])} of "
                             f"{(model.name if model is not None else self.robot)}: a result of another robot model?")
        return slots_from_file_units(np.array([self.slots[n] for n in names]))

    def model(self):
        """The robot model (nominal) the result was computed with."""
        from fgcal.robots.robot_file import load_model, model_from_dict

        cached = self.__dict__.get("_model")
        if cached is None:
            cached = (model_from_dict(self.robot_model, source=f"result of {self.robot}") if self.robot_model
                      else load_model(self.robot))
            self.__dict__["_model"] = cached
        return cached

    def tool_point(self) -> np.ndarray | None:
        """The centre (3,) mm in the tool frame of the ball that made the contacts, or None (DESIGN.md 8.2)."""
        name = self.tooling.get("tool_ball")
        return None if name is None else np.array(self.tooling["balls"][name], dtype=float)

    def correlation(self) -> np.ndarray:
        s = np.sqrt(np.diag(self.covariance))
        return self.covariance / np.outer(s, s)

    def to_dict(self) -> dict:
        d = {"format": FORMAT, "robot": self.robot, "n_poses": self.n_poses,
             "parameters": [asdict(p) for p in self.parameters],
             "covariance": np.asarray(self.covariance).tolist()}
        for key in ("slots", "held", "iterations", "converged", "cost", "singular_values", "condition_number",
                    "pose_ids", "options", "dataset", "fgcal_version", "residuals", "tool_xyz", "robot_model",
                    "joint_errors", "setup", "tooling"):
            d[key] = getattr(self, key)
        d["levels"] = {k: asdict(v) for k, v in self.levels.items()}
        d["noise_mode"], d["fit_test"] = self.noise_mode, self.fit_test
        d["noise"] = {k: asdict(v) for k, v in self.noise.items()}
        if self.noise_groups:
            d["noise_groups"] = {k: asdict(v) for k, v in self.noise_groups.items()}
        d["outliers"] = [asdict(o) for o in self.outliers]
        d["at_readings"] = {k: asdict(v) for k, v in self.at_readings.items()}
        # PoseResidual holds scalars only: a shallow dict is asdict's (which deep-copies, 10x slower)
        names = [f.name for f in fields(PoseResidual)]
        d["pose_residuals"] = [{n: getattr(p, n) for n in names} for p in self.pose_residuals]
        return d


def _pose_residual(d: dict) -> PoseResidual:
    p = PoseResidual(**d)
    for name in ("rms_mm", "moved_mm", "nominal_mm", "max_mm"):
        setattr(p, name, _float(getattr(p, name)))
    p.pose, p.n, p.excluded = int(p.pose), int(p.n), int(p.excluded)
    if p.rotation_deg is not None:
        p.rotation_deg = _float(p.rotation_deg)
    return p


def save_result(result: CalibrationResult, path) -> None:
    """Write ``result`` as ``fgcal-result/1`` JSON, atomically.

    Raises
    ------
    FgcalError
        When the result is from no pose (only the prior): no reader would take it.
    """
    if result.n_poses < 1:
        raise FgcalError(f"{path}: not written: the result is from no pose (only the prior; nothing was calibrated)")
    atomic_write_text(path, _dumps(result.to_dict()) + "\n")


def load_result(path) -> CalibrationResult:
    """Read and check a result file; a malformed one raises ``FgcalError`` naming the file."""
    from fgcal.estimation.result_check import validate_result
    from fgcal.util.yamlio import read_text_file

    path = Path(path)
    text = read_text_file(path, FgcalError, max_bytes=MAX_RESULT_BYTES)
    try:
        d = json.loads(text)
    except json.JSONDecodeError as exc:
        raise FgcalError(f"{path}: not a JSON result file ({exc.msg}, line {exc.lineno})") from None
    except RecursionError:
        raise FgcalError(f"{path}: not a result file (JSON nested too deep)") from None
    if not isinstance(d, dict) or d.get("format") != FORMAT:
        raise FgcalError(f"{path}: format {d.get('format') if isinstance(d, dict) else None!r} is not {FORMAT!r}")
    try:
        params = [ParameterEstimate(**p) for p in d["parameters"]]
        cov = np.array(d["covariance"], dtype=float).reshape(len(params), len(params))
        slots = {k: float(v) for k, v in d["slots"].items()}
        bad = [k for k, v in slots.items() if not math.isfinite(v)]
        bad += [p.name for p in params if not finite_number(p.estimate)]
        if bad:
            raise ValueError(f"{', '.join(map(str, bad[:3]))}: not a finite number")
        levels = {k: LevelSummary(**v) for k, v in d.get("levels", {}).items()}
        cond = d.get("condition_number")
        cond = float("inf") if cond == "Infinity" else (float("nan") if cond is None else float(cond))
        result = CalibrationResult(
            robot=str(d["robot"]), n_poses=int(d["n_poses"]), parameters=params, covariance=cov, slots=slots,
            held=list(d.get("held", [])), levels=levels, iterations=int(d.get("iterations", 0)),
            converged=bool(d.get("converged", True)), cost=float(d.get("cost", 0.0)),
            singular_values=[float(v) for v in d.get("singular_values", [])], condition_number=cond,
            pose_ids=[int(v) for v in d.get("pose_ids", [])], options=dict(d.get("options", {})),
            dataset=d.get("dataset"), fgcal_version=str(d.get("fgcal_version", "")),
            residuals={k: [float(x) for x in v] for k, v in d.get("residuals", {}).items()},
            tool_xyz=[[float(c) for c in p] for p in d.get("tool_xyz", [])],
            robot_model=dict(d.get("robot_model") or {}), joint_errors=dict(d.get("joint_errors") or {}),
            setup=check_setup(d.get("setup"), [p.name for p in params]),
            tooling=check_tooling(d.get("tooling")), noise_mode=str(d.get("noise_mode", "declared")),
            noise={k: LevelNoise(**v) for k, v in d.get("noise", {}).items()},
            noise_groups={k: LevelNoise(**v) for k, v in d.get("noise_groups", {}).items()},
            outliers=[Outlier(**o) for o in d.get("outliers", [])],
            fit_test={k: _float(v) for k, v in d.get("fit_test", {}).items()},
            at_readings={k: ResidualSummary(**v) for k, v in d.get("at_readings", {}).items()},
            pose_residuals=[_pose_residual(p) for p in d.get("pose_residuals", [])])
    except (AttributeError, KeyError, OverflowError, TypeError, ValueError) as exc:
        raise FgcalError(f"{path}: malformed result: {exc}") from None
    try:
        result.slot_vector()  # every slot of the result's own model has a value
        validate_result(result)  # finite, sigmas >= 0, a PSD covariance, names of the model
    except FgcalError as exc:
        raise FgcalError(f"{path}: malformed result: {exc}") from None
    return result
