"""Figures of a calibration: each takes ``ax=None`` and returns the axes it drew on.

Built on ``matplotlib.figure.Figure`` (no pyplot state); where no axes are given a new figure is
made, reachable as ``ax.figure``.
"""
from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from fgcal.estimation.result import CalibrationResult

__all__ = [
    "RESIDUAL_LEVELS",
    "correlation_names",
    "joint_error_map_curves",
    "plot_convergence",
    "plot_correlation",
    "plot_error_distribution",
    "plot_joint_error_map",
    "plot_poses",
    "plot_residuals",
    "plot_sigmas",
    "plot_verification",
    "plot_workspace_errors",
]

RESIDUAL_LEVELS = {"probes_mm": ("probe points: distance off the sphere", "mm"),
                   "centres_mm": ("ball centres (per coordinate)", "mm"),
                   "poses_position_mm": ("poses: position (per coordinate)", "mm"),
                   "poses_rotation_deg": ("poses: rotation (per component)", "deg"),
                   "joints_deg": ("joints: estimate - reading", "deg")}


LOG_RANGE = 30.0  # a log axis only where the values span more than this factor


def _log_wide(ax, values, axis: str = "y") -> bool:
    """Put ``axis`` on a log scale when the positive ``values`` span more than :data:`LOG_RANGE`; True if so."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v) & (v > 0)]
    wide = bool(v.size) and float(v.max()) > LOG_RANGE * float(v.min())
    if wide:
        (ax.set_yscale if axis == "y" else ax.set_xscale)("log")
    return wide


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
        ax.set_xticks(range(len(sig)), names, rotation=90, fontsize=8 if len(sig) <= 40 else 5)
        wide = _log_wide(ax, sig)
    else:
        wide = False
    ax.set_ylabel(f"standard deviation ({unit}{', log scale' if wide else ''})")
    ax.set_title(f"Standard deviation of the {'lengths' if unit == 'mm' else 'angles'}")
    return ax


def correlation_names(result: CalibrationResult) -> list[str]:
    """The parameters the correlation figure shows: all, but a large joint-error block (a map) left out.

    A map's hundreds of coefficients would merge the labels into a smear; its own figure
    (:func:`plot_joint_error_map`) shows it.
    """
    block = set(result.joint_errors.get("names") or ())
    names = list(result.names)
    return [n for n in names if n not in block] if len(names) > MAX_CORRELATION_LABELS and block else names


MAX_CORRELATION_LABELS = 60  # more labels than this do not read


def plot_correlation(result: CalibrationResult, ax=None):
    """The parameters' correlation matrix (:func:`correlation_names`: without a large joint-error block)."""
    ax = _axes(ax, size=(7.0, 6.0))
    names = correlation_names(result)
    keep = [result.names.index(n) for n in names]
    rho = result.correlation()[np.ix_(keep, keep)]
    im = ax.imshow(rho, vmin=-1, vmax=1, cmap="RdBu_r")
    n = len(names)
    size = 6 if n <= 40 else 4
    ax.set_xticks(range(n), names, rotation=90, fontsize=size)
    ax.set_yticks(range(n), names, fontsize=size)
    ax.figure.colorbar(im, ax=ax, shrink=0.8, label="correlation")
    ax.set_title("Correlation of the estimates")
    return ax


def joint_error_map_curves(result: CalibrationResult, n: int = 181) -> dict[int, tuple]:
    """The fitted map of each joint: ``{joint: (q_deg (n,), correction_urad (n,), sigma_urad (n,))}``.

    ``correction = sum_h s_h sin(h q) + c_h cos(h q)`` over the joint's fitted range
    (``joint_ranges_deg``), with its standard deviation from the coefficients' covariance.
    """
    names = list(result.names)
    ranges = result.joint_errors.get("joint_ranges_deg") or []
    out: dict[int, tuple] = {}
    for j in range(1, len(ranges) + 1):
        terms = [(k, n_) for k, n_ in enumerate(names) if n_.startswith(f"map.j{j}.")]
        if not terms:
            continue
        lo, hi = ranges[j - 1]
        q = np.linspace(float(lo), float(hi), n)
        G = np.zeros((n, len(terms)))
        for c, (_, name) in enumerate(terms):
            kind = name.rsplit(".", 1)[1]
            h = int(kind[3:])
            G[:, c] = np.sin(h * np.radians(q)) if kind.startswith("sin") else np.cos(h * np.radians(q))
        idx = [k for k, _ in terms]
        coef = np.array([result.parameters[k].estimate for k in idx])
        C = np.asarray(result.covariance, dtype=float)[np.ix_(idx, idx)]
        out[j] = (q, G @ coef, np.sqrt(np.maximum(np.einsum("ip,ip->i", G @ C, G), 0.0)))
    return out


def plot_joint_error_map(result: CalibrationResult, ax=None):
    """The fitted joint error map, one curve per joint over the range it was fitted on, with +-1 sigma."""
    ax = _axes(ax)
    curves = joint_error_map_curves(result)
    unit = next((p.unit for p in result.parameters if p.name.startswith("map.")), "urad")
    for j, (q, corr, sig) in curves.items():
        line, = ax.plot(q, corr, label=f"joint {j}")
        ax.fill_between(q, corr - sig, corr + sig, color=line.get_color(), alpha=0.15)
    ax.axhline(0, color="k", lw=0.6)
    ax.set_xlabel("joint reading (deg)")
    ax.set_ylabel(f"joint correction ({unit})")
    if curves:
        ax.legend(fontsize=7, ncol=2)
    ax.set_title("Fitted joint error map (joint = reading + correction)")
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
        s = result.levels.get(summary_key) if summary_key else None
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
    ax.set_ylabel(f"density (1/{unit})" if unit else "density")
    ax.set_title(title[:1].upper() + title[1:])
    return ax


def _tolerance_line(ax, tolerance_mm, horizontal=True):
    if tolerance_mm is not None:
        (ax.axhline if horizontal else ax.axvline)(tolerance_mm, color="k", ls="--", lw=1,
                                                   label=f"tolerance {tolerance_mm:g} mm")


def plot_verification(verification: dict, quantity: str = "position", ax=None, tolerance_mm=None):
    """Per-pose error before (nominal) and after calibration, poses sorted by the calibrated error.

    From a ``verify.json`` dict. With up to 40 poses the x axis names them; beyond that it is
    their rank, so that hundreds of poses read as a curve rather than a smear of labels.
    """
    ax = _axes(ax)
    key, unit = ("position_mm", "mm") if quantity == "position" else ("orientation_deg", "deg")
    poses = [p for p in verification.get("poses", []) if p.get(key) is not None]
    after = np.array([p[key] for p in poses], dtype=float)
    before = np.array([p[f"before_{key}"] for p in poses], dtype=float)
    order = np.argsort(after)
    x = np.arange(1, len(poses) + 1)
    marker = "o" if len(poses) <= 60 else "."
    ax.plot(x, before[order], marker, color="tab:red", ms=4, label="nominal model")
    ax.plot(x, after[order], marker, color="tab:green", ms=4, label="calibrated model")
    wide = _log_wide(ax, np.concatenate([before, after]))
    if quantity == "position":
        _tolerance_line(ax, tolerance_mm)
    if 0 < len(poses) <= 40:
        ax.set_xticks(x, [str(poses[i]["pose"]) for i in order], rotation=90, fontsize=7)
        ax.set_xlabel("verification pose (id), sorted by calibrated error")
    else:
        ax.set_xlabel("verification poses, ranked by calibrated error")
    ax.set_ylabel(f"{quantity} error ({unit}{', log scale' if wide else ''})")
    ax.legend(fontsize=8)
    ax.set_title(f"{quantity.capitalize()} error at the verification poses")
    return ax


def plot_error_distribution(verification: dict, ax=None, tolerance_mm=None):
    """Cumulative share of verification poses within a position error, nominal and calibrated."""
    ax = _axes(ax)
    poses = verification.get("poses", [])
    for key, colour, label in (("before_position_mm", "tab:red", "nominal model"),
                               ("position_mm", "tab:green", "calibrated model")):
        e = np.sort(np.array([p[key] for p in poses], dtype=float))
        if e.size:
            ax.step(e, 100.0 * np.arange(1, e.size + 1) / e.size, where="post", color=colour, label=label)
    _tolerance_line(ax, tolerance_mm, horizontal=False)
    wide = _log_wide(ax, [p[k] for p in poses for k in ("before_position_mm", "position_mm")], "x")
    ax.set_ylim(0, 101)
    ax.set_xlabel(f"position error (mm{', log scale' if wide else ''})")
    ax.set_ylabel("verification poses within (%)")
    ax.legend(fontsize=8, loc="lower right")
    ax.set_title("Share of the verification poses within a given error")
    return ax


def _box(ax, volume):
    lo, hi = np.asarray(volume, dtype=float)
    for a in (lo[0], hi[0]):
        for b in (lo[1], hi[1]):
            ax.plot([a, a], [b, b], [lo[2], hi[2]], color="0.6", lw=0.8)
    for a in (lo[0], hi[0]):
        for c in (lo[2], hi[2]):
            ax.plot([a, a], [lo[1], hi[1]], [c, c], color="0.6", lw=0.8)
    for b in (lo[1], hi[1]):
        for c in (lo[2], hi[2]):
            ax.plot([lo[0], hi[0]], [b, b], [c, c], color="0.6", lw=0.8)


def plot_workspace_errors(verification: dict, volume=None, ax=None, tolerance_mm=None, label_poses=()):
    """The calibrated position error at each verification pose, as coloured points in the workspace.

    Needs the positions ``xyz_mm`` of ``verify.json``'s poses; the measuring volume (2, 3) mm is
    drawn as a box when given; poses beyond ``tolerance_mm`` are ringed in red and ``label_poses``
    (pose ids) are named.
    """
    ax = _axes(ax, projection="3d", size=(7.0, 5.6))
    poses = [p for p in verification.get("poses", []) if "xyz_mm" in p]
    if poses:
        xyz = np.array([p["xyz_mm"] for p in poses], dtype=float)
        err = np.array([p["position_mm"] for p in poses], dtype=float)
        # the colour scale ends near the 95th percentile so that one outlier does not flatten the rest
        top = max(float(np.percentile(err, 95)) * 1.25, tolerance_mm or 0.0, 1e-12)
        sc = ax.scatter(xyz[:, 0], xyz[:, 1], xyz[:, 2], c=err, cmap="viridis", vmin=0.0, vmax=top, s=22,
                        depthshade=False)
        ax.figure.colorbar(sc, ax=ax, shrink=0.7, pad=0.1, extend="max" if err.max() > top else "neither",
                           label="calibrated position error (mm)")
        if tolerance_mm is not None:
            bad = err > tolerance_mm
            if bad.any():
                ax.scatter(xyz[bad, 0], xyz[bad, 1], xyz[bad, 2], s=90, facecolors="none", edgecolors="tab:red",
                           linewidths=1.2, depthshade=False, label=f"beyond {tolerance_mm:g} mm")
                ax.legend(fontsize=8, loc="upper left")
        named = set(label_poses)
        for p, (x, y, z) in zip(poses, xyz):
            if p["pose"] in named:
                ax.text(x, y, z, f" {p['pose']}", fontsize=8, color="tab:red")
    if volume is not None:
        _box(ax, volume)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_zlabel("z (mm)")
    ax.set_title("Calibrated position error over the workspace")
    return ax


def plot_poses(result: CalibrationResult, volume=None, ax=None):
    """Where the tool was at the calibration poses (world, mm), inside the measuring volume."""
    ax = _axes(ax, projection="3d", size=(6.0, 5.5))
    xyz = np.asarray(result.tool_xyz, dtype=float).reshape(-1, 3)
    if xyz.size:
        sc = ax.scatter(xyz[:, 0], xyz[:, 1], xyz[:, 2], c=np.arange(1, len(xyz) + 1), cmap="viridis", s=14)
        ax.figure.colorbar(sc, ax=ax, shrink=0.7, pad=0.1, label="order of the calibration poses")
    if volume is not None:
        _box(ax, volume)
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
    # in units of each parameter's final sigma: one axis for mm and deg alike
    unit = np.where(sig[-1] > 0, sig[-1], 1.0)
    for k, name in enumerate(names):
        d = (est[:, k] - ref[k]) / unit[k]
        line, = ax.plot(n_poses, d, label=name)
        ax.fill_between(n_poses, d - sig[:, k] / unit[k], d + sig[:, k] / unit[k], color=line.get_color(), alpha=0.15)
    ax.axhline(0, color="k", lw=0.6)
    # symmetric log, linear within +-1 final sigma: the first poses move by the prior's spread
    ax.set_yscale("symlog", linthresh=1.0, linscale=1.0)
    from matplotlib.ticker import FixedLocator

    top = max(1.0, float(np.nanmax(np.abs((est - ref) / unit) + sig / unit)))
    ticks = [0.0] + [s * 10.0 ** e for e in range(0, int(np.ceil(np.log10(top))) + 1) for s in (1.0, -1.0)]
    ax.yaxis.set_major_locator(FixedLocator(sorted(ticks)))
    ax.set_xlabel("number of poses")
    ax.set_ylabel("(estimate - " + ("truth" if truth is not None else "final") + ") / final sigma")
    ax.legend(fontsize=7, ncol=2)
    ax.set_title("Estimates and +-1 sigma as poses arrive")
    return ax
