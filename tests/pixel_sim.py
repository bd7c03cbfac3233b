"""An independent generator of camera data (``pixels.csv``: target corners seen by a camera) for
checking fgcal's pixel measurement type.

Nothing here uses fgcal: the forward kinematics is :mod:`contact_sim`'s own URDF reader, the
projection is OpenCV's ``cv2.projectPoints``, poses are drawn by rejection (the whole board in the
image, facing the camera within 60 deg), and the dataset is written as plain text in fgcal's
dataset format. Lengths mm, angles rad inside, deg in files.
"""
from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from contact_sim import UrdfChain, _sample_joints, perturbed_urdf

K_TRUE = np.array([900.0, 905.0, 652.0, 498.0, -0.08, 0.03, 0.0005, -0.0003, 0.0])
WIDTH, HEIGHT = 1280, 1024
INTRINSICS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


def pose(t, phi=0.0, theta=0.0, psi=0.0) -> np.ndarray:
    """``Trans(t) Rz(phi) Ry(theta) Rx(psi)`` (4, 4)."""
    c, s = np.cos, np.sin
    Rz = np.array([[c(phi), -s(phi), 0], [s(phi), c(phi), 0], [0, 0, 1]])
    Ry = np.array([[c(theta), 0, s(theta)], [0, 1, 0], [-s(theta), 0, c(theta)]])
    Rx = np.array([[1, 0, 0], [0, c(psi), -s(psi)], [0, s(psi), c(psi)]])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = Rz @ Ry @ Rx, t
    return T


def looking_at(eye, centre) -> np.ndarray:
    """A camera frame at ``eye`` with z towards ``centre`` (x right, y down)."""
    z = (centre - eye) / np.linalg.norm(centre - eye)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = eye
    return T


def cv_project(T_ct, X, k) -> np.ndarray:
    """OpenCV's projection of target points ``X`` (m, 3) seen at ``T_ct`` (target in camera)."""
    rvec, _ = cv2.Rodrigues(T_ct[:3, :3])
    cam = np.array([[k[0], 0, k[2]], [0, k[1], k[3]], [0, 0, 1.0]])
    uv, _ = cv2.projectPoints(X, rvec, T_ct[:3, 3], cam, k[[4, 5, 6, 7, 8]])
    return uv[:, 0]


@dataclass
class CameraTruth:
    urdf: str
    chain: dict
    mode: str            # "eye-to-hand" or "eye-in-hand"
    camera: np.ndarray   # camera frame in the world (eye-to-hand) or in the tool frame (4, 4)
    target: np.ndarray   # board frame in the tool frame (eye-to-hand) or in the world (4, 4)
    k: np.ndarray        # true intrinsics (9,)
    points: np.ndarray   # board points (m, 3) in the board frame
    q: np.ndarray        # joint sets (rad) of the images
    held_out: np.ndarray  # joint sets (rad) of further images in view

    def board_in_camera(self, fk) -> np.ndarray:
        """``T_ct`` (4, 4) at the tool pose ``fk``."""
        if self.mode == "eye-to-hand":
            return np.linalg.inv(self.camera) @ fk @ self.target
        return np.linalg.inv(self.camera) @ np.linalg.inv(fk) @ self.target


def _grid(rows, cols, square):
    return np.array([[j * square, i * square, 0.0] for i in range(rows) for j in range(cols)])


def _visible(T_ct, X, k, max_tilt_deg=60.0, margin=20.0) -> bool:
    pc = X @ T_ct[:3, :3].T + T_ct[:3, 3]
    if np.any(pc[:, 2] < 200.0):
        return False
    centre = pc.mean(axis=0)
    if abs(T_ct[:3, 2] @ centre) < np.cos(np.radians(max_tilt_deg)) * np.linalg.norm(centre):
        return False
    uv = cv_project(T_ct, X, k)
    return bool(np.all((uv[:, 0] > margin) & (uv[:, 0] < WIDTH - margin) & (uv[:, 1] > margin)
                       & (uv[:, 1] < HEIGHT - margin)))


def camera_dataset(out_dir, urdf_path, chain: dict, rng, mode: str = "eye-to-hand", n_images: int = 12,
                   rows: int = 4, cols: int = 5, square: float = 30.0, pixel_sigma: float = 0.3,
                   estimate=(), n_held_out: int = 20, perturb_mm: float = 0.5, perturb_deg: float = 0.05,
                   tool_ball=None, reflector_sigma=None) -> CameraTruth:
    """A camera and a board on a perturbed robot; writes ``out_dir`` (``dataset.yaml``, ``joints.csv``,
    ``pixels.csv``, the nominal ``robot.urdf``). ``estimate``: the intrinsics to estimate (their
    start in the file is off the truth by 1-2 %, the distortion's at 0). With ``tool_ball`` (3,) and
    ``reflector_sigma`` (mm) a tracker's reflector at that tool point is measured too (``centres.csv``)."""
    out_dir = Path(out_dir)
    text = Path(urdf_path).read_text()
    true_text = perturbed_urdf(text, rng, chain.get("base"), chain.get("tip"), mm=perturb_mm, deg=perturb_deg)
    true = UrdfChain(true_text, chain.get("base"), chain.get("tip"))
    X = _grid(rows, cols, square)
    pool = _sample_joints(true, rng, 4000)
    fk = true.fk(pool)
    c = np.median(fk[:, :3, 3], axis=0)
    if mode == "eye-to-hand":
        out = np.array([c[0], c[1], 0.0])
        out = out / max(np.linalg.norm(out), 1e-9)
        camera = looking_at(c + 900.0 * out + np.array([0.0, 0.0, 300.0]), c)
        target = pose([-(cols - 1) * square / 2, -(rows - 1) * square / 2, 40.0], 0.2, 0.0, 0.0)
    else:
        camera = pose([0.0, 40.0, 30.0], 0.1, 0.05, -0.05)
        half = np.array([(cols - 1) * square / 2, (rows - 1) * square / 2, 0.0])
        target = pose(c + np.array([0.0, 0.0, -350.0]) - half, 0.3, 0.0, 0.0)
    ok = []
    for qi, Fi in zip(pool, fk, strict=True):
        T_ct = (np.linalg.inv(camera) @ Fi @ target if mode == "eye-to-hand"
                else np.linalg.inv(camera) @ np.linalg.inv(Fi) @ target)
        if _visible(T_ct, X, K_TRUE):
            ok.append(qi)
        if len(ok) >= n_images + n_held_out:
            break
    if len(ok) < n_images + n_held_out:
        raise RuntimeError(f"only {len(ok)} of 4000 joint sets see the board")
    ok = np.array(ok)
    truth = CameraTruth(true_text, chain, mode, camera, target, K_TRUE.copy(), X, ok[:n_images], ok[n_images:])
    rows_px = []
    for pid, qi in enumerate(truth.q, start=1):
        uv = cv_project(truth.board_in_camera(true.fk(qi)), X, K_TRUE) + rng.normal(scale=pixel_sigma, size=(len(X), 2))
        rows_px += [f"{pid},left,r{i // cols}c{i % cols},{float(u)!r},{float(v)!r}" for i, (u, v) in enumerate(uv)]
    out_dir.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(urdf_path, out_dir / "robot.urdf")
    k_file = K_TRUE.copy()
    scale = {"fx": 1.015, "fy": 0.99, "cx": 1.01, "cy": 0.985}
    for i, n in enumerate(INTRINSICS):
        if n in estimate:
            k_file[i] = K_TRUE[i] * scale[n] if n in scale else 0.0
    ball = "{}" if tool_ball is None else "{B: [" + ", ".join(repr(float(v)) for v in tool_ball) + "]}"
    noise = (f"{{cmm_sigma: {reflector_sigma!r}, joint_resolution: 0.0}}" if reflector_sigma
             else "{joint_resolution: 0.0}")
    lines = ["format: fgcal-dataset/1", "robot: robot.urdf",
             "chain: {" + ", ".join(f"{k}: {v}" for k, v in chain.items()) + "}",
             "tool:", "  radius: 0.0", f"  balls: {ball}", f"noise: {noise}",
             "provenance: {generator: tests/pixel_sim.py}",
             "cameras:", "  left:", f"    mount: {'world' if mode == 'eye-to-hand' else 'tool'}",
             f"    width: {WIDTH}", f"    height: {HEIGHT}",
             "    intrinsics: {" + ", ".join(f"{n}: {float(v)!r}" for n, v in zip(INTRINSICS, k_file, strict=True))
             + "}",
             f"    estimate: [{', '.join(estimate)}]", f"    pixel_sigma: {pixel_sigma!r}",
             "targets:", "  board:", f"    mount: {'tool' if mode == 'eye-to-hand' else 'world'}",
             f"    grid: {{rows: {rows}, cols: {cols}, square: {square!r}}}"]
    (out_dir / "dataset.yaml").write_text("\n".join(lines) + "\n")
    header = "pose," + ",".join(f"q{k + 1}" for k in range(true.n))
    jrows = [f"{p}," + ",".join(repr(float(v)) for v in true.to_readings(qi)) for p, qi in enumerate(truth.q, start=1)]
    (out_dir / "joints.csv").write_text("\n".join([header] + jrows) + "\n")
    (out_dir / "pixels.csv").write_text("\n".join(["pose,camera,point,u,v"] + rows_px) + "\n")
    if tool_ball is not None and reflector_sigma:
        pts = true.point(truth.q, np.asarray(tool_ball, float))
        pts = pts + rng.normal(scale=reflector_sigma, size=pts.shape)
        crow = [f"{p},B," + ",".join(repr(float(v)) for v in x) for p, x in enumerate(pts, start=1)]
        (out_dir / "centres.csv").write_text("\n".join(["pose,ball,x,y,z"] + crow) + "\n")
    return truth
