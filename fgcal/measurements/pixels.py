"""Pixels: the image of a target point in a camera (DESIGN.md 8.4).

File ``pixels.csv``: ``pose,camera,point,u,v``. At this pose, target point ``point`` is seen by
camera ``camera`` at pixel ``(u, v)``. The camera (mount pose and intrinsics) and the target
(its pose) are set-up blocks (:mod:`fgcal.measurements.camera`); a camera on the world with a
target on the tool is eye-to-hand, a camera on the tool with a target in the world eye-in-hand.
2 rows per corner: the predicted pixel less the measured one (px), scaled by the ratio of the
dataset's ``pixel_sigma`` to the camera's own (one noise component ``pixels``).

Corners behind the camera, seen at a grazing angle of a planar target or measured off the image
are refused by :meth:`Pixels.admit` before the solve and named in the result. No I/O here.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from fgcal.errors import FgcalError
from fgcal.measurements.base import NoiseComponent, ObservationRows, Terms
from fgcal.measurements.camera import CAMERA_SIZE, mount_transform, pose_entries, pose_matrix, project
from fgcal.measurements.camera_start import hand_eye, pnp_each
from fgcal.measurements.contact import SetupMeasurement
from fgcal.robots.kinematics import jacobians

__all__ = ["GRAZING_DEG", "MIN_DEPTH_MM", "PIXELS", "PIXEL_COLUMNS", "PIXEL_FILE", "PixelObservations", "Pixels"]

log = logging.getLogger(__name__)

PIXEL_FILE = "pixels.csv"
PIXEL_COLUMNS = ("pose", "camera", "point", "u", "v")
GRAZING_DEG = 80.0  # a planar target's corners seen at more than this from its normal are refused
MIN_DEPTH_MM = 1.0  # a corner nearer than this in front of the camera (or behind it) is refused


@dataclass
class PixelObservations(ObservationRows):
    """Corners, one row each: pose ids (M,), camera and target names (M,), point names (M,), pixels
    ``uv`` (M, 2), the point in its target's frame ``xyz`` (M, 3) mm, file lines (M,).

    ``specs`` (not a row field): the cameras' and targets' specs by name (kept by :meth:`subset`).
    ``pnp_memo`` (not a row field, shared with every subset): each image's PnP by its corners and
    intrinsics (:func:`~fgcal.measurements.camera_start.pnp_each`: the refusal test and the blocks'
    start solve the same images)."""

    pose: np.ndarray
    camera: np.ndarray
    target: np.ndarray
    point: np.ndarray
    uv: np.ndarray
    xyz: np.ndarray
    line: np.ndarray | None = None

    ROW_SHAPES = {"uv": (2,), "xyz": (3,)}

    def __post_init__(self):
        for name in ("camera", "target", "point"):
            setattr(self, name, np.asarray(getattr(self, name), dtype=str).reshape(-1))
        super().__post_init__()
        self.specs: dict = {}
        self.pnp_memo: dict = {}

    @classmethod
    def build(cls, pose, camera, point, uv, specs: dict, line=None) -> PixelObservations:
        """Rows from ``pose, camera, point, uv`` and the specs (each camera's one target: the target
        that has the point)."""
        camera = np.asarray(camera, dtype=str).reshape(-1)
        point = np.asarray(point, dtype=str).reshape(-1)
        targets = {n: s for n, s in specs.items() if s.type == "target"}
        tgt, xyz = [], []
        for p in point.tolist():
            owner = [n for n, t in targets.items() if p in t.points]
            if not owner:
                raise ValueError(f"point {p!r} is in no target")
            tgt.append(owner[0])
            xyz.append(targets[owner[0]].points[p])
        out = cls(pose, camera, np.array(tgt, dtype=str), point, uv, np.array(xyz, dtype=float).reshape(-1, 3), line)
        out.specs = dict(specs)
        return out

    def subset(self, mask):
        out = super().subset(mask)
        out.specs, out.pnp_memo = self.specs, self.pnp_memo
        return out


def _mode(cam, tgt) -> int:
    """0: eye-to-hand (camera on the world, target on the tool); 1: eye-in-hand."""
    if cam.mount == "world" and tgt.mount == "tool":
        return 0
    if cam.mount == "tool" and tgt.mount == "world":
        return 1
    raise FgcalError(f"camera {cam.name} (mount {cam.mount}) and target {tgt.name} (mount {tgt.mount}): one must "
                     "be on the tool and the other on the world")


def _skew(v) -> np.ndarray:
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2], S[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    S[..., 1, 0], S[..., 2, 0], S[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return S


def _where(eye, a, b) -> np.ndarray:
    """``np.where(eye, a(), b())`` row by row (``eye`` (M,), ``a()``, ``b()`` (M, ...)), computing only
    the side used when every row is on one side."""
    if eye.all() or not eye.any():
        return a() if eye.all() else b()
    x, y = a(), b()
    return np.where(eye.reshape((-1,) + (1,) * (x.ndim - 1)), x, y)


def pixel_model(theta, q, data, s, index, held, chain, need_jac: bool = True):
    """Predicted pixels and the camera-frame points of the payload ``data`` (see :meth:`Pixels.terms`).

    Returns ``uv (M, 2), p_c (M, 3)`` and, with ``need_jac``, ``J_t (M, 2, P), J_q (M, 2, n),
    J_s (M, 2, 21)`` (the camera's 15 entries, then the target's 6)."""
    from factors.errors import slots_of

    xyz, _, cam0, tgt0, mode, _ = data
    x = slots_of(theta, index, held)
    q = np.atleast_2d(q)
    m = len(xyz)
    uq, inv = np.unique(q, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    jac = jacobians(x, uq, chain=chain)
    R, p = jac.T[inv, :3, :3], jac.T[inv, :3, 3]
    R_t, t_t, dR_t = np.empty((m, 3, 3)), np.empty((m, 3)), np.empty((m, 3, 3, 3))
    for k in np.unique(tgt0):
        rows = tgt0 == k
        R_t[rows], t_t[rows], dR_t[rows] = mount_transform(s[k:k + 6])
    R_c, t_c, dR_c, K = np.empty((m, 3, 3)), np.empty((m, 3)), np.empty((m, 3, 3, 3)), np.empty((m, 9))
    for k in np.unique(cam0):
        rows = cam0 == k
        R_c[rows], t_c[rows], dR_c[rows] = mount_transform(s[k:k + 6])
        K[rows] = s[k + 6:k + CAMERA_SIZE]
    X_o = np.einsum("mij,mj->mi", R_t, xyz) + t_t  # the point in the target's mount frame
    eye = mode == 0
    v = _where(eye, lambda: np.einsum("mij,mj->mi", R, X_o), lambda: X_o - p)  # p_w - p
    p_m = _where(eye, lambda: v + p, lambda: np.einsum("mji,mj->mi", R, v))  # the point in the camera's mount frame
    p_c = np.einsum("mji,mj->mi", R_c, p_m - t_c)
    uv, J_X, J_k = project(p_c, K)
    if not need_jac:
        return uv, p_c
    Rc_T = np.swapaxes(R_c, 1, 2)
    A = J_X @ Rc_T  # d uv / d p_m
    # d p_m / d (dp, omega) of the tool pose: eye-to-hand dp - [v]x omega; eye-in-hand R^T ([v]x omega - dp)
    S = _skew(v)
    Rt = np.swapaxes(R, 1, 2)
    D = _where(eye, lambda: np.concatenate([np.broadcast_to(np.eye(3), (m, 3, 3)), -S], axis=2),
               lambda: np.concatenate([-Rt, Rt @ S], axis=2))  # (M, 3, 6)
    Jp_t = jac.pose_slots[:, :, index][inv]
    Jp_q = jac.pose_joints[inv]
    J_t = A @ (D @ Jp_t)
    J_q = A @ (D @ Jp_q)
    dpm_dXo = _where(eye, lambda: R, lambda: Rt)
    J_s = np.empty((m, 2, CAMERA_SIZE + 6))
    J_s[:, :, 0:3] = -A
    J_s[:, :, 3:6] = np.einsum("mrj,maij,mi->mra", J_X, dR_c, p_m - t_c)  # dR_c^T (p_m - t_c)
    J_s[:, :, 6:15] = J_k
    B = A @ dpm_dXo
    J_s[:, :, 15:18] = B
    J_s[:, :, 18:21] = np.einsum("mri,maij,mj->mra", B, dR_t, xyz)
    return uv, p_c, J_t, J_q, J_s


class Pixels(SetupMeasurement):
    """A target point's pixel in a camera: 2 rows, predicted less measured (px)."""

    level = "pixels"
    file = PIXEL_FILE
    columns: tuple = PIXEL_COLUMNS
    width = 2
    per_ball = False
    title = "pixels of target points"
    noun = "corner"
    fixture_type = "camera"
    noise_key = "pixel_sigma"
    sigma_field = "pixel"
    unit = "px"
    derived = True  # read with the dataset's cameras and targets (fgcal.io.dataset_io)
    noise_components = (NoiseComponent("pixels", slice(0, 2), "pixel", unit="px"),)

    def declared_sigmas(self, noise) -> dict:
        value = dict(noise.extra).get(self.noise_key)
        return {self.sigma_field: float(value if value is not None else 0.5)}

    def blocks_of(self, obs: PixelObservations) -> np.ndarray:
        """Each corner's camera (its target is :meth:`targets_of`)."""
        return obs.camera

    def all_blocks(self, obs: PixelObservations) -> list:
        """Every block the corners use: their cameras and targets."""
        return list(dict.fromkeys(obs.camera.tolist() + obs.target.tolist()))

    def tool_blocks(self, obs: PixelObservations) -> list:
        """The blocks mounted on the tool (eye-to-hand: targets, eye-in-hand: cameras)."""
        return [n for n in self.all_blocks(obs) if obs.specs[n].mount == "tool"]

    def terms(self, obs: PixelObservations, tooling, row_of_pose, layout=None) -> Terms:
        return Terms(np.array([row_of_pose[p] for p in obs.pose.tolist()], dtype=int), self._pixel_payload(obs, layout))

    def _pixel_payload(self, obs, layout) -> tuple:
        """``xyz (M, 3), uv (M, 2)``, each corner's camera and target block start in ``s`` (M,), its
        mode (M,) (0 eye-to-hand, 1 eye-in-hand) and weight (M,) (declared sigma over the camera's)."""
        ref = self._reference_sigma(obs)
        cam0 = np.array([layout.offset[c] for c in obs.camera.tolist()], dtype=int)
        tgt0 = np.array([layout.offset[t] for t in obs.target.tolist()], dtype=int)
        spec = layout.spec.fixtures
        pairs = zip(obs.camera.tolist(), obs.target.tolist(), strict=True)
        mode = np.array([_mode(spec[c], spec[t]) for c, t in pairs], dtype=int).reshape(-1)
        weight = np.array([ref / spec[c].pixel_sigma for c in obs.camera.tolist()], dtype=float).reshape(-1)
        return obs.xyz, obs.uv, cam0, tgt0, mode, weight

    @staticmethod
    def _reference_sigma(obs) -> float:
        cams = [s for s in obs.specs.values() if s.type == "camera"]
        return float(cams[0].pixel_sigma) if cams else 1.0

    def setup_error(self, theta, q, data, s, index, held, chain):
        _, uv_meas, cam0, tgt0, _, weight = data
        uv, _, J_t, J_q, J_s = pixel_model(theta, q, data, s, index, held, chain)
        w = weight[:, None]
        cols = np.concatenate([cam0[:, None] + np.arange(CAMERA_SIZE), tgt0[:, None] + np.arange(6)], axis=1)
        return ((uv - uv_meas) * w, J_t * w[:, :, None], J_q * w[:, :, None], J_s * w[:, :, None], cols)

    # ------------------------------------------------------------------ the start
    def start_poses(self, obs: PixelObservations, T) -> tuple[dict, dict]:
        """Start entries of every camera (15) and target (6) the corners use, from the tool poses
        ``T`` (M, 4, 4) at the start geometry: a given value or ``mount_pose`` where there is one,
        else per-image PnP and a robot-world hand-eye solve. Also a report ``{pair: {...}}``."""
        specs = obs.specs
        out, report = {}, {}
        for name in self.all_blocks(obs):
            f = specs[name]
            given = f.value if f.value is not None else f.start_pose
            if given is not None:
                out[name] = np.concatenate([given[:6], f.intrinsics]) if f.type == "camera" else np.array(given[:6])
        pairs = list(dict.fromkeys(zip(obs.camera.tolist(), obs.target.tolist(), strict=False)))
        for cam, tgt in pairs:
            if cam in out and tgt in out:
                continue
            cs, ts = specs[cam], specs[tgt]
            mode = _mode(cs, ts)
            A, B, rms = [], [], []
            sel = (obs.camera == cam) & (obs.target == tgt)
            images = [np.nonzero(sel & (obs.pose == pid))[0] for pid in dict.fromkeys(obs.pose[sel].tolist())]
            seen = pnp_each([(obs.xyz[rows], obs.uv[rows]) for rows in images], cs.intrinsics, obs.pnp_memo)
            for rows, got in zip(images, seen, strict=True):
                if got is None:
                    continue
                T_ct, err = got
                F = T[rows[0]]
                A.append(F if mode == 0 else np.linalg.inv(F))
                B.append(T_ct)
                rms.append(err)
            if len(A) < 3:
                raise FgcalError(f"camera {cam} and target {tgt}: the start needs three or more images with "
                                 f"four or more corners each (it has {len(A)}); give mount_pose: starts")
            X, Y = hand_eye(np.array(A), np.array(B))
            res = [np.linalg.norm((a @ X - Y @ b)[:3, 3]) for a, b in zip(A, B, strict=False)]
            report[f"{cam}/{tgt}"] = {"images": len(A), "pnp_rms_px": float(np.sqrt(np.mean(np.square(rms)))),
                                      "hand_eye_rms_mm": float(np.sqrt(np.mean(np.square(res))))}
            log.info("start of camera %s and target %s: PnP on %d images (RMS %.3g px), hand-eye residual "
                     "RMS %.3g mm", cam, tgt, len(A), report[f"{cam}/{tgt}"]["pnp_rms_px"],
                     report[f"{cam}/{tgt}"]["hand_eye_rms_mm"])
            if cam not in out:
                out[cam] = np.concatenate([pose_entries(Y), cs.intrinsics])
            if tgt not in out:
                out[tgt] = pose_entries(X)
        return out, report

    def block_starts(self, obs, T, tooling, unknown, where) -> dict:
        starts, _ = self.start_poses(obs, T)
        return {n: v for n, v in starts.items() if n in unknown}

    def admit(self, obs: PixelObservations, T) -> tuple[np.ndarray, list]:
        """Which corners to use (M,) and the refused ones (``{pose, camera, point, reason}``), at
        the start poses from the tool poses ``T`` (M, 4, 4): measured off the image, behind the
        camera (or nearer than :data:`MIN_DEPTH_MM`) or seen at more than :data:`GRAZING_DEG` from a
        planar target's normal."""
        specs = obs.specs
        keep = np.ones(len(obs), dtype=bool)
        reasons = np.full(len(obs), "", dtype=object)
        w = np.array([specs[c].width for c in obs.camera.tolist()], dtype=float)
        h = np.array([specs[c].height for c in obs.camera.tolist()], dtype=float)
        off = (obs.uv[:, 0] < -0.5) | (obs.uv[:, 1] < -0.5) | (obs.uv[:, 0] > w - 0.5) | (obs.uv[:, 1] > h - 0.5)
        reasons[off] = "measured off the image"
        if (~off).any():
            starts, _ = self.start_poses(obs.subset(~off), T[~off])
            rows = np.nonzero(~off)[0]
            cams, cam_of = np.unique(obs.camera[rows], return_inverse=True)
            tgts, tgt_of = np.unique(obs.target[rows], return_inverse=True)
            cam_of, tgt_of = cam_of.reshape(-1), tgt_of.reshape(-1)
            Tc_inv = np.linalg.inv(np.array([pose_matrix(starts[c][:6]) for c in cams.tolist()]))[cam_of]  # per row
            Tt = np.array([pose_matrix(starts[t]) for t in tgts.tolist()])[tgt_of]
            on_tool = np.array([specs[t].mount == "tool" for t in tgts.tolist()])[tgt_of]
            F = T[rows]
            F_inv = np.linalg.inv(F)
            Tm = np.where(on_tool[:, None, None], F, F_inv) @ Tt  # the target in the camera's mount frame
            Tct = Tc_inv @ Tm
            pc = np.einsum("mij,mj->mi", Tct[:, :3, :3], obs.xyz[rows]) + Tct[:, :3, 3]
            planar = np.array([specs[t].planar for t in tgts.tolist()])[tgt_of]
            cos = np.abs(np.einsum("mi,mi->m", pc, Tct[:, :3, 2])) / np.linalg.norm(pc, axis=1)
            behind = pc[:, 2] < MIN_DEPTH_MM
            grazing = ~behind & planar & (cos < np.cos(np.radians(GRAZING_DEG)))
            reasons[rows[behind]] = "behind the camera"
            reasons[rows[grazing]] = f"seen at more than {GRAZING_DEG:g} deg from the target's normal"
        keep = reasons == ""
        refused = [{"pose": int(obs.pose[i]), "camera": str(obs.camera[i]), "point": str(obs.point[i]),
                    "reason": str(reasons[i])} for i in np.nonzero(~keep)[0]]
        for r in refused[:5]:
            log.warning("pixels: refused corner %s of camera %s at pose %d: %s", r["point"], r["camera"], r["pose"],
                        r["reason"])
        return keep, refused

    # ------------------------------------------------------------------ the rest of the protocol
    def error(self, theta, q, data, index, held, chain):
        *payload, s = data
        return self.setup_error(theta, q, tuple(payload), np.asarray(s, dtype=float), index, held, chain)[:3]

    def design_data(self, forward, offsets, fixture=None, setup=None, radius: float = 0.0) -> tuple:
        raise FgcalError("design for cameras is not available yet")

    def simulate(self, T, offsets, rng, noise) -> np.ndarray:
        raise NotImplementedError(f"fgcal's simulator does not simulate {self.title}")

    def parse(self, where, record, balls):
        raise NotImplementedError("pixels.csv is read with the dataset's cameras and targets (fgcal.io.dataset_io)")

    def observations(self, pose, ball, values, line=None):
        raise NotImplementedError("pixels are built by PixelObservations.build")

    # ------------------------------------------------------------------ each camera's noise
    def noise_groups(self, terms: Terms, layout) -> dict:
        """Each camera's corners (``{camera: rows (M,) bool}``): a noise group each
        (:mod:`fgcal.estimation.group_noise`)."""
        cam0 = terms.data[2]
        return {n: cam0 == layout.offset[n] for n, f in layout.spec.fixtures.items()
                if f.type == "camera" and np.any(cam0 == layout.offset[n])}

    def group_weight(self, terms: Terms) -> np.ndarray:
        """The corners' weights (M,) in the payload (the component's sigma over the camera's): rescaled in place."""
        return terms.data[5]

    # ------------------------------------------------------------------ the online engines' rows
    block_specs = True  # block_observations needs the dataset's cameras and targets (``specs``)

    def row_labels(self, obs: PixelObservations) -> np.ndarray:
        """Each corner's point name (M,): what the online engines keep as a row's ball."""
        return obs.point

    def row_values(self, obs: PixelObservations) -> np.ndarray:
        """Each corner's measured pixel (M, 2): what the online engines keep as a row's values."""
        return obs.uv

    def row_blocks(self, block: str, label: str, specs: dict) -> list:
        """The blocks one corner (camera ``block``, point ``label``) depends on: its camera, then the
        target that has the point."""
        return [block] + [n for n, s in specs.items() if s.type == "target" and label in s.points][:1]

    def block_observations(self, pose, ball, block, values, specs=None) -> PixelObservations:
        """Corners from the online engines' rows: pose ids (M,), point names ``ball`` (M,), cameras
        ``block`` (M,), pixels ``values`` (M, 2) (further columns ignored) and the specs by name."""
        uv = np.asarray(values, dtype=float).reshape(len(np.atleast_1d(pose)), -1)[:, :2]
        return PixelObservations.build(np.asarray(pose, dtype=int), block, ball, uv, dict(specs or {}))

    def rows(self, obs):
        return ([int(p), c, n, float(u), float(v)]
                for p, c, n, (u, v) in zip(obs.pose, obs.camera, obs.point, obs.uv, strict=True))

    def metric(self, e):
        """The reprojection error per corner (px); no angle."""
        return np.linalg.norm(e, axis=1), None

    def residual_summary(self, e) -> dict:
        return {"pixels_px": np.asarray(e).ravel().tolist()}

    def residual_places(self, e, terms: Terms, pose_ids, layout) -> dict:
        """Where each corner's residual ``e`` (M, 2) is, for the report's image-plane bins: its
        measured pixel (``pixels_u_px``, ``pixels_v_px``), its pose id, its camera (``pixels_camera``:
        the index among the layout's cameras, in their order) and the residual in that camera's
        own px (``pixels_du_px``, ``pixels_dv_px``)."""
        _, uv, cam0, _, _, weight = terms.data
        cams = [n for n, f in layout.spec.fixtures.items() if f.type == "camera"]
        index = {layout.offset[n]: i for i, n in enumerate(cams)}
        own = np.asarray(e, dtype=float) / weight[:, None]
        return {"pixels_u_px": uv[:, 0].tolist(), "pixels_v_px": uv[:, 1].tolist(),
                "pixels_pose": np.asarray(pose_ids)[terms.pose].astype(float).tolist(),
                "pixels_camera": [float(index[int(k)]) for k in cam0],
                "pixels_du_px": own[:, 0].tolist(), "pixels_dv_px": own[:, 1].tolist()}


PIXELS = Pixels()
