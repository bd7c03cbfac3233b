"""Figures of a calibration: each takes ``ax=None`` and returns the axes it drew on.

Built on ``matplotlib.figure.Figure`` (no pyplot state); where no axes are given a new figure is
made, reachable as ``ax.figure``.
"""
from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from .result import CalibrationResult

__all__ = ["plot_sigmas", "plot_correlation", "plot_residuals", "plot_verification", "plot_poses",
           "plot_convergence", "RESIDUAL_LEVELS"]

RESIDUAL_LEVELS = {"probes_mm": ("probe points: distance off the sphere", "mm"),
                   "centres_mm": ("ball centres (per coordinate)", "mm"),
                   "poses_position_mm": ("poses: position (per coordinate)", "mm"),
                   "poses_rotation_deg": ("poses: rotation (per component)", "deg"),
                   "joints_deg": ("joints: estimate - reading", "deg")}


def _axes(ax, projection=None, size=(6.4, 4.0)):
    if ax is not None:
        return ax
    fig = Figure(figsize=size, layout="constrained")
    return fig.add_subplot(projection=projection)


def plot_sigmas(result: CalibrationResult, unit: str = "mm", ax=None):
    """Standard deviation of every parameter in ``unit`` ("mm" or "deg"), log scale."""
    ax = _axes(ax)
    rows = [(p.name, p.sigma) for p in result.parameters if p.unit == unit]
    if rows:
        names, sig = zip(*rows)
        ax.bar(range(len(sig)), sig, color="tab:blue" if unit == "mm" else "tab:orange")
        ax.set_xticks(range(len(sig)), names, rotation=90, fontsize=8)
        ax.set_yscale("log")
    ax.set_ylabel(f"sigma ({unit})")
    ax.set_title(f"Standard deviation of the {'lengths' if unit == 'mm' else 'angles'}")
    return ax


def plot_correlation(result: CalibrationResult, ax=None):
    """The parameters' correlation matrix."""
    ax = _axes(ax, size=(7.0, 6.0))
    rho = result.correlation()
    im = ax.imshow(rho, vmin=-1, vmax=1, cmap="RdBu_r")
    n = len(result.names)
    ax.set_xticks(range(n), result.names, rotation=90, fontsize=6)
    ax.set_yticks(range(n), result.names, fontsize=6)
    ax.figure.colorbar(im, ax=ax, shrink=0.8, label="correlation")
    ax.set_title("Correlation of the estimates")
    return ax


def plot_residuals(result: CalibrationResult, level: str, ax=None):
    """Histogram of one level's residuals with the normal density of the assumed noise."""
    ax = _axes(ax)
    values = np.asarray(result.residuals.get(level, []), dtype=float)
    title, unit = RESIDUAL_LEVELS.get(level, (level, ""))
    if values.size:
        ax.hist(values, bins=min(60, max(10, values.size // 10)), density=True, color="0.6", label="residuals")
        summary_key = {"probes_mm": "probes", "centres_mm": "centres", "poses_position_mm": "poses",
                       "poses_rotation_deg": "poses", "joints_deg": "joints"}.get(level)
        s = result.levels.get(summary_key)
        sigma = None
        if s is not None:
            sigma = s.sigma_rotation_deg if level == "poses_rotation_deg" else s.sigma
        if sigma and sigma > 0 and np.isfinite(sigma):
            x = np.linspace(values.min(), values.max(), 200)
            x = np.linspace(min(x[0], -4 * sigma), max(x[-1], 4 * sigma), 200)
            ax.plot(x, np.exp(-0.5 * (x / sigma) ** 2) / (sigma * np.sqrt(2 * np.pi)), "k-",
                    label=f"assumed noise, sigma {sigma:.3g} {unit}")
        ax.legend(fontsize=8)
    ax.set_xlabel(f"residual ({unit})")
    ax.set_title(title)
    return ax


def plot_verification(verification: dict, quantity: str = "position", ax=None):
    """Per-pose error before (nominal) and after calibration, from a ``verify.json`` dict."""
    ax = _axes(ax)
    poses = verification.get("poses", [])
    key, unit = ("position_mm", "mm") if quantity == "position" else ("orientation_deg", "deg")
    x = np.arange(len(poses))
    before = [p[f"before_{key}"] for p in poses]
    after = [p[key] for p in poses]
    ax.semilogy(x, before, "o", color="tab:red", label="nominal")
    ax.semilogy(x, after, "o", color="tab:green", label="calibrated")
    ax.set_xticks(x, [str(p["pose"]) for p in poses], rotation=90, fontsize=6)
    ax.set_xlabel("verification pose")
    ax.set_ylabel(f"{quantity} error ({unit})")
    ax.legend(fontsize=8)
    ax.set_title(f"{quantity.capitalize()} error against the measurements")
    return ax


def plot_poses(result: CalibrationResult, volume=None, ax=None):
    """Where the tool was at the calibration poses (world, mm), inside the measuring volume."""
    ax = _axes(ax, projection="3d", size=(6.0, 5.5))
    xyz = np.asarray(result.tool_xyz, dtype=float).reshape(-1, 3)
    if xyz.size:
        ax.scatter(xyz[:, 0], xyz[:, 1], xyz[:, 2], c=np.arange(len(xyz)), cmap="viridis", s=14)
    if volume is not None:
        lo, hi = np.asarray(volume, dtype=float)
        for a in (lo[0], hi[0]):
            for b in (lo[1], hi[1]):
                ax.plot([a, a], [b, b], [lo[2], hi[2]], color="0.7", lw=0.8)
        for a in (lo[0], hi[0]):
            for c in (lo[2], hi[2]):
                ax.plot([a, a], [lo[1], hi[1]], [c, c], color="0.7", lw=0.8)
        for b in (lo[1], hi[1]):
            for c in (lo[2], hi[2]):
                ax.plot([lo[0], hi[0]], [b, b], [c, c], color="0.7", lw=0.8)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_zlabel("z (mm)")
    ax.set_title("Tool positions at the calibration poses")
    return ax


def plot_convergence(n_poses, estimates, sigmas, names, truth=None, ax=None):
    """Estimates (deviation from the last) with +-sigma bands against the number of poses.

    Parameters
    ----------
    n_poses : array_like, shape (K,)
    estimates, sigmas : array_like, shape (K, P)
        In file units, one row per update.
    names : sequence of str, length P
    truth : array_like, shape (P,), optional
    """
    ax = _axes(ax)
    n_poses = np.asarray(n_poses)
    est = np.asarray(estimates, dtype=float)
    sig = np.asarray(sigmas, dtype=float)
    ref = est[-1] if truth is None else np.asarray(truth, dtype=float)
    for k, name in enumerate(names):
        line, = ax.plot(n_poses, est[:, k] - ref[k], label=name)
        ax.fill_between(n_poses, est[:, k] - ref[k] - sig[:, k], est[:, k] - ref[k] + sig[:, k],
                        color=line.get_color(), alpha=0.15)
    ax.axhline(0, color="k", lw=0.6)
    # symmetric log: the first poses move by the prior's spread, the last by a fraction of sigma
    ax.set_yscale("symlog", linthresh=max(float(np.min(sig[-1])), 1e-12))
    ax.set_xlabel("poses")
    ax.set_ylabel("estimate - " + ("truth" if truth is not None else "final"))
    ax.legend(fontsize=7, ncol=2)
    ax.set_title("Estimates and +-1 sigma as poses arrive")
    return ax
