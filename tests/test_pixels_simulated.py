"""Camera calibration against an independent simulation (tests/pixel_sim.py: contact_sim's own URDF
forward kinematics of a perturbed robot, OpenCV's projectPoints, 0.3 px noise): a 7R (Panda) and
a 6R (Kinova), eye-to-hand and eye-in-hand, intrinsics known and estimated.

Checked: the board's corners at held-out poses (in the camera's frame, which needs no choice of
world or tool frame) within 1.5 times the accuracy the covariance predicts; the intrinsics and the
camera mount within their sigmas, the mount after expressing the truth in the calibration's frame
(base and tool held at nominal: the true robot's base and tool are fitted by least squares of the
nominal model to the true forward kinematics); and over 25 seeded datasets their chi-square per
degree of freedom in 0.7-1.5."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import least_squares

pytest.importorskip("cv2")

from contact_sim import UrdfChain
from pixel_sim import camera_dataset, pose

from fgcal.estimation.calibrate import CalibrationOptions, calibrate
from fgcal.estimation.result import load_result
from fgcal.io.dataset_io import dataset_model, load_dataset

DATA = Path(__file__).parent / "data" / "urdf"
ROBOTS = {"panda": ("panda.urdf", {"base": "panda_link0", "tip": "panda_hand_tcp"}),
          "kinova": ("kinova.urdf", {"tip": "j2s6s200_end_effector"})}
ALL = ("fx", "fy", "cx", "cy", "k1", "k2")
MOUNT = ("px", "py", "pz", "phi", "theta", "psi")


def _entries_matrix(e):
    """``Trans Rz Ry Rx`` of entries (mm, deg): pixel_sim's own composition."""
    return pose(np.asarray(e[:3], float), *np.radians(e[3:6]))


def _solve(tmp, robot, mode, estimate, seed, **kw):
    name, chain = ROBOTS[robot]
    truth = camera_dataset(tmp, DATA / name, chain, np.random.default_rng(seed), mode=mode, estimate=estimate, **kw)
    ds = load_dataset(tmp)
    model = dataset_model(ds)
    return truth, model, calibrate(ds, model, CalibrationOptions())


def _values(result):
    return {p.name: p.estimate for p in result.parameters}


def _board_points(result, model, truth, values, q):
    """The board's corners (H * m, 3) in the camera frame predicted at joint sets ``q`` for parameter
    values ``values`` ({name: file units}), the others at the result's."""
    slots = result.slot_vector(model).copy()
    for n, v in values.items():
        if n in model.slot_names:
            k = model.slot(n)
            slots[k] = np.radians(v) if model.slot_is_angle[k] else v
    est = result.setup["estimated"]
    cam = [values.get(f"camera.left.{c}", est["left"]["pose"][i]) for i, c in enumerate(MOUNT)]
    tgt = [values.get(f"target.board.{c}", est["board"]["pose"][i]) for i, c in enumerate(MOUNT)]
    Tc, Tt = _entries_matrix(cam), _entries_matrix(tgt)
    F = model.forward(slots, q)
    out = []
    for Fi in F:
        T_ct = np.linalg.inv(Tc) @ (Fi @ Tt if truth.mode == "eye-to-hand" else np.linalg.inv(Fi) @ Tt)
        out.append(truth.points @ T_ct[:3, :3].T + T_ct[:3, 3])
    return np.concatenate(out)


def _held_out_check(result, model, truth):
    """RMS error (mm) of the corners in the camera frame at held-out poses, and the RMS the covariance predicts."""
    true = UrdfChain(truth.urdf, truth.chain.get("base"), truth.chain.get("tip"))
    q = truth.held_out
    ref = np.concatenate([truth.points @ T[:3, :3].T + T[:3, 3]
                          for T in (truth.board_in_camera(true.fk(qi)) for qi in q)])
    names = [p.name for p in result.parameters]
    base = _values(result)
    pred = _board_points(result, model, truth, base, q)
    J = np.empty((pred.size, len(names)))
    for a, n in enumerate(names):
        h = 1e-4
        up, dn = dict(base), dict(base)
        up[n] += h
        dn[n] -= h
        J[:, a] = (_board_points(result, model, truth, up, q)
                   - _board_points(result, model, truth, dn, q)).ravel() / (2 * h)
    C = np.asarray(result.covariance)
    predicted = float(np.sqrt(np.einsum("ij,jk,ik->", J, C, J) / len(pred)))
    return float(np.sqrt(np.mean(np.sum((pred - ref) ** 2, axis=1)))), predicted


def _gauge(result, model, truth):
    """The true robot in the calibration's frames: ``T_g`` (world) and ``T_x`` (tool) with
    ``FK_model(theta, q) = T_g FK_true(q) T_x`` for the estimated robot parameters fitted to the truth."""
    true = UrdfChain(truth.urdf, truth.chain.get("base"), truth.chain.get("tip"))
    q = np.random.default_rng(7).uniform(-2.0, 2.0, size=(60, model.n_joints))
    q = np.clip(q, model.joint_limits[:, 0], model.joint_limits[:, 1])
    F_true = true.fk(q)
    robot = [p.name for p in result.parameters if p.name in model.slot_names]
    idx = [model.slot(n) for n in robot]
    slots0 = result.slot_vector(model).copy()

    def unpack(x):
        s = slots0.copy()
        s[idx] = x[:len(idx)]
        return s, pose(x[-12:-9], *x[-9:-6]), pose(x[-6:-3], *x[-3:])

    def fun(x):
        s, Tg, Tx = unpack(x)
        D = model.forward(s, q) - Tg @ F_true @ Tx
        return np.concatenate([D[:, :3, 3].ravel(), 100.0 * D[:, :3, :3].ravel()])

    x0 = np.concatenate([slots0[idx], np.zeros(12)])
    sol = least_squares(fun, x0, x_scale="jac", xtol=1e-14, ftol=1e-14)
    assert np.max(np.abs(sol.fun)) < 1e-5, "the nominal model does not reach the true robot"
    return unpack(sol.x)[1:]


def _z_scores(result, model, truth, estimate):
    """(estimate - truth) / sigma of the estimated intrinsics and the camera mount (the truth in the
    calibration's frames)."""
    sig = {p.name: p.sigma for p in result.parameters}
    val = _values(result)
    Tg, Tx = _gauge(result, model, truth)
    cam = Tg @ truth.camera if truth.mode == "eye-to-hand" else np.linalg.inv(Tx) @ truth.camera
    R = cam[:3, :3]
    mount = np.concatenate([cam[:3, 3], np.degrees([np.arctan2(R[1, 0], R[0, 0]), -np.arcsin(R[2, 0]),
                                                     np.arctan2(R[2, 1], R[2, 2])])])
    z = [(val[f"camera.left.{c}"] - mount[i]) / sig[f"camera.left.{c}"] for i, c in enumerate(MOUNT)]
    k = dict(zip(("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"), truth.k, strict=True))
    z += [(val[f"camera.left.{c}"] - k[c]) / sig[f"camera.left.{c}"] for c in estimate]
    return np.array(z)


CASES = [("panda", "eye-to-hand", ()), ("panda", "eye-in-hand", ALL), ("kinova", "eye-to-hand", ALL),
         ("kinova", "eye-in-hand", ())]


@pytest.mark.parametrize("robot,mode,estimate", CASES, ids=[f"{r}-{m}-{'intrinsics' if e else 'known'}"
                                                            for r, m, e in CASES])
def test_camera_calibration_reaches_the_noise_limit(tmp_path, robot, mode, estimate):
    truth, model, result = _solve(tmp_path / "ds", robot, mode, estimate, seed=1, n_images=12)
    assert result.converged
    assert 0.6 < result.levels["pixels"].variance_factor < 1.6  # the pixel noise (0.3 px) found
    assert result.levels["pixels"].unit == "px"
    assert result.setup["start"]["left"]["type"] == "camera"  # the start is reported
    assert {h["name"] for h in result.held} >= {"base.px", "tool.px"}  # both frames are gauges here
    err, predicted = _held_out_check(result, model, truth)
    assert err < 1.5 * predicted, (err, predicted)
    assert predicted < 5.0  # mm: twelve images of 20 corners place the board to a few millimetres or better
    z = _z_scores(result, model, truth, estimate)
    assert np.all(np.abs(z) < 4.0), z


def test_camera_sigmas_are_honest_over_25_datasets(tmp_path):
    """Over 25 seeded datasets (Kinova, eye-to-hand, six intrinsics estimated, 8 images of 12
    corners): the chi-square per degree of freedom of the camera mount and the intrinsics in
    0.7-1.5, and the board's corners at 10 held-out poses each within 1.5 times the accuracy the
    covariance predicts (RMS over the datasets). The first 10 datasets by default (about a minute
    alone); all 25 with FGCAL_HEAVY=1 (measured: chi-square per dof 0.921, held-out ratio 0.922)."""
    import os

    z, err2, pred2 = [], [], []
    for seed in range(25 if os.environ.get("FGCAL_HEAVY") else 10):
        truth, model, result = _solve(tmp_path / f"ds{seed}", "kinova", "eye-to-hand", ALL, seed=100 + seed,
                                      n_images=8, rows=3, cols=4, square=40.0, n_held_out=10)
        assert result.converged
        z.append(_z_scores(result, model, truth, ALL))
        err, predicted = _held_out_check(result, model, truth)
        err2.append(err**2)
        pred2.append(predicted**2)
    z = np.array(z)
    chi2 = float(np.mean(z**2))
    ratio = float(np.sqrt(np.mean(err2) / np.mean(pred2)))
    print(f"chi-square per dof over {len(z)} datasets: {chi2:.3f}; "
          f"per entry {np.round(np.mean(z**2, axis=0), 2).tolist()}; held-out corners: RMS error / predicted "
          f"{ratio:.3f} (predicted {np.sqrt(np.mean(pred2)):.3f} mm)")
    assert 0.7 < chi2 < 1.5, (chi2, np.mean(z**2, axis=0))
    assert ratio < 1.5, ratio


def _cli(*args):
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-m", "fgcal.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=600)


def test_calibrate_verify_report_and_refusals_through_the_cli(tmp_path):
    """Calibrate on 10 images, verify on 6 held-out ones: the reprojection error (px) at the
    calibrated model is near the pixel noise (0.3 px per coordinate: about 0.42 px per corner) and
    far below the nominal model's; a corner measured off the image is refused and named in the
    result; the report shows the images' residuals in px; bad input exits 2 in one line."""
    truth = camera_dataset(tmp_path / "all", DATA / "kinova.urdf", ROBOTS["kinova"][1], np.random.default_rng(8),
                           mode="eye-in-hand", n_images=16, n_held_out=0)
    assert len(truth.q) == 16
    lines = (tmp_path / "all" / "pixels.csv").read_text().splitlines()
    pose, cam, point, _, v = lines[1].split(",")
    lines[1] = ",".join([pose, cam, point, "5000.0", v])  # off the 1280-px image
    (tmp_path / "all" / "pixels.csv").write_text("\n".join(lines) + "\n")
    from fgcal.io.dataset_io import save_dataset

    ds = load_dataset(tmp_path / "all")
    save_dataset(ds.select(ds.pose_ids[:10]), tmp_path / "cal")
    save_dataset(ds.select(ds.pose_ids[10:]), tmp_path / "check")
    for d in ("cal", "check"):
        (tmp_path / d / "robot.urdf").write_text((tmp_path / "all" / "robot.urdf").read_text())
    back = load_dataset(tmp_path / "cal")  # the written cameras: and targets: read back
    assert back.setup.fixtures["left"].mount == "tool" and len(back.setup.fixtures["board"].points) == 20
    assert np.array_equal(back.pixels.uv, ds.select(ds.pose_ids[:10]).pixels.uv)
    run = _cli("calibrate", tmp_path / "cal", "--out", tmp_path / "r.json")
    assert run.returncode == 0, run.stderr

    result = load_result(tmp_path / "r.json")
    assert result.setup["refused"] == [{"level": "pixels", "pose": 1, "camera": "left", "point": point,
                                        "reason": "measured off the image"}]
    run = _cli("verify", tmp_path / "r.json", tmp_path / "check", "--out", tmp_path / "v.json")
    assert run.returncode == 0, run.stderr
    import json

    v = json.loads((tmp_path / "v.json").read_text())
    assert "reprojection" in v["reference"] and v["n_poses"] == 6
    assert 0.3 < v["position_mm"]["rms"] < 0.6, v["position_mm"]  # px here: 0.3 px per coordinate
    assert v["before"]["position_mm"]["rms"] > 3 * v["position_mm"]["rms"]
    run = _cli("report", tmp_path / "r.json", "--out", tmp_path / "rep")
    assert run.returncode == 0, run.stderr
    text = next((tmp_path / "rep").glob("*.md")).read_text()
    assert "reprojection error" in text and "camera.left.px" in text
    # export: the camera's mount as the link camera_left_optical on the tool link, intrinsics beside
    run = _cli("export", tmp_path / "r.json", "--urdf", tmp_path / "out.urdf")
    assert run.returncode == 0, run.stderr
    urdf = (tmp_path / "out.urdf").read_text()
    chain = UrdfChain(urdf, "world", "camera_left_optical")  # the tests' own URDF reader
    model = dataset_model(load_dataset(tmp_path / "cal"))
    q = truth.q[:3]
    est = result.setup["estimated"]["left"]
    T_tc = _entries_matrix(est["pose"])
    fgcal_cam = model.forward(result.slot_vector(model), q) @ T_tc
    assert np.max(np.abs(chain.fk(q)[:, :3, 3] - fgcal_cam[:, :3, 3])) < 1e-6  # mm
    assert np.max(np.abs(chain.fk(q)[:, :3, :3] - fgcal_cam[:, :3, :3])) < 1e-9
    import yaml

    info = yaml.safe_load((tmp_path / "out.urdf.camera_left.yaml").read_text())
    assert info["image_width"] == 1280 and info["distortion_model"] == "plumb_bob"
    assert info["camera_matrix"]["data"][0] == pytest.approx(est["intrinsics"]["fx"])
    # the online engines and design take pixels (tests/test_online_pixels.py, tests/test_design_cameras.py)
    run = _cli("online", tmp_path / "cal", "--engine", "ekf", "--out", tmp_path / "online.json")
    assert run.returncode == 0 and "Traceback" not in run.stderr, run.stderr
    online = load_result(tmp_path / "online.json")
    assert online.names == result.names and online.setup["refused"] == result.setup["refused"]  # named alike
    assert np.max(np.abs(online.estimate - result.estimate) / result.sigma) < 0.1
    run = _cli("design", "--dataset", tmp_path / "cal", "--poses", "5", "--out", tmp_path / "plan.csv")
    assert run.returncode == 0 and "Traceback" not in run.stderr, run.stderr
    assert len((tmp_path / "plan.csv").read_text().strip().splitlines()) == 1 + 5
    bad = (tmp_path / "cal" / "pixels.csv").read_text().replace(",left,", ",right,", 1)
    (tmp_path / "cal" / "pixels.csv").write_text(bad)
    run = _cli("calibrate", tmp_path / "cal", "--out", tmp_path / "r2.json")
    assert run.returncode == 2 and "camera 'right' is not in dataset.yaml's cameras" in run.stderr, run.stderr
    assert len(run.stderr.strip().splitlines()) == 1 and "Traceback" not in run.stderr


def _ball_check(result, model, truth, ball):
    """RMS error (mm) of the tool ball at held-out poses against the truth (world = the tracker's
    frame, which the reflector fixes), and the RMS the covariance predicts."""
    true = UrdfChain(truth.urdf, truth.chain.get("base"), truth.chain.get("tip"))
    q = truth.held_out
    ref = true.point(q, ball)
    names = [p.name for p in result.parameters]
    base = _values(result)

    def predict(values):
        slots = result.slot_vector(model).copy()
        for n, v in values.items():
            if n in model.slot_names:
                k = model.slot(n)
                slots[k] = np.radians(v) if model.slot_is_angle[k] else v
        F = model.forward(slots, q)
        return F[:, :3, :3] @ ball + F[:, :3, 3]

    pred = predict(base)
    J = np.empty((pred.size, len(names)))
    for a, n in enumerate(names):
        up, dn = dict(base), dict(base)
        up[n] += 1e-4
        dn[n] -= 1e-4
        J[:, a] = (predict(up) - predict(dn)).ravel() / 2e-4
    predicted = float(np.sqrt(np.einsum("ij,jk,ik->", J, np.asarray(result.covariance), J) / len(pred)))
    return float(np.sqrt(np.mean(np.sum((pred - ref) ** 2, axis=1)))), predicted


def test_a_camera_and_a_reflector_calibrate_in_one_solve(tmp_path):
    """Eye-to-hand pixels and a tracker's reflector (0.02 mm) on the same 20 poses: one solve finds
    both noises, the tracker fixes the world (the base is estimated, the camera is in the tracker's
    frame: its position within 4 sigma of the truth), the ball and the board are each within 1.5
    times their predicted accuracy, and the camera's accuracy is checked against the reflector's:
    the board from the joint solve is predicted no worse than from the camera alone, and the camera
    alone is within 2 times its own prediction (one seed's draw; 25 datasets test the ratio)."""
    ball = np.array([0.0, 0.0, 30.0])
    truth, model, both = _solve(tmp_path / "both", "kinova", "eye-to-hand", (), seed=5, n_images=20,
                                tool_ball=ball, reflector_sigma=0.02)
    assert both.converged
    assert set(both.levels) >= {"pixels", "centres"}
    for lv in ("pixels", "centres"):
        assert 0.5 < both.levels[lv].variance_factor < 1.8, (lv, both.levels[lv].variance_factor)
    held = {h["name"] for h in both.held}
    assert not held & {"base.px", "base.py", "base.pz", "tool.px", "tool.py", "tool.pz"}  # the tracker fixes them
    err, predicted = _ball_check(both, model, truth, ball)
    assert err < 1.5 * predicted and predicted < 0.05, (err, predicted)
    err_cam, pred_cam = _held_out_check(both, model, truth)
    assert err_cam < 1.5 * pred_cam, (err_cam, pred_cam)
    est = both.setup["estimated"]["left"]["pose"]  # the camera in the tracker's frame: the truth's, no gauge
    sig = {p.name: p.sigma for p in both.parameters}
    for i, c in enumerate(("px", "py", "pz")):
        assert abs(est[i] - truth.camera[i, 3]) < 4 * sig[f"camera.left.{c}"], (c, est[i], truth.camera[i, 3])
    import shutil

    shutil.copytree(tmp_path / "both", tmp_path / "camera")
    (tmp_path / "camera" / "centres.csv").unlink()
    alone = calibrate(load_dataset(tmp_path / "camera"), model, CalibrationOptions())
    err_alone, pred_alone = _held_out_check(alone, model, truth)
    assert err_alone < 2.0 * pred_alone, (err_alone, pred_alone)
    assert pred_cam <= pred_alone * 1.01, (pred_cam, pred_alone)  # the reflector adds information
    print(f"camera and reflector: ball {err:.4f} mm (predicted {predicted:.4f}), board {err_cam:.3f} mm "
          f"(predicted {pred_cam:.3f}); camera alone: board {err_alone:.3f} mm (predicted {pred_alone:.3f})")


def test_the_gtsam_engine_takes_pixels_like_the_batch(tmp_path):
    """``--engine gtsam`` on camera data (eye-in-hand, four intrinsics estimated): the same estimates
    (to 1e-4 sigma) and sigmas (to 1e-6) as the batch engine."""
    name, chain = ROBOTS["kinova"]
    camera_dataset(tmp_path / "ds", DATA / name, chain, np.random.default_rng(21), mode="eye-in-hand", n_images=8,
                   rows=3, cols=4, square=40.0, estimate=("fx", "fy", "cx", "cy"), n_held_out=0)
    ds = load_dataset(tmp_path / "ds")
    model = dataset_model(ds)
    batch = calibrate(ds, model, CalibrationOptions())
    gt = calibrate(ds, model, CalibrationOptions(engine="gtsam"))
    a = {p.name: p for p in batch.parameters}
    b = {p.name: p for p in gt.parameters}
    assert set(a) == set(b) and any(n.startswith("camera.left.f") for n in a)
    assert max(abs(a[n].estimate - b[n].estimate) / a[n].sigma for n in a) < 1e-4
    assert max(abs(a[n].sigma / b[n].sigma - 1) for n in a) < 1e-6
