"""The report's camera part (DESIGN.md 8.4): reprojection residuals per image and over the image plane.

A calibration with pixels keeps, beside each corner's residual, where it was measured
(``result.residuals``: ``pixels_u_px``, ``pixels_v_px``, ``pixels_pose``, ``pixels_camera``,
``pixels_du_px``, ``pixels_dv_px``, see :meth:`fgcal.measurements.pixels.Pixels.residual_places`).
Per image: the RMS of its corners' residual norms (px). Over the image plane: the same RMS in a
3 x 3 grid of regions (the corners, the edges and the centre), where a distortion the model misses
shows (it grows with the distance from the principal point), and in a finer grid drawn as a map.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgcal.report.report_blocks import Block, Section, num

__all__ = ["CORNER_RATIO", "ImagePlaneResiduals", "camera_sections", "image_plane_residuals", "plot_image_plane"]

CORNER_RATIO = 1.5  # the corners' RMS over the centre's beyond which the report names a distortion missed
ROWS = ("top", "middle", "bottom")
COLUMNS = ("left", "centre", "right")


@dataclass
class ImagePlaneResiduals:
    """One camera's reprojection residuals (px) by image and by region of the image.

    Attributes
    ----------
    camera : str
    width, height : int
        The image's size (px).
    per_image : list of (pose id, corners, RMS px, max px)
        In the order of the calibration's poses.
    grid_rms : ndarray, shape (3, 3)
        RMS (px) in each region (rows top to bottom, columns left to right); NaN where no corner is.
    grid_n : ndarray of int, shape (3, 3)
        Corners in each region.
    """

    camera: str
    width: int
    height: int
    per_image: list
    grid_rms: np.ndarray
    grid_n: np.ndarray
    u: np.ndarray  # (M,) measured pixel of each corner
    v: np.ndarray
    d: np.ndarray  # (M, 2) residual (px)

    @property
    def corner_ratio(self) -> float:
        """The RMS over the four corner regions' corners divided by the centre region's (NaN if either is empty)."""
        corner = self.grid_n[[0, 0, 2, 2], [0, 2, 0, 2]]
        if not corner.sum() or not self.grid_n[1, 1]:
            return float("nan")
        ms = self.grid_rms[[0, 0, 2, 2], [0, 2, 0, 2]] ** 2
        return float(np.sqrt(np.nansum(ms * corner) / corner.sum()) / self.grid_rms[1, 1])


def _rms_by(cells, d2, n_cells):
    n = np.bincount(cells, minlength=n_cells)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(np.bincount(cells, weights=d2, minlength=n_cells) / n), n


def image_plane_residuals(result) -> list[ImagePlaneResiduals]:
    """Per camera of ``result`` (a :class:`~fgcal.estimation.result.CalibrationResult`) its residuals
    by image and region; empty without pixels (or from a result written before they were kept)."""
    r = result.residuals
    if not r.get("pixels_u_px"):
        return []
    fixtures = (result.setup or {}).get("fixtures", {})
    cams = [n for n, f in fixtures.items() if f.get("type") == "camera"]
    u, v = np.asarray(r["pixels_u_px"], float), np.asarray(r["pixels_v_px"], float)
    d = np.column_stack([r["pixels_du_px"], r["pixels_dv_px"]])
    pose, cam = np.asarray(r["pixels_pose"], float).astype(int), np.asarray(r["pixels_camera"], float).astype(int)
    out = []
    for c, name in enumerate(cams):
        sel = cam == c
        if not sel.any():
            continue
        w, h = int(fixtures[name].get("width", 0)), int(fixtures[name].get("height", 0))
        w = w or int(np.ceil(u[sel].max() + 1))
        h = h or int(np.ceil(v[sel].max() + 1))
        d2 = np.sum(d[sel] ** 2, axis=1)
        ids, inv = np.unique(pose[sel], return_inverse=True)
        rms, n = _rms_by(inv, d2, len(ids))
        peak = np.zeros(len(ids))
        np.maximum.at(peak, inv, np.sqrt(d2))
        order = [p for p in dict.fromkeys(pose[sel].tolist())]
        where = {int(p): k for k, p in enumerate(ids)}
        per_image = [(p, int(n[where[p]]), float(rms[where[p]]), float(peak[where[p]])) for p in order]
        col = np.clip((u[sel] + 0.5) * 3 // w, 0, 2).astype(int)
        row = np.clip((v[sel] + 0.5) * 3 // h, 0, 2).astype(int)
        g_rms, g_n = _rms_by(row * 3 + col, d2, 9)
        out.append(ImagePlaneResiduals(name, w, h, per_image, g_rms.reshape(3, 3), g_n.reshape(3, 3), u[sel], v[sel],
                                       d[sel]))
    return out


def camera_sections(result, limit: int = 10) -> list:
    """The report's section on each camera's reprojection residuals (report_sections' Blocks)."""
    out = []
    for ip in image_plane_residuals(result):
        worst = sorted(ip.per_image, key=lambda t: -t[2])[:limit]
        blocks = [Block("p", f"Camera {ip.camera} ({ip.width} x {ip.height} px): the reprojection residuals of "
                             f"{int(ip.grid_n.sum())} corners in {len(ip.per_image)} images, RMS "
                             f"{num(float(np.sqrt(np.mean(np.sum(ip.d ** 2, axis=1)))))} px.")]
        ratio = ip.corner_ratio
        if np.isfinite(ratio) and ratio > CORNER_RATIO:
            blocks.append(Block("banner", f"Camera {ip.camera}: the residuals at the image's corners are "
                                          f"{num(ratio)} times those at its centre: a lens distortion the model "
                                          "misses (estimate k1, k2, k3 or check the intrinsics given).",
                                status="fail"))
        elif np.isfinite(ratio):
            blocks.append(Block("p", f"The corners' RMS is {num(ratio)} times the centre's: no sign of a distortion "
                                     "the model misses."))
        rows = [[ROWS[i]] + [("-" if not ip.grid_n[i, j] else f"{num(float(ip.grid_rms[i, j]))} ({ip.grid_n[i, j]})")
                             for j in range(3)] for i in range(3)]
        blocks.append(Block("table", header=["RMS px (corners)", *COLUMNS], rows=rows))
        blocks.append(Block("details", f"The {len(worst)} images with the largest RMS",
                            header=["pose", "corners", "RMS px", "max px"],
                            rows=[[str(p), str(n), num(a), num(m)] for p, n, a, m in worst]))
        out.append(Section(f"Reprojection residuals: camera {ip.camera}", blocks))
    return out


def plot_image_plane(ip: ImagePlaneResiduals, bins=(8, 6)):
    """The RMS residual (px) over the image in ``bins`` (columns, rows) regions, with each corner's
    residual drawn as an arrow (magnified to be seen). Returns the matplotlib Axes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5.5))
    nx, ny = bins
    col = np.clip((ip.u + 0.5) * nx // ip.width, 0, nx - 1).astype(int)
    row = np.clip((ip.v + 0.5) * ny // ip.height, 0, ny - 1).astype(int)
    rms, _ = _rms_by(row * nx + col, np.sum(ip.d**2, axis=1), nx * ny)
    im = ax.imshow(rms.reshape(ny, nx), extent=(-0.5, ip.width - 0.5, ip.height - 0.5, -0.5), cmap="viridis",
                   interpolation="nearest", aspect="equal")
    scale = 0.05 * ip.width / max(float(np.sqrt(np.mean(np.sum(ip.d**2, axis=1)))), 1e-12)
    ax.quiver(ip.u, ip.v, ip.d[:, 0] * scale, ip.d[:, 1] * scale, angles="xy", scale_units="xy", scale=1.0,
              color="white", width=0.002)
    fig.colorbar(im, ax=ax, label="RMS residual (px)")
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    ax.set_title(f"Camera {ip.camera}: reprojection residuals over the image")
    fig.tight_layout()
    return ax
