"""Regenerate docs/report.png, the README's picture of `frontdiag report`.

    python scripts/report_png.py [--out docs/report.png]

Analyses sample_logs/mixed.mcap into a temporary folder, writes the HTML report and takes a
1280x900 screenshot of it in headless Chromium (Debian's /usr/bin/chromium through Playwright,
the same browser the report's test uses). The analysis runs from inside the temporary folder on
a relative path, so the page shows a neutral demo folder, not this machine's paths. The
sample log itself is read, never written.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CHROMIUM = Path("/usr/bin/chromium")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "report.png")
    args = ap.parse_args()
    if not CHROMIUM.exists():
        print(f"{CHROMIUM} is missing: install Debian's chromium (apt install chromium)",
              file=sys.stderr)
        return 2
    from playwright.sync_api import sync_playwright

    from frontdiag.cli import main as cli

    out = args.out.resolve()
    here = Path.cwd()
    with tempfile.TemporaryDirectory(prefix="frontdiag-demo-") as tmp:
        try:
            os.chdir(tmp)
            shutil.copyfile(ROOT / "sample_logs" / "mixed.mcap", "mixed.mcap")
            cli(["analyze", "mixed.mcap", "--out", "mixed-results", "-q"])
            if cli(["report", "mixed-results", "-o", "report.html", "-q"]) != 0:
                return 2
            page_uri = (Path(tmp) / "report.html").as_uri()
            with sync_playwright() as p:
                browser = p.chromium.launch(
                    executable_path=str(CHROMIUM), headless=True,
                    args=["--no-sandbox", "--disable-gpu", "--no-first-run",
                          "--disable-background-networking", "--disable-component-update"])
                try:
                    page = browser.new_page(viewport={"width": 1280, "height": 900})
                    page.goto(page_uri, wait_until="load")
                    n = page.evaluate(
                        "JSON.parse(document.getElementById('frontdiag-meta').text).plots")
                    page.wait_for_function(
                        "document.querySelectorAll('.plotly-graph-div .main-svg').length"
                        f" >= {n}")
                    page.screenshot(path=str(out), full_page=False)
                finally:
                    browser.close()
        finally:
            os.chdir(here)
    print(f"wrote {out} ({out.stat().st_size / 1024:.0f} KiB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
