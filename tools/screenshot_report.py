#!/usr/bin/env python
"""Render an fgcal HTML report in headless Chromium and save PNG screenshots of it.

    python tools/screenshot_report.py DIR/report.html --out SHOTS [--width 1280] [--height 5000] [--narrow 560]

Writes ``SHOTS/report-WIDTH.png`` (the page at a desktop width, ``--height`` pixels tall, so that
most of the report is in one picture) and ``SHOTS/report-NARROW.png`` (a phone-like width, to see
that tables and figures do not overflow). Chromium is looked up as ``chromium``,
``chromium-browser``, ``google-chrome`` or ``$CHROMIUM``; it runs with a throw-away profile, no
network services and no sandbox (for containers). Exit status 2 when Chromium or the report is
missing.
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--hide-scrollbars", "--force-device-scale-factor=1"]


def find_chromium() -> str | None:
    """The path of a Chromium-like browser, or None."""
    for name in (os.environ.get("CHROMIUM"), "chromium", "chromium-browser", "google-chrome"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


def screenshot(html: Path, png: Path, width: int, height: int, browser: str, timeout: float = 120.0) -> Path:
    """Save a ``width`` x ``height`` screenshot of the page ``html`` to ``png``."""
    png.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="fgcal-chromium-") as profile:
        cmd = [browser, *FLAGS, f"--user-data-dir={profile}", f"--window-size={width},{height}",
               f"--screenshot={png.resolve()}", html.resolve().as_uri()]
        run = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    if run.returncode != 0 or not png.exists():
        raise RuntimeError(f"chromium failed ({run.returncode}): {run.stderr.strip()[-500:]}")
    return png


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("html", type=Path, help="report.html written by fgcal report")
    ap.add_argument("--out", type=Path, required=True, help="directory for the PNG screenshots")
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--height", type=int, default=5000)
    ap.add_argument("--narrow", type=int, default=560, help="width of the second, narrow screenshot (0: none)")
    args = ap.parse_args(argv)
    browser = find_chromium()
    if browser is None:
        print("screenshot_report: no chromium found (apt-get install chromium, or set CHROMIUM)", file=sys.stderr)
        return 2
    if not args.html.is_file():
        print(f"screenshot_report: {args.html}: no such file", file=sys.stderr)
        return 2
    widths = [args.width] + ([args.narrow] if args.narrow else [])
    for w in widths:
        path = screenshot(args.html, args.out / f"report-{w}.png", w, args.height, browser)
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
