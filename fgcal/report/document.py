"""``fgcal report``: the calibration report as HTML (self-contained), Markdown and PNG figures.

The content (verdict, accuracy statistics, flagged poses, parameters) is built by
:mod:`fgcal.report.report_sections`; this module draws the figures and writes the documents.
"""
from __future__ import annotations

import base64
import html
import io
import logging
from pathlib import Path

from fgcal.estimation.result import CalibrationResult
from fgcal.report import plots
from fgcal.report.report_sections import ReportContent, build_content
from fgcal.util.yamlio import atomic_write_bytes, atomic_write_text

__all__ = ["captions", "figures", "render_html", "render_markdown", "write_report"]

log = logging.getLogger(__name__)


def _outlier_ids(verification: dict | None, tolerance) -> list[int]:
    from fgcal.report.accuracy import flag_poses

    if not verification:
        return []
    flags = sorted(flag_poses(verification, tolerance), key=lambda f: -f.error_mm)
    outliers = [f.pose for f in flags if any(x.startswith("outlier") for x in f.flags)]
    return (outliers + [f.pose for f in flags[:5] if f.pose not in outliers])[:10]


def figures(result: CalibrationResult, verification: dict | None = None, volume=None,
            tolerance: float | None = None) -> dict[str, object]:
    """The report's figures by file stem: ``{name: matplotlib Figure}``, most telling first."""
    out = {}
    if verification is not None and verification.get("poses"):
        if any("xyz_mm" in p for p in verification["poses"]):
            out["verify_workspace"] = plots.plot_workspace_errors(
                verification, volume, tolerance_mm=tolerance, label_poses=_outlier_ids(verification, tolerance)).figure
        out["verify_distribution"] = plots.plot_error_distribution(verification, tolerance_mm=tolerance).figure
        out["verify_position"] = plots.plot_verification(verification, "position", tolerance_mm=tolerance).figure
        if any(p.get("orientation_deg") is not None for p in verification["poses"]):
            out["verify_orientation"] = plots.plot_verification(verification, "orientation").figure
    for level in plots.RESIDUAL_LEVELS:
        if result.residuals.get(level):
            out[f"residuals_{level}"] = plots.plot_residuals(result, level).figure
    from fgcal.report.camera_report import image_plane_residuals, plot_image_plane

    for ip in image_plane_residuals(result):
        out[f"image_plane_{ip.camera}"] = plot_image_plane(ip).figure
    for unit in ("mm", "deg"):
        if any(p.unit == unit for p in result.parameters):
            out[f"sigma_{'lengths' if unit == 'mm' else 'angles'}"] = plots.plot_sigmas(result, unit).figure
    if any(n.startswith("map.") for n in result.names):
        out["joint_error_map"] = plots.plot_joint_error_map(result).figure
    if len(plots.correlation_names(result)) > 1:
        out["correlation"] = plots.plot_correlation(result).figure
    if result.tool_xyz:
        out["poses_3d"] = plots.plot_poses(result, volume).figure
    return out


def captions(names, tolerance: float | None = None, volume=None) -> dict[str, str]:
    """A sentence per figure, saying what it shows and how to read it."""
    tol = f" The dashed line is the tolerance of {tolerance:g} mm." if tolerance is not None else ""
    box = " The grey box is the instrument's measuring volume." if volume is not None else ""
    text = {
        "verify_workspace": "Calibrated position error at each verification pose, placed where the tool was in the "
                            "instrument's frame and coloured by its size; poses beyond the tolerance are ringed in "
                            "red; outliers and the five largest errors are named by their pose id." + box,
        "verify_distribution": "Share of the verification poses whose position error is below a given value, for "
                               "the nominal and the calibrated model: the further left the curve, the better." + tol,
        "verify_position": "Position error at every verification pose with the nominal (red) and the calibrated "
                           "(green) model, poses ranked by their calibrated error." + tol,
        "verify_orientation": "Orientation error at every verification pose with the nominal (red) and the "
                              "calibrated (green) model, poses ranked by their calibrated error.",
        "sigma_lengths": "Standard deviation of every length parameter: tall bars are the lengths the data pin "
                         "down least.",
        "sigma_angles": "Standard deviation of every angle parameter: tall bars are the angles the data pin down "
                        "least.",
        "correlation": "Correlation between the parameter estimates: dark red or blue squares off the diagonal are "
                       "pairs the data barely tell apart (a large joint error map's coefficients are left out: its own "
                       "figure shows the map).",
        "joint_error_map": "The fitted joint error map: the correction added to each joint's reading, over the "
                           "range of readings it was fitted on (outside it the map is not valid), with +-1 sigma.",
        "poses_3d": "Where the tool was at the calibration poses, coloured by their order." + box,
    }
    for level, (what, unit) in plots.RESIDUAL_LEVELS.items():
        text[f"residuals_{level}"] = (f"Calibration residuals of the {what} ({unit}) against the noise the "
                                      "calibration assumed: a wider histogram than the curve means more noise "
                                      "than assumed, or something the model misses.")
    for n in names:
        if n.startswith("image_plane_"):
            text[n] = (f"Reprojection residuals of camera {n[len('image_plane_'):]} over its image: the RMS in each "
                       "region (colour) and each corner's residual (arrows, magnified). Large residuals at the "
                       "corners and edges, pointing along the radius, are a lens distortion the model misses.")
    return {n: text.get(n, n.replace("_", " ").capitalize() + ".") for n in names}


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    return buf.getvalue()


def render_markdown(content: ReportContent) -> str:
    """The report as Markdown (figures referenced as ``NAME.png`` next to it)."""
    def cell(c):
        return str(c).replace("|", "/")

    def table(header, rows):
        header = header or [""] * len(rows[0])
        return (["| " + " | ".join(map(cell, header)) + " |", "|" + "---|" * len(header)]
                + ["| " + " | ".join(map(cell, r)) + " |" for r in rows] + [""])

    md = [f"# {content.title}", ""]
    for sec in content.sections:
        md += [f"## {sec.title}", ""]
        for b in sec.blocks:
            if b.kind == "banner":
                md += [f"**{b.text}**", ""]
            elif b.kind == "p":
                md += [b.text, ""]
            elif b.kind == "ul":
                md += [f"- {i}" for i in b.items] + [""]
            elif b.kind in ("table", "details"):
                if b.kind == "details":
                    md += [f"{b.text}:", ""]
                md += table(b.header, b.rows)
            elif b.kind == "figure":
                md += [f"![{b.text}]({b.name}.png)", "", f"*{b.text}*", ""]
    return "\n".join(md)


STYLE = ("body{font-family:system-ui,sans-serif;max-width:1150px;margin:2em auto;padding:0 1em;color:#222;"
         "line-height:1.4}h1{font-size:1.6em}h2{margin-top:1.6em;border-bottom:1px solid #ddd}"
         "table{border-collapse:collapse;font-size:13px;margin:.5em 0}td,th{border:1px solid #ccc;padding:3px 6px;"
         "vertical-align:top}th{background:#f4f4f4;text-align:left}td.num{text-align:right;"
         "font-family:ui-monospace,monospace;white-space:nowrap}tr.flag{background:#fff4e0}"
         ".banner{font-size:1.15em;font-weight:bold;padding:.7em 1em;border-radius:6px;margin:.5em 0}"
         ".pass{background:#e3f6e3;border:2px solid #2e8b2e}.fail{background:#fde8e8;border:2px solid #c62828}"
         ".none{background:#f1f1f1;border:2px solid #999}figure{margin:1.5em 0}img{max-width:100%;"
         "border:1px solid #eee}figcaption{font-size:.92em;color:#444;max-width:800px}"
         "details{margin:.5em 0}summary{cursor:pointer;color:#1a5fb4}.scroll{overflow-x:auto}")


def _is_num(text: str) -> bool:
    t = text.strip().lstrip("[").rstrip("]").split(",")[0].split(" ")[0]
    try:
        float(t)
        return True
    except ValueError:
        return False


def _html_table(e, header, rows, row_flags=()):
    """A table in a box that scrolls sideways on a narrow screen; a row header when ``header`` is empty."""
    flags = list(row_flags) + [False] * (len(rows) - len(row_flags))
    out = ["<div class='scroll'><table>"]
    if header:
        out.append("<tr>" + "".join(f"<th>{e(str(h))}</th>" for h in header) + "</tr>")
    for r, f in zip(rows, flags):
        if not header:  # key-value table
            out.append(f"<tr><th>{e(str(r[0]))}</th>" + "".join(f"<td>{e(str(c))}</td>" for c in r[1:]) + "</tr>")
            continue
        out.append(f"<tr{' class=flag' if f else ''}>" + "".join(
            f"<td{' class=num' if _is_num(str(c)) else ''}>{e(str(c))}</td>" for c in r) + "</tr>")
    return out + ["</table></div>"]


def render_html(content: ReportContent, pngs: dict[str, bytes]) -> str:
    """The report as one self-contained HTML page (figures embedded as PNG data)."""
    e = html.escape
    parts = ["<!doctype html><html lang='en'><head><meta charset='utf-8'>"
             f"<meta name='viewport' content='width=device-width, initial-scale=1'><title>{e(content.title)}</title>"
             f"<style>{STYLE}</style></head><body><h1>{e(content.title)}</h1>"]
    for sec in content.sections:
        parts.append(f"<h2>{e(sec.title)}</h2>")
        for b in sec.blocks:
            if b.kind == "banner":
                parts.append(f"<div class='banner {b.status}'>{e(b.text)}</div>")
            elif b.kind == "p":
                parts.append(f"<p>{e(b.text)}</p>")
            elif b.kind == "ul":
                parts.append("<ul>" + "".join(f"<li>{e(i)}</li>" for i in b.items) + "</ul>")
            elif b.kind == "table":
                parts += _html_table(e, b.header, b.rows, b.row_flags)
            elif b.kind == "details":
                parts += [f"<details><summary>{e(b.text)}</summary>"] + _html_table(e, b.header, b.rows) + ["</details>"]
            elif b.kind == "figure" and b.name in pngs:
                parts.append(f"<figure><img alt='{e(b.text)}' src='data:image/png;base64,"
                             f"{base64.b64encode(pngs[b.name]).decode()}'><figcaption>{e(b.text)}</figcaption></figure>")
    parts.append("</body></html>")
    return "\n".join(parts)


def write_report(result: CalibrationResult, out_dir, verification: dict | None = None, volume=None,
                 title: str | None = None, tolerance: float | None = None) -> Path:
    """Write ``report.html``, ``report.md`` and the figures (PNG) into ``out_dir``; returns the HTML path.

    Parameters
    ----------
    verification : dict, optional
        ``verify.json``'s content (format fgcal-verify/1).
    volume : array_like, shape (2, 3), optional
        The instrument's measuring volume ``[min, max]`` (mm), drawn around the poses.
    tolerance : float, optional
        Position tolerance (mm) the verification poses are judged against.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    figs = figures(result, verification, volume, tolerance)
    content = build_content(result, verification, tolerance, captions(figs, tolerance, volume), title)
    pngs = {name: _png(fig) for name, fig in figs.items()}
    for name, data in pngs.items():
        atomic_write_bytes(out_dir / f"{name}.png", data)
    atomic_write_text(out_dir / "report.md", render_markdown(content) + "\n")
    path = out_dir / "report.html"
    atomic_write_text(path, render_html(content, pngs))
    return path
