"""Cost per equation of camera pixels against the point type (issue 25), on bench_types.py's UR10.

The UR10 of ``bench/bench_types.py`` (its geometry perturbed by typical deviations, the same seed) is
measured with about the same number of equations (rows of the least squares) four ways:

* ``centres``: one tracker reflector, 3 rows a pose (the reference, as in bench_types.py);
* ``px_eth_known``: a 7 x 10 chessboard (20 mm squares) on the tool seen by a camera fixed in the
  world (eye-to-hand), intrinsics known; 2 rows a corner, 140 an image;
* ``px_eth_est``: the same with ``fx, fy, cx, cy, k1, k2`` estimated (their start 1-2 % off, the
  distortion's at 0);
* ``px_eih_est``: the camera on the tool, the board fixed in the world (eye-in-hand), the six
  intrinsics estimated.

The generator is independent of fgcal's projection: the pinhole with OpenCV's distortion is written
here in numpy (and checked against ``cv2.projectPoints`` when OpenCV is installed); the tool poses are
the UR10 model's forward kinematics at the true geometry, as bench_types.py's. 0.3 px noise. Poses
are drawn near a pose facing the camera (or the board) and kept when the whole board is in the
image, at least 200 mm in front and facing the camera within 60 deg.

Each dataset is calibrated by :func:`fgcal.estimation.calibrate.calibrate` at the default options
(with its PnP / hand-eye start); the figure is process CPU time (user + system, best of
``--repeat`` rounds, the datasets in turn in each) per equation, and its ratio to the point type's;
"with joints" counts each pose's joint readings as rows as well. Single-threaded BLAS.

Run: ``python bench/bench_types_pixels.py [--rows 3000] [--repeat 3] [--corners 7x10] [--profile NAME]``
(``--profile``: a cProfile of that dataset's calibration, the 25 costliest functions by own time).
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")
sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402
from bench_types import _truth, _write, cpu_of, make_centres  # noqa: E402

K_TRUE = np.array([900.0, 905.0, 652.0, 498.0, -0.08, 0.03, 0.0005, -0.0003, 0.0])
NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
ESTIMATE = ("fx", "fy", "cx", "cy", "k1", "k2")
WIDTH, HEIGHT = 1280, 1024
PIXEL_SIGMA = 0.3
Q0 = np.array([0.3, -1.9, 1.9, -1.5, -1.57, 0.0])  # a pose near which the images are taken (rad)


def project(Xc, k) -> np.ndarray:
    """Pinhole projection with OpenCV's distortion (k1, k2, p1, p2, k3) of camera-frame points
    ``Xc`` (m, 3) mm; pixels (m, 2). Written here, independent of fgcal's."""
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = k
    x, y = Xc[:, 0] / Xc[:, 2], Xc[:, 1] / Xc[:, 2]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.column_stack([fx * xd + cx, fy * yd + cy])


def _check_against_opencv(T_ct, X) -> None:
    try:
        import cv2
    except ImportError:
        return
    rvec, _ = cv2.Rodrigues(T_ct[:3, :3])
    cam = np.array([[K_TRUE[0], 0, K_TRUE[2]], [0, K_TRUE[1], K_TRUE[3]], [0, 0, 1.0]])
    uv, _ = cv2.projectPoints(X, rvec, T_ct[:3, 3], cam, K_TRUE[4:])
    gap = np.abs(uv[:, 0] - project(X @ T_ct[:3, :3].T + T_ct[:3, 3], K_TRUE)).max()
    if gap > 1e-6:
        raise RuntimeError(f"the bench's projection is {gap:.3g} px from cv2.projectPoints")


def _frame(origin, z, x_hint) -> np.ndarray:
    """A frame at ``origin`` with z along ``z`` and x as near ``x_hint`` as is orthogonal to it."""
    z = z / np.linalg.norm(z)
    x = x_hint - (x_hint @ z) * z
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = np.column_stack([x, np.cross(z, x), z]), origin
    return T


def _pose_entries(T) -> list[float]:
    """``[x, y, z, phi, theta, psi]`` (mm, deg) of ``T = Trans Rz Ry Rx``."""
    R = T[:3, :3]
    ang = [np.arctan2(R[1, 0], R[0, 0]), -np.arcsin(np.clip(R[2, 0], -1, 1)), np.arctan2(R[2, 1], R[2, 2])]
    return [float(v) for v in T[:3, 3]] + [float(v) for v in np.degrees(ang)]


def _visible(T_ct, X) -> bool:
    pc = X @ T_ct[:3, :3].T + T_ct[:3, 3]
    if np.any(pc[:, 2] < 200.0):
        return False
    centre = pc.mean(axis=0)
    if abs(T_ct[:3, 2] @ centre) < np.cos(np.radians(60.0)) * np.linalg.norm(centre):
        return False
    uv = project(pc, K_TRUE)
    return bool(np.all((uv > 20.0) & (uv < np.array([WIDTH, HEIGHT]) - 20.0)))


def make_pixels(root, model, x, rng, rows, *, name, mode, estimate, grid=(7, 10), square=20.0):
    """A camera and a board on the true UR10 ``x``: ``rows`` // (2 corners) images written to
    ``root / name``; returns the equation count (2 a corner)."""
    n_rows, n_cols = grid
    X = np.array([[j * square, i * square, 0.0] for i in range(n_rows) for j in range(n_cols)])
    n_images = max(3, rows // (2 * len(X)))
    F0 = model.forward(x, Q0[None])[0]
    half = np.array([(n_cols - 1) * square / 2, (n_rows - 1) * square / 2, 0.0])
    if mode == "eye-to-hand":  # the board 40 mm out along the tool's z, the camera 800 mm beyond, facing it
        target = _frame(np.zeros(3), np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.2, 0.0]))
        target[:3, 3] = np.array([0.0, 0.0, 40.0]) - target[:3, :3] @ half
        board = F0 @ target
        camera = _frame(board[:3, 3] + 800.0 * F0[:3, 2], -F0[:3, 2], F0[:3, 0])
    else:  # the camera 60 mm out along the tool's z looking along it, the board 600 mm beyond
        camera = _frame(np.array([0.0, 30.0, 60.0]), np.array([0.05, -0.05, 1.0]), np.array([1.0, 0.1, 0.0]))
        cam_w = F0 @ camera
        target = _frame(np.zeros(3), -cam_w[:3, 2], cam_w[:3, 0])
        target[:3, 3] = cam_w[:3, 3] + 600.0 * cam_w[:3, 2] - target[:3, :3] @ half
    q_all, uv_all = [], []
    for _batch in range(100):
        q = Q0 + rng.normal(size=(2000, model.n_joints)) * 0.35
        for qk, F in zip(q, model.forward(x, q), strict=True):
            T_ct = (np.linalg.inv(camera) @ F @ target if mode == "eye-to-hand"
                    else np.linalg.inv(F @ camera) @ target)
            if _visible(T_ct, X):
                if not q_all:
                    _check_against_opencv(T_ct, X)
                q_all.append(qk)
                uv_all.append(project(X @ T_ct[:3, :3].T + T_ct[:3, 3], K_TRUE))
            if len(q_all) == n_images:
                break
        if len(q_all) == n_images:
            break
    else:
        raise RuntimeError(f"{name}: only {len(q_all)} images see the board")
    uv = np.array(uv_all) + rng.normal(size=(n_images, len(X), 2)) * PIXEL_SIGMA
    k_file = K_TRUE.copy()
    scale = {"fx": 1.015, "fy": 0.99, "cx": 1.01, "cy": 0.985}
    for i, n in enumerate(NAMES):
        if n in estimate:
            k_file[i] = K_TRUE[i] * scale[n] if n in scale else 0.0
    meta = {"tool": {"radius": 0.0, "balls": {}}, "noise": {"joint_resolution": 0.0},
            "provenance": {"generator": "bench_types_pixels"},
            "cameras": {"cam": {"mount": "world" if mode == "eye-to-hand" else "tool", "width": WIDTH,
                                "height": HEIGHT, "intrinsics": {n: float(v) for n, v in zip(NAMES, k_file)},
                                "estimate": list(estimate), "pixel_sigma": PIXEL_SIGMA}},
            "targets": {"board": {"mount": "tool" if mode == "eye-to-hand" else "world",
                                  "grid": {"rows": n_rows, "cols": n_cols, "square": square}}}}
    out = root / name
    _write(out, model, np.array(q_all), meta=meta)
    lines = ["pose,camera,point,u,v"] + [
        f"{p + 1},cam,r{i // n_cols}c{i % n_cols},{float(u)!r},{float(v)!r}"
        for p in range(n_images) for i, (u, v) in enumerate(uv[p])]
    (out / "pixels.csv").write_text("\n".join(lines) + "\n")
    return 2 * n_images * len(X)


def _times(root: Path, names: list, repeat: int) -> tuple[dict, dict]:
    """Best CPU time (s) of a default calibration of each dataset ``root / name``, and its result;
    the datasets in turn, ``repeat`` rounds (a load that changes while the bench runs falls on all)."""
    best: dict = {n: np.inf for n in names}
    results: dict = {}
    for _ in range(repeat):
        for n in names:
            cpu, results[n] = cpu_of(root / n, 1)
            best[n] = min(best[n], cpu)
    return best, results


def _profile(path: Path, top: int = 25) -> None:
    import cProfile
    import pstats

    from fgcal.estimation.calibrate import CalibrationOptions, calibrate
    from fgcal.io.dataset_io import dataset_model, load_dataset

    ds = load_dataset(path)
    model = dataset_model(ds)
    prof = cProfile.Profile()
    prof.runcall(calibrate, ds, model, CalibrationOptions())
    pstats.Stats(prof).sort_stats(os.environ.get("SORT", "tottime")).print_stats(top)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rows", type=int, default=3000, help="equations per dataset (about; default 3000)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per dataset, best taken (default 3)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--corners", default="7x10", help="the board's ROWSxCOLS corners (default 7x10)")
    ap.add_argument("--profile", default=None, help="profile the calibration of this dataset instead of timing")
    args = ap.parse_args(argv)
    from fgcal.robots.robot_file import load_model

    grid = tuple(int(v) for v in args.corners.split("x"))
    model = load_model("ur10")
    rng = np.random.default_rng(args.seed)
    x = _truth(model, rng)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        rows = {"centres": make_centres(root, model, x, rng, args.rows)}
        for name, mode, est in (("px_eth_known", "eye-to-hand", ()), ("px_eth_est", "eye-to-hand", ESTIMATE),
                                ("px_eih_est", "eye-in-hand", ESTIMATE)):
            rows[name] = make_pixels(root, model, x, rng, args.rows, name=name, mode=mode, estimate=est, grid=grid)
        if args.profile:
            _profile(root / args.profile)
            return 0
        print(f"UR10, about {args.rows} equations a type; board {args.corners} corners, {PIXEL_SIGMA} px; "
              f"CPU s best of {args.repeat}; single-threaded BLAS")
        print(f"{'type':12s} {'poses':>6s} {'equations':>9s} {'CPU s':>7s} {'us/eq':>7s} {'ratio':>6s} "
              f"{'with joints':>11s} {'us/row':>7s} {'ratio':>6s}  converged")
        best, results = _times(root, list(rows), args.repeat)
        ref = ref_all = None
        for name, n_rows in rows.items():
            cpu, result = best[name], results[name]
            all_rows = n_rows + result.n_poses * model.n_joints
            per, per_all = cpu / n_rows * 1e6, cpu / all_rows * 1e6
            ref = per if ref is None else ref
            ref_all = per_all if ref_all is None else ref_all
            print(f"{name:12s} {result.n_poses:6d} {n_rows:9d} {cpu:7.2f} {per:7.1f} {per / ref:6.2f} "
                  f"{all_rows:11d} {per_all:7.1f} {per_all / ref_all:6.2f}  {result.converged}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
