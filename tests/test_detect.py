"""``fgcal detect``: chessboard corners found in images rendered here (a board texture warped by
the homography of a known camera and board pose, OpenCV's warpPerspective at four times the
resolution, averaged down) are the board's true
corners projected by OpenCV's projectPoints, to a small fraction of a pixel, numbered as
``grid:`` names them (a chessboard's numbering is known up to half a turn: the first image's, kept
in the others); an image without the board is named and skipped; bad input is one line."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("cv2")

import cv2
from pixel_sim import cv_project, pose

from fgcal.api.detecting import detect
from fgcal.errors import FgcalError

K = np.array([900.0, 905.0, 640.0, 480.0, 0.0, 0.0, 0.0, 0.0, 0.0])
SIZE = (1280, 960)
ROWS, COLS, SQUARE = 5, 7, 20.0
PX_PER_MM = 8  # the texture's resolution


def _texture():
    """The board: (ROWS+1) x (COLS+1) squares and a white border of one square; its first inner corner
    at texture pixel edge (2 P, 2 P), P pixels a square."""
    P = int(SQUARE * PX_PER_MM)
    img = np.full(((ROWS + 3) * P, (COLS + 3) * P), 255, np.uint8)
    for i in range(ROWS + 1):
        for j in range(COLS + 1):
            if (i + j) % 2 == 0:
                img[(i + 1) * P:(i + 2) * P, (j + 1) * P:(j + 2) * P] = 0
    return img


def _render(T_ct, f: int = 4):
    """The board seen at ``T_ct`` (board in camera, mm), and its true corners (ROWS*COLS, 2) px:
    rendered at ``f`` times the resolution and averaged down (an image's pixels integrate light)."""
    # pixel u of the image is sub-pixel f u + (f - 1) / 2 of the fine one
    cam = np.array([[K[0] * f, 0, K[2] * f + (f - 1) / 2], [0, K[1] * f, K[3] * f + (f - 1) / 2], [0, 0, 1.0]])
    board_to_image = cam @ np.column_stack([T_ct[:3, 0], T_ct[:3, 1], T_ct[:3, 3]])
    # texture pixel centre (x, y) -> board mm: (x + 0.5) / s - 2 * square
    s = PX_PER_MM
    texture_to_board = np.array([[1 / s, 0, 0.5 / s - 2 * SQUARE], [0, 1 / s, 0.5 / s - 2 * SQUARE], [0, 0, 1.0]])
    H = board_to_image @ texture_to_board
    fine = cv2.warpPerspective(_texture(), H, (SIZE[0] * f, SIZE[1] * f), flags=cv2.INTER_LINEAR, borderValue=200)
    img = cv2.resize(fine, SIZE, interpolation=cv2.INTER_AREA)
    X = np.array([[j * SQUARE, i * SQUARE, 0.0] for i in range(ROWS) for j in range(COLS)])
    return img, cv_project(T_ct, X, K)


def _board_pose(centre, rx=0.0, ry=0.0, rz=0.0):
    """The board in the camera: its middle at ``centre`` (mm, camera frame), turned by ``rz`` in its
    plane and tilted by ``rx``, ``ry`` (deg) from facing the camera."""
    R = pose([0.0, 0.0, 0.0], *np.radians([rz, ry, rx]))[:3, :3]
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(centre, float) - R @ np.array([(COLS - 1) * SQUARE / 2, (ROWS - 1) * SQUARE / 2, 0.0])
    return T


def test_corners_are_the_projected_truth(tmp_path):
    # within 90 deg of each other in the image: a chessboard's numbering is kept across them
    poses = {3: _board_pose([0.0, 0.0, 500.0], 10.0, -15.0, 5.0), 7: _board_pose([-80.0, 60.0, 450.0], -20.0, 10.0, 35.0),
             12: _board_pose([120.0, -40.0, 600.0], 25.0, 20.0, -40.0)}
    truth = {}
    for pid, T in poses.items():
        img, uv = _render(T)
        cv2.imwrite(str(tmp_path / f"img_{pid:03d}.png"), img)
        truth[pid] = uv
    cv2.imwrite(str(tmp_path / "img_020.png"), np.full((SIZE[1], SIZE[0]), 128, np.uint8))  # no board
    images = sorted(tmp_path.glob("img_*.png"))
    with pytest.warns(UserWarning, match="img_020.png: no 5 x 7 board found"):
        d = detect(images, "5x7", SQUARE, tmp_path / "pixels.csv")
    assert d.found == {3: 35, 7: 35, 12: 35} and d.missed == [str(tmp_path / "img_020.png")]
    rows = (tmp_path / "pixels.csv").read_text().split()
    assert rows[0] == "pose,camera,point,u,v" and len(rows) == 1 + 105
    got: dict = {}
    for r in rows[1:]:
        pid, cam, point, u, v = r.split(",")
        assert cam == "left"
        i, j = (int(x) for x in point[1:].split("c"))
        got.setdefault(int(pid), np.zeros((ROWS * COLS, 2)))[i * COLS + j] = (float(u), float(v))
    if np.linalg.norm(got[3] - truth[3], axis=1).max() > 10.0:  # the first image numbered from the other end
        got = {p: g[::-1] for p, g in got.items()}
    err = np.concatenate([np.linalg.norm(got[p] - truth[p], axis=1) for p in poses])
    assert np.sqrt(np.mean(err**2)) < 0.1 and err.max() < 0.3, (np.sqrt(np.mean(err**2)), err.max())
    assert "grid: {rows: 5, cols: 7, square: 20}" in "\n".join(d.lines) and "width: 1280" in "\n".join(d.lines)


def test_bad_input_is_one_line(tmp_path):
    img, _ = _render(_board_pose([0.0, 0.0, 500.0]))
    cv2.imwrite(str(tmp_path / "a1.png"), img)
    (tmp_path / "b.png").write_bytes(b"not an image")
    with pytest.raises(FgcalError, match="--grid must be ROWSxCOLS"):
        detect([tmp_path / "a1.png"], "5by7", SQUARE, tmp_path / "p.csv")
    with pytest.raises(FgcalError, match="b.png: no pose number in the file name"):
        detect([tmp_path / "a1.png", tmp_path / "b.png"], "5x7", SQUARE, tmp_path / "p.csv")
    with pytest.warns(UserWarning, match="no 4 x 4 board found"), \
            pytest.raises(FgcalError, match="no 4 x 4 board in any of the 1 images"):
        detect([tmp_path / "a1.png"], "4x4", SQUARE, tmp_path / "p.csv")
    assert not (tmp_path / "p.csv").exists()
    run = subprocess.run([sys.executable, "-m", "fgcal.cli", "detect", str(tmp_path / "b.png"), "--grid", "5x7",
                          "--square", "20", "--out", str(tmp_path / "p.csv")], capture_output=True, text=True)
    assert run.returncode == 2 and run.stderr.count("\n") == 1 and "not an image OpenCV reads" in run.stderr
    assert "Traceback" not in run.stderr
