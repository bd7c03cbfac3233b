"""``fgcal report``: the uncertainty report as HTML (self-contained), Markdown and PNG figures."""
from __future__ import annotations

import base64
import html
import io
import logging
from pathlib import Path


from . import plots
from .result import CalibrationResult
from .uncertainty import parameter_table, verdict
from .yamlio import atomic_write_bytes, atomic_write_text

__all__ = ["write_report", "figures"]

log = logging.getLogger(__name__)


def figures(result: CalibrationResult, verification: dict | None = None, volume=None) -> dict[str, object]:
    """The report's figures by file stem: ``{name: matplotlib Figure}``."""
    out = {}
    for unit in ("mm", "deg"):
        if any(p.unit == unit for p in result.parameters):
            out[f"sigma_{'lengths' if unit == 'mm' else 'angles'}"] = plots.plot_sigmas(result, unit).figure
    if len(result.parameters) > 1:
        out["correlation"] = plots.plot_correlation(result).figure
    for level in plots.RESIDUAL_LEVELS:
        if result.residuals.get(level):
            out[f"residuals_{level}"] = plots.plot_residuals(result, level).figure
    if verification is not None and verification.get("poses"):
        out["verify_position"] = plots.plot_verification(verification, "position").figure
        out["verify_orientation"] = plots.plot_verification(verification, "orientation").figure
    if result.tool_xyz:
        out["poses_3d"] = plots.plot_poses(result, volume).figure
    return out


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    return buf.getvalue()


def _fmt(v, digits=6):
    if v is None:
        return "-"
    if isinstance(v, tuple):
        return f"[{_fmt(v[0])}, {_fmt(v[1])}]"
    return f"{v:.{digits}g}"


def _summary(result: CalibrationResult, verification: dict | None) -> list[tuple[str, str]]:
    items = [("robot", result.robot), ("poses", str(result.n_poses)),
             ("parameters identified", f"{len(result.parameters)} (held at nominal: {len(result.held)})"),
             ("solve", f"{result.iterations} iterations, {'converged' if result.converged else 'NOT converged'}"),
             ("condition number (scaled information)", f"{result.condition_number:.4g}")]
    for level, s in result.levels.items():
        if level in ("kinematic", "prior"):
            continue
        text = f"{s.rms:.4g} {s.unit} RMS over {s.n} (assumed sigma {s.sigma:.3g}; variance factor {s.variance_factor:.3g})"
        if s.rms_rotation_deg is not None:
            text += f"; rotation {s.rms_rotation_deg:.4g} deg RMS"
        items.append((f"residuals: {level}", text))
    if verification is not None:
        for label, d in (("verification, nominal", verification["before"]), ("verification, calibrated", verification)):
            items.append((label, f"position {d['position_mm']['rms']:.4g} mm RMS (max {d['position_mm']['max']:.4g})"
                                 + _orientation_text(d)))
        if "truth" in verification:
            t = verification["truth"]
            items.append(("verification against the truth", f"position {t['position_mm']['rms']:.4g} mm RMS "
                          f"(max {t['position_mm']['max']:.4g})" + _orientation_text(t)))
    return items


def _orientation_text(summary: dict) -> str:
    o = summary.get("orientation_deg")
    return "" if o is None else f"; orientation {o['rms']:.4g} deg RMS"


COLUMNS = ["name", "unit", "nominal", "estimate", "deviation", "sigma", "95% interval", "deviation/sigma", "flags"]


def _row_cells(r) -> list[str]:
    return [r.name, r.unit, _fmt(r.nominal, 8), _fmt(r.estimate, 10), _fmt(r.deviation, 4), _fmt(r.sigma, 3),
            _fmt(r.interval95), _fmt(r.z, 3), "; ".join(r.flags)]


def write_report(result: CalibrationResult, out_dir, verification: dict | None = None, volume=None,
                 title: str | None = None) -> Path:
    """Write ``report.html``, ``report.md`` and the figures (PNG) into ``out_dir``; returns the HTML path."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    title = title or f"fgcal calibration report: {result.robot}, {result.n_poses} poses"
    rows = parameter_table(result)
    summary = _summary(result, verification)
    verdict_lines = verdict(result, verification)
    figs = figures(result, verification, volume)
    pngs = {name: _png(fig) for name, fig in figs.items()}
    for name, data in pngs.items():
        atomic_write_bytes(out_dir / f"{name}.png", data)

    md = [f"# {title}", "", "## Verdict", ""] + [f"- {v}" for v in verdict_lines] + ["", "## Summary", ""]
    md += ["| | |", "|---|---|"] + [f"| {k} | {v} |" for k, v in summary] + ["", "## Parameters", ""]
    md += ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    md += ["| " + " | ".join(c.replace("|", "/") for c in _row_cells(r)) + " |" for r in rows]
    md += ["", "## Figures", ""] + [f"![{name}]({name}.png)" for name in pngs]
    atomic_write_text(out_dir / "report.md", "\n".join(md) + "\n")

    e = html.escape
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{e(title)}</title><style>",
             "body{font-family:sans-serif;max-width:1200px;margin:2em auto;color:#222}"
             "table{border-collapse:collapse;font-size:13px}td,th{border:1px solid #ccc;padding:3px 6px}"
             "td.num{text-align:right;font-family:monospace}tr.flag{background:#fff4e0}img{max-width:100%}",
             f"</style></head><body><h1>{e(title)}</h1><h2>Verdict</h2><ul>"]
    parts += [f"<li>{e(v)}</li>" for v in verdict_lines]
    parts += ["</ul><h2>Summary</h2><table>"] + [f"<tr><th>{e(k)}</th><td>{e(v)}</td></tr>" for k, v in summary]
    parts += ["</table><h2>Parameters</h2><table><tr>" + "".join(f"<th>{e(c)}</th>" for c in COLUMNS) + "</tr>"]
    for r in rows:
        cells = _row_cells(r)
        parts.append(f"<tr{' class=flag' if r.flags else ''}>" + "".join(
            f"<td{' class=num' if 1 < i < 8 else ''}>{e(c)}</td>" for i, c in enumerate(cells)) + "</tr>")
    parts.append("</table><h2>Figures</h2>")
    for name, data in pngs.items():
        parts.append(f"<figure><img alt='{e(name)}' src='data:image/png;base64,{base64.b64encode(data).decode()}'>"
                     f"<figcaption>{e(name)}</figcaption></figure>")
    parts.append("</body></html>")
    path = out_dir / "report.html"
    atomic_write_text(path, "\n".join(parts))
    return path
