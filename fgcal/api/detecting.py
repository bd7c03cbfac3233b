"""``fgcal.detect``: chessboard corners in a folder of images -> ``pixels.csv`` (DESIGN.md 8.4)."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from fgcal.api.notes import warn
from fgcal.errors import FgcalError

__all__ = ["Detection", "detect"]


@dataclass
class Detection:
    """What :func:`detect` found and wrote.

    Attributes
    ----------
    out : Path
        The ``pixels.csv`` written.
    found : dict of int to int
        Pose id -> corners written, per image with the board.
    missed : list of str
        The images without the board (named, nothing written for them).
    lines : list of str
        What ``fgcal detect`` prints: a summary and the ``cameras:`` / ``targets:`` entries for
        ``dataset.yaml``.
    """

    out: Path
    found: dict = field(default_factory=dict)
    missed: list = field(default_factory=list)
    lines: list = field(default_factory=list)


def detect(images, grid: str, square: float, out, camera: str = "left", target: str = "board") -> Detection:
    """Find a chessboard of ``grid`` (``ROWSxCOLS`` inner corners, ``square`` mm) in ``images``
    and write its corners as ``pixels.csv`` rows ``pose,camera,point,u,v`` to ``out`` (atomically;
    the path is checked before the images are read).

    Raises
    ------
    FgcalError
        One line: OpenCV missing, an image unreadable or of another size, a file name without the
        pose number the others have, or the board in no image.

    Warns
    -----
    FgcalWarning
        Each image without the board.
    """
    from fgcal.io.corners import find_board, parse_grid
    from fgcal.io.dataset_io import write_csv

    rows, cols = parse_grid(grid)
    if not (square > 0):
        raise FgcalError(f"--square must be a positive length in mm, got {square:g}")
    images = [Path(p) for p in images]
    if not images:
        raise FgcalError("fgcal detect needs one or more images")
    out = Path(out)
    if not out.parent.is_dir() or out.is_dir():
        raise FgcalError(f"--out {out}: {'is a folder' if out.is_dir() else 'its folder does not exist'}")
    if any(out.resolve() == p.resolve() for p in images):
        raise FgcalError(f"--out {out}: is one of the images; refusing to overwrite it")
    corners = find_board(images, rows, cols)
    names = corners.point_names
    rec, found, missed = [], {}, []
    for path, pid, uv in zip(images, corners.pose_ids, corners.uv, strict=True):
        if uv is None:
            missed.append(str(path))
            warn(f"{path}: no {rows} x {cols} board found (nothing written for pose {pid})")
            continue
        found[pid] = len(uv)
        rec += [[pid, camera, n, float(u), float(v)] for n, (u, v) in zip(names, uv, strict=True)]
    if not found:
        raise FgcalError(f"no {rows} x {cols} board in any of the {len(images)} images (--grid counts inner corners)")
    write_csv(out, ["pose", "camera", "point", "u", "v"], rec)
    w, h = corners.size or (0, 0)
    lines = [f"{len(found)} of {len(images)} images show the {rows} x {cols} board: {len(rec)} corners written "
             f"to {out}" + (f"; not found in {len(missed)} (named above)" if missed else ""),
             "for dataset.yaml (the camera's intrinsics and mount as you know them):",
             f"cameras:\n  {camera}:\n    mount: world\n    width: {w}\n    height: {h}",
             f"targets:\n  {target}:\n    mount: tool\n    grid: {{rows: {rows}, cols: {cols}, square: {square:g}}}"]
    return Detection(out, found, missed, lines)
