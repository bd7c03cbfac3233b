"""Chessboard corners in images, with OpenCV (an extra: ``pip install fgcal[camera]``), for ``fgcal detect``.

A board of ``rows x cols`` inner corners: its points are named ``r{i}c{j}`` at ``(j square, i
square, 0)`` mm, as ``dataset.yaml``'s ``grid:`` target defines them (DESIGN.md 8.4). OpenCV finds
the corners row by row from one of the board's ends; which end is not fixed (a board turned by
half a turn looks the same), so each image's corners are numbered from the end that keeps the
first row's direction in the image nearest the first image's (a board turned by less than 90 deg
between images keeps its numbering). Each image's pose id is the last integer in its file name
(``img_012.png``: 12), or its place in the list (from 1) when no name has one.
"""
from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field
from pathlib import Path

from fgcal.errors import FgcalError

__all__ = ["BoardCorners", "find_board", "image_pose_ids", "parse_grid"]

log = logging.getLogger(__name__)


def parse_grid(text: str) -> tuple[int, int]:
    """``ROWSxCOLS`` (inner corners) as two integers, each 2 to 100; FgcalError otherwise."""
    m = re.fullmatch(r"\s*(\d{1,3})\s*[xX]\s*(\d{1,3})\s*", str(text))
    if not m or not all(2 <= int(v) <= 100 for v in m.groups()):
        raise FgcalError(f"--grid must be ROWSxCOLS of inner corners, each 2 to 100 (got {str(text)[:30]!r})")
    return int(m.group(1)), int(m.group(2))


def image_pose_ids(paths) -> list[int]:
    """Each image's pose id: the last integer in its file name, or its place (from 1) when no name has
    one; FgcalError when only some have one, or two images share an id."""
    numbers = [re.findall(r"\d+", Path(p).stem) for p in paths]
    if not any(numbers):
        return list(range(1, len(paths) + 1))
    missing = [str(p) for p, n in zip(paths, numbers, strict=True) if not n]
    if missing:
        raise FgcalError(f"{missing[0]}: no pose number in the file name (the others have one: img_012.png is pose 12)")
    ids = [int(n[-1]) for n in numbers]
    seen: dict[int, str] = {}
    for p, i in zip(paths, ids, strict=True):
        if i in seen:
            raise FgcalError(f"{p}: pose {i} is {seen[i]}'s too (the last number in the file name is the pose id)")
        seen[i] = str(p)
    return ids


@dataclass
class BoardCorners:
    """The corners found: per image (in the order given) its pose id and pixels (rows * cols, 2) or
    None where the board was not found; the images' size (px)."""

    rows: int
    cols: int
    pose_ids: list[int]
    uv: list = field(default_factory=list)  # (rows * cols, 2) or None, per image
    size: tuple[int, int] | None = None  # (width, height) px of the first image read

    @property
    def point_names(self) -> list[str]:
        return [f"r{i}c{j}" for i in range(self.rows) for j in range(self.cols)]


def _cv2():
    try:
        import cv2
    except ImportError:
        raise FgcalError("fgcal detect needs OpenCV: pip install fgcal[camera]") from None
    return cv2


def find_board(paths, rows: int, cols: int) -> BoardCorners:
    """The ``rows x cols`` chessboard's corners (sub-pixel) in each of the images ``paths``."""
    cv2 = _cv2()
    paths = [Path(p) for p in paths]
    out = BoardCorners(rows, cols, image_pose_ids(paths))
    reference = None  # the first image's first-row direction
    for p in paths:
        if not p.is_file():
            raise FgcalError(f"{p}: no such image")
        img = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise FgcalError(f"{p}: not an image OpenCV reads")
        if out.size is None:
            out.size = (int(img.shape[1]), int(img.shape[0]))
        elif out.size != (img.shape[1], img.shape[0]):
            raise FgcalError(f"{p}: {img.shape[1]} x {img.shape[0]} px, the first image is "
                             f"{out.size[0]} x {out.size[1]} (one camera's images)")
        ok, found = cv2.findChessboardCorners(img, (cols, rows),
                                              flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
        if not ok:
            log.info("%s: no %d x %d board found", p, rows, cols)
            out.uv.append(None)
            continue
        criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
        found = cv2.cornerSubPix(img, found, (5, 5), (-1, -1), criteria).reshape(-1, 2).astype(float)
        direction = found[cols - 1] - found[0]
        if reference is None:
            reference = direction
        elif float(direction @ reference) < 0:  # OpenCV started from the other end: the same numbering
            found = found[::-1].copy()
        out.uv.append(found)
    return out
