"""``fgcal.verify``: the paper's VERIFY, errors of a calibration at the poses of a dataset."""
from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from fgcal.api.notes import note, warn
from fgcal.api.selection import as_dataset, as_result, select_poses
from fgcal.errors import FgcalError

if TYPE_CHECKING:
    from fgcal.estimation.verification import Verification

__all__ = ["load_verification", "verification_dict", "verification_summary", "verify"]


def verify(result, dataset, *, poses: str | Sequence[int] | None = None) -> Verification:
    """Errors of ``result`` against the measurements (and the truth, for a simulation) of ``dataset``.

    Parameters
    ----------
    result : path or CalibrationResult
    dataset : path or Dataset
        Of the same robot; poses the calibration used are noted (their errors are optimistic).
    poses : str or sequence of int, optional
        As for :func:`fgcal.calibrate`.

    Returns
    -------
    Verification
        ``.to_dict()`` is ``fgcal-verify/1``; ``.save(path)`` writes it.

    Warns
    -----
    FgcalWarning
        Values of the dataset that look like a unit mistake.
    FgcalNote
        Poses the calibration used; measurements skipped.
    """
    from fgcal.estimation.sanity import unit_warnings
    from fgcal.estimation.verification import check_same_robot
    from fgcal.estimation.verification import verify as compare
    from fgcal.io.dataset_io import dataset_model

    where_result = result if isinstance(result, str | Path) else "the result"
    result = as_result(result)
    ds = as_dataset(dataset)
    model = dataset_model(ds)
    check_same_robot(result, model, where=f"{where_result} against {ds.path or 'the dataset'}")
    for w in unit_warnings(ds, model):
        warn(w)
    ds = select_poses(ds, poses)
    same = result.dataset is not None and ds.path is not None and str(result.dataset) == str(ds.path)
    overlap = sorted(set(result.pose_ids) & set(ds.pose_ids.tolist())) if same else []
    if overlap:
        note(f"{len(overlap)} of these poses were used in the calibration; the errors there are optimistic")
    report = compare(result, ds, model)
    for s in report.skipped:
        note(f"skipped {s}")
    return report


def verification_summary(verification) -> list[str]:
    """The lines ``fgcal verify`` prints: nominal and calibrated errors against the measurements (and truth)."""
    d = verification_dict(verification)

    def line(label, summary):
        p, o = summary["position_mm"], summary["orientation_deg"]
        text = f"  {label:28s} position mean {p['mean']:.4g} rms {p['rms']:.4g} max {p['max']:.4g} mm"
        if o is not None:  # None for position-only data
            text += f"; orientation mean {o['mean']:.4g} rms {o['rms']:.4g} max {o['max']:.4g} deg"
        return text

    out = [f"verification on {d['n_poses']} poses ({d['reference']}):", line("nominal vs measured", d["before"]),
           line("calibrated vs measured", d)]
    if "truth" in d:
        out += [line("nominal vs truth", d["truth"]["before"]), line("calibrated vs truth", d["truth"])]
    return out


def verification_dict(verification) -> dict:
    """``fgcal-verify/1`` as a mapping, from a :class:`Verification`, a mapping or a ``verify.json`` path."""
    if isinstance(verification, str | Path):
        return load_verification(verification)
    if isinstance(verification, dict):
        from fgcal.estimation.verification import check_verification

        return check_verification(verification)
    return verification.to_dict()


def load_verification(path) -> dict:
    """Read and check a ``verify.json`` (``fgcal-verify/1``); a malformed one raises ``FgcalError`` naming it."""
    from fgcal.estimation.verification import check_verification
    from fgcal.util.yamlio import read_text_file

    text = read_text_file(path, max_bytes=256 * 1024 * 1024)
    try:
        d = json.loads(text)
    except ValueError as exc:
        raise FgcalError(f"{path}: not a verification file (invalid JSON: {getattr(exc, 'msg', exc)}, "
                         f"line {getattr(exc, 'lineno', '?')})") from None
    return check_verification(d, path)
