"""Regenerate docs/report.png, the README's picture of `frontdiag report`.

    python scripts/report_png.py [--out docs/report.png]

Analyses sample_logs/mixed.mcap into a temporary folder, writes the HTML report and takes a
1280x900 screenshot of it in headless Chromium (Debian's /usr/bin/chromium through Playwright,
the same browser the report's test uses). The analysis runs from inside the temporary folder on
a relative path, so the page shows a neutral demo folder, not this machine's paths. The
sample log itself is read, never written.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _screenshot import Page, picture_main

ROOT = Path(__file__).resolve().parent.parent


def build(tmp: Path) -> Page | None:
    from frontdiag.cli import main as cli

    shutil.copyfile(ROOT / "sample_logs" / "mixed.mcap", "mixed.mcap")
    cli(["analyze", "mixed.mcap", "--out", "mixed-results", "-q"])
    if cli(["report", "mixed-results", "-o", "report.html", "-q"]) != 0:
        return None
    # every plot drawn: as many plotly SVGs as the page's own count of plots
    return (tmp / "report.html", 1280, 900,
            "document.querySelectorAll('.plotly-graph-div .main-svg').length >= "
            "JSON.parse(document.getElementById('frontdiag-meta').text).plots")


if __name__ == "__main__":
    sys.exit(picture_main(__doc__, ROOT / "docs" / "report.png", build))
