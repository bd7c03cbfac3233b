"""The pixel measurement's model: the projection against OpenCV's ``projectPoints`` (an independent
reference), its analytic Jacobians in the robot's parameters, the joints, the camera (mount and
intrinsics) and the target against central differences at seeded random points, the closed-form
start (PnP, hand-eye) against known transforms, and the corners refused by name."""
import numpy as np
import pytest

from fgcal.measurements.camera import CameraSpec, TargetSpec, pose_entries, pose_matrix, project
from fgcal.measurements.camera_start import hand_eye, pnp, pnp_each, undistort
from fgcal.measurements.pixels import PIXELS, PixelObservations, pixel_model
from fgcal.measurements.setup import SetupLayout, SetupSpec

cv2 = pytest.importorskip("cv2")

K = np.array([1400.0, 1380.0, 640.0, 512.0, -0.12, 0.08, 0.001, -0.0007, -0.02])


def _random_pose(rng, dist=800.0):
    e = np.concatenate([rng.normal(scale=50, size=2), [dist], rng.uniform(-0.4, 0.4, size=3)])
    return e


def test_projection_equals_opencv_project_points():
    rng = np.random.default_rng(0)
    X = np.column_stack([rng.uniform(-300, 300, 200), rng.uniform(-250, 250, 200), rng.uniform(500, 1500, 200)])
    uv, _, _ = project(X, K)
    cam = np.array([[K[0], 0, K[2]], [0, K[1], K[3]], [0, 0, 1]])
    ref, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), cam, K[[4, 5, 6, 7, 8]])
    assert np.max(np.abs(uv - ref[:, 0])) < 1e-9 * 1e3


def test_projection_jacobians_match_central_differences():
    rng = np.random.default_rng(1)
    X = np.column_stack([rng.uniform(-300, 300, 20), rng.uniform(-250, 250, 20), rng.uniform(500, 1500, 20)])
    _, J_X, J_k = project(X, K)
    for a in range(3):
        h = np.zeros(3)
        h[a] = 1e-4
        num = (project(X + h, K)[0] - project(X - h, K)[0]) / 2e-4
        assert np.max(np.abs(num - J_X[:, :, a])) < 1e-6
    for a in range(9):
        h = np.zeros(9)
        h[a] = 1e-6 * max(1.0, abs(K[a]))
        num = (project(X, K + h)[0] - project(X, K - h)[0]) / (2 * h[a])
        assert np.max(np.abs(num - J_k[:, :, a])) < 1e-4 * max(1.0, np.max(np.abs(J_k[:, :, a])))


def _setup(mode, rng, F=None):
    """A camera and a board; with the tool pose ``F`` (4, 4) the board is 600 mm in front of the camera."""
    cam = CameraSpec("left", "camera", mount="world" if mode == 0 else "tool", width=1280, height=1024,
                     intrinsics=K, estimate=("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"), pixel_sigma=0.3)
    tgt = TargetSpec("board", "target", mount="tool" if mode == 0 else "world",
                     points={f"c{i}": np.array([20.0 * (i % 4), 20.0 * (i // 4), 0.0]) for i in range(12)})
    spec = SetupSpec({"left": cam, "board": tgt})
    mounted = pose_matrix(_random_pose(rng, 100.0))  # the board on the tool, or the camera on the tool
    T_ct = pose_matrix(np.array([-30.0, -20.0, 600.0, 0.1, 0.2, -0.1]))  # the board seen from the camera
    F = np.eye(4) if F is None else F
    if mode == 0:  # camera in the world: T_wc = F T_tt T_ct^-1
        starts = {"left": np.concatenate([pose_entries(F @ mounted @ np.linalg.inv(T_ct)), K]),
                  "board": pose_entries(mounted)}
    else:  # board in the world: T_wt = F T_tc T_ct
        starts = {"left": np.concatenate([pose_entries(mounted), K]), "board": pose_entries(F @ mounted @ T_ct)}
    return spec, SetupLayout.build(spec, starts)


@pytest.mark.parametrize("mode", [0, 1], ids=["eye-to-hand", "eye-in-hand"])
def test_pixel_jacobians_match_central_differences(puma, mode):
    rng = np.random.default_rng(10 + mode)
    names = puma.identifiable_names()
    index = np.array([puma.slot(n) for n in names])
    held = puma.nominal.copy()
    held[index] += rng.normal(scale=0.01, size=len(index))
    theta = held[index].copy()
    n = 6
    q0 = rng.uniform(-1.5, 1.5, size=6)
    q = np.repeat(q0 + rng.normal(scale=0.05, size=(3, 6)), 4, axis=0)  # three poses, four corners each
    spec, layout = _setup(mode, rng, puma.forward(held, q0[None])[0])
    obs = PixelObservations.build(np.repeat([1, 2, 3], 4), ["left"] * 12, [f"c{i}" for i in [0, 3, 5, 11] * 3],
                                  np.zeros((12, 2)), dict(spec.fixtures))
    data = PIXELS._pixel_payload(obs, layout)
    s = layout.start + rng.normal(scale=1e-3, size=layout.size)
    e, J_t, J_q, J_s, cols = PIXELS.setup_error(theta, q, data, s, index, held, puma.chain)
    assert np.all(pixel_model(theta, q, data, s, index, held, puma.chain, need_jac=False)[1][:, 2] > 400)
    assert e.shape == (12, 2) and J_s.shape == (12, 2, 21) and cols.shape == (12, 21)

    def f(th=theta, qq=q, ss=s):
        return PIXELS.setup_error(th, qq, data, ss, index, held, puma.chain)[0]

    def check(J, num, what):
        scale = max(1.0, float(np.max(np.abs(J))))
        assert np.max(np.abs(J - num)) < 2e-5 * scale, what

    for a in range(len(theta)):
        h = 1e-6 if puma.slot_is_angle[index[a]] else 1e-4
        d = np.zeros(len(theta))
        d[a] = h
        check(J_t[:, :, a], (f(th=theta + d) - f(th=theta - d)) / (2 * h), names[a])
    for a in range(n):
        d = np.zeros((1, n))
        d[0, a] = 1e-6
        check(J_q[:, :, a], (f(qq=q + d) - f(qq=q - d)) / 2e-6, f"joint {a}")
    for j in range(21):
        k = cols[0, j]
        h = 1e-6 * max(1.0, abs(s[k]))
        d = np.zeros(len(s))
        d[k] = h
        check(J_s[:, :, j], (f(ss=s + d) - f(ss=s - d)) / (2 * h), layout.names()[j] if j < 15 else f"target {j}")


def test_pnp_and_hand_eye_recover_known_transforms():
    rng = np.random.default_rng(3)
    X = np.array([[25.0 * (i % 7), 25.0 * (i // 7), 0.0] for i in range(35)])
    Xt = pose_matrix(_random_pose(rng, 100.0))
    Yt = pose_matrix(np.array([30.0, -40.0, 1500.0, 0.1, 0.05, np.pi - 0.1]))  # looking down at the origin
    A, B = [], []
    for _ in range(8):
        Ai = pose_matrix(np.concatenate([rng.normal(scale=200, size=3), rng.uniform(-0.5, 0.5, 3)]))
        Bi = np.linalg.inv(Yt) @ Ai @ Xt
        uv = project(X @ Bi[:3, :3].T + Bi[:3, 3], K)[0]
        T, rms = pnp(X, uv, K)
        assert rms < 1e-6 and np.max(np.abs(T - Bi)) < 1e-6
        A.append(Ai)
        B.append(T)
    X_, Y_ = hand_eye(np.array(A), np.array(B))
    assert np.max(np.abs(X_ - Xt)) < 1e-6 and np.max(np.abs(Y_ - Yt)) < 1e-5
    assert np.allclose(pose_matrix(pose_entries(Xt)), Xt)
    n = undistort(project(X + [0, 0, 900.0], K)[0], K)
    assert np.max(np.abs(n - (X[:, :2] / 900.0))) < 1e-9


def test_pnp_of_many_images_at_once_recovers_each_known_pose():
    """pnp_each solves images of equal corner counts together (planar and not in one batch): each
    known pose from OpenCV's pixels within 1e-6, equal to the one-image pnp within 1e-9; a
    non-planar image of five corners (six needed) refused (None) and the planar image of five
    corners in its batch solved; a repeated image answered from the memo."""
    rng = np.random.default_rng(8)
    cam = np.array([[K[0], 0, K[2]], [0, K[1], K[3]], [0, 0, 1]])
    grid = np.array([[25.0 * (i % 7), 25.0 * (i // 7), 0.0] for i in range(35)])
    images, truth = [], []
    for j in range(9):
        X = grid + np.column_stack([np.zeros((35, 2)), rng.uniform(-40, 40, 35) * (j in (0, 3, 6, 7))])
        X = X[[0, 6, 17, 28, 34]] if j in (7, 8) else X[:20] if j == 5 else X
        T = pose_matrix(_random_pose(rng))
        uv = cv2.projectPoints(X, cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], cam, K[4:])[0][:, 0]
        images.append((X, uv))
        truth.append(T)
    memo: dict = {}
    got = pnp_each(images + images[:1], K, memo)
    assert got[7] is None and len(memo) == 9 and got[9] is got[0]
    for j in (0, 1, 2, 3, 4, 5, 6, 8):
        T, rms = got[j]
        assert rms < 1e-6 and np.max(np.abs(T - truth[j])) < 1e-6
        one = pnp(*images[j], K)
        assert np.max(np.abs(one[0] - T)) < 1e-9


def test_refused_corners_are_named(puma):
    """A corner behind the camera, one at a grazing angle and one measured off the image are refused
    and named; the others are kept."""
    rng = np.random.default_rng(5)
    spec, layout = _setup(0, rng)
    cam = spec.fixtures["left"]
    Tc = pose_matrix(np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0]))  # the camera at the world origin, looking along z
    spec = SetupSpec({"left": CameraSpec("left", "camera", mount="world", width=1280, height=1024, intrinsics=K,
                                         pixel_sigma=0.3, start_pose=pose_entries(Tc)),
                      "board": TargetSpec("board", "target", mount="tool", points=spec.fixtures["board"].points,
                                          start_pose=np.zeros(6))})
    assert cam.estimate
    # tool poses: the board 800 mm in front, facing the camera; one behind; one seen edge-on
    front = pose_matrix(np.array([-30.0, -20.0, 800.0, 0.0, 0.0, 0.0]))
    behind = pose_matrix(np.array([0.0, 0.0, -500.0, 0.0, 0.0, 0.0]))
    edge = pose_matrix(np.array([0.0, 0.0, 800.0, 0.0, np.radians(89.5), 0.0]))
    poses = [front, behind, edge, front]
    uv = np.array([[700.0, 500.0], [700.0, 500.0], [700.0, 500.0], [2000.0, 500.0]])
    obs = PixelObservations.build([1, 2, 3, 4], ["left"] * 4, ["c0"] * 4, uv, dict(spec.fixtures))
    keep, refused = PIXELS.admit(obs, np.array(poses))
    assert keep.tolist() == [True, False, False, False]
    assert [(r["pose"], r["reason"].split()[0]) for r in refused] == [(2, "behind"), (3, "seen"), (4, "measured")]
