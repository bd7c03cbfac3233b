"""``verify`` on camera data (DESIGN.md 8.4): the reprojection error (px) of held-out images.

After: the calibrated robot with the cameras and targets the calibration found
(``result.setup.estimated``). Before: the nominal robot with the cameras and targets started
from these images (per-image PnP and hand-eye at the nominal geometry), as a calibration would
start. Per pose, the RMS over its corners of the pixel error's norm.

The tool-point error implied (mm): each image's own target pose (PnP with the intrinsics the
model has) against the model's prediction of it. Eye-to-hand (the target on the tool: its points
are tool points) the mean distance of the target's points, predicted less seen, in the camera
frame; eye-in-hand (the camera on the tool) the distance of the camera's optical centre, predicted
less seen, in the target's frame. Per pose, the RMS over its cameras. No I/O here.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from fgcal.errors import FgcalError
from fgcal.estimation.verification_result import Comparison, ToolPointErrors, Verification
from fgcal.measurements.camera import INTRINSICS, pose_matrix
from fgcal.measurements.camera_start import pnp
from fgcal.measurements.dataset import Dataset
from fgcal.measurements.pixels import PIXELS
from fgcal.measurements.setup import SetupLayout, SetupSpec
from fgcal.robots.model import RobotModel

__all__ = ["found_blocks", "tool_point_errors", "verify_pixels"]


def found_blocks(result, names) -> dict:
    """The cameras' (15 entries) and targets' (6) values a result found, internal units (mm, rad)."""
    found = (result.setup or {}).get("estimated", {})
    out = {}
    for n in names:
        e = found.get(n)
        if e is None or e.get("type") not in ("camera", "target"):
            raise FgcalError(f"the calibration found no camera or target {n!r}: verify with its cameras and targets")
        pose = np.concatenate([np.asarray(e["pose"][:3], float), np.radians(e["pose"][3:6])])
        out[n] = np.concatenate([pose, [e["intrinsics"][c] for c in INTRINSICS]]) if e["type"] == "camera" else pose
    return out


def _errors(model, slots, obs, q, ids, values) -> np.ndarray:
    """Per pose (len(ids),) the RMS reprojection error (px) at ``slots`` with block values ``values``."""
    spec = SetupSpec({n: replace(obs.specs[n], value=None) for n in PIXELS.all_blocks(obs)})
    layout = SetupLayout.build(spec, values)
    row = {int(p): i for i, p in enumerate(ids)}
    terms = PIXELS.terms(obs, None, row, layout)
    every = np.arange(len(model.slot_names))
    e = PIXELS.setup_error(slots, q[terms.pose], terms.data, layout.start, every, slots, model.chain)[0]
    _, _, _, _, _, weight = terms.data
    d2 = np.sum((e / weight[:, None]) ** 2, axis=1)  # px of each corner's own camera
    return np.sqrt(np.bincount(terms.pose, weights=d2, minlength=len(ids)) / np.bincount(terms.pose,
                                                                                       minlength=len(ids)))


def tool_point_errors(model, slots, obs, q, ids, values) -> tuple[np.ndarray, str]:
    """Per pose (len(ids),) the tool-point error implied (mm, see the module's text) at ``slots``
    (S,) with block values ``values`` (name -> entries, internal units) and joints ``q``
    (len(ids), n) rad; and what it measures (``"target points"``, ``"camera centre"``, or both
    joined by ``" and "`` when the cameras are mounted both ways). NaN for a pose no image of which
    has enough corners for PnP."""
    row = {int(p): i for i, p in enumerate(ids)}
    F = model.forward(slots, q)
    d2, n = np.zeros(len(ids)), np.zeros(len(ids))
    kinds = set()
    for pid, cam, tgt in dict.fromkeys(zip(obs.pose.tolist(), obs.camera.tolist(), obs.target.tolist(),
                                           strict=True)):
        sel = (obs.pose == pid) & (obs.camera == cam) & (obs.target == tgt)
        k = values[cam][6:]
        try:
            seen, _ = pnp(obs.xyz[sel], obs.uv[sel], k)
        except (ValueError, np.linalg.LinAlgError):
            continue
        i = row[int(pid)]
        on_tool = obs.specs[tgt].mount == "tool"
        pred = np.linalg.inv(pose_matrix(values[cam][:6])) @ (F[i] if on_tool else np.linalg.inv(F[i])) \
            @ pose_matrix(values[tgt])
        if on_tool:  # the target's points are tool points: where they are in the camera frame
            X = obs.xyz[sel]
            err = np.mean(np.linalg.norm(X @ (pred[:3, :3] - seen[:3, :3]).T + (pred[:3, 3] - seen[:3, 3]), axis=1))
            kinds.add("target points")
        else:  # the camera is on the tool: where its optical centre is in the target's frame
            err = np.linalg.norm(np.linalg.inv(pred)[:3, 3] - np.linalg.inv(seen)[:3, 3])
            kinds.add("camera centre")
        d2[i] += err**2
        n[i] += 1
    with np.errstate(invalid="ignore"):
        return np.sqrt(d2 / n), " and ".join(sorted(kinds))


def verify_pixels(result, ds: Dataset, model: RobotModel, slots):
    """A :class:`~fgcal.estimation.verification_result.Verification` of ``ds.pixels`` (px per pose)."""
    obs = ds.pixels
    if obs is None:
        raise FgcalError(f"{ds.path or 'dataset'}: no pixels to verify")
    ids = np.array([int(p) for p in ds.pose_ids if np.any(obs.pose == p)], dtype=int)
    q = model.joints_to_internal(ds.joints_deg[ds.row_of(ids)])
    row = {int(p): i for i, p in enumerate(ids)}
    pose = np.asarray([row[int(p)] for p in obs.pose.tolist()], dtype=int)
    found = found_blocks(result, PIXELS.all_blocks(obs))
    after = _errors(model, slots, obs, q, ids, found)
    starts, _ = PIXELS.start_poses(obs, model.forward(model.nominal, q[pose]))
    before = _errors(model, model.nominal, obs, q, ids, starts)
    tool_after, what = tool_point_errors(model, slots, obs, q, ids, found)
    tool_before, _ = tool_point_errors(model, model.nominal, obs, q, ids, starts)
    return Verification(ids, Comparison(after, None), Comparison(before, None),
                        reference="reprojection error of held-out images (px)", robot=model.name,
                        joints_deg=np.asarray(ds.joints_deg[ds.row_of(ids)], dtype=float),
                        tool_points=ToolPointErrors(what, tool_after, tool_before))
