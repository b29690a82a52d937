"""Headless Chromium screenshots of frontdiag's HTML pages, for the pictures in docs/.

Debian's /usr/bin/chromium through Playwright, the same browser the report's test uses.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

CHROMIUM = Path("/usr/bin/chromium")


def have_chromium() -> bool:
    """Whether the browser is installed; says how to get it when it is not."""
    if CHROMIUM.exists():
        return True
    print(f"{CHROMIUM} is missing: install Debian's chromium (apt install chromium)",
          file=sys.stderr)
    return False


def screenshot(page: Path, out: Path, width: int, height: int, ready: str) -> None:
    """Open ``page`` at ``width`` x ``height``, wait until the JavaScript ``ready`` is true, and
    write the visible part to ``out`` (PNG)."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(
            executable_path=str(CHROMIUM), headless=True,
            args=["--no-sandbox", "--disable-gpu", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update"])
        try:
            tab = browser.new_page(viewport={"width": width, "height": height})
            tab.goto(page.as_uri(), wait_until="load")
            tab.wait_for_function(ready)
            tab.screenshot(path=str(out), full_page=False)
        finally:
            browser.close()


Page = tuple[Path, int, int, str]
"""A page to photograph: its file, the viewport's width and height, and the JavaScript that is
true once it is drawn."""


def picture_main(doc: str, default_out: Path, build: Callable[[Path], Page | None]) -> int:
    """A script's main: ``--out`` (default ``default_out``), then ``build`` in a fresh
    temporary folder that is also the working directory (relative paths: the page shows a
    neutral demo folder, not this machine's), then the screenshot of the page it returns
    (None: it failed, exit 2)."""
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=default_out)
    args = ap.parse_args()
    if not have_chromium():
        return 2
    out = args.out.resolve()
    here = Path.cwd()
    with tempfile.TemporaryDirectory(prefix="frontdiag-demo-") as tmp:
        try:
            os.chdir(tmp)
            page = build(Path(tmp))
            if page is None:
                return 2
            screenshot(page[0], out, page[1], page[2], page[3])
        finally:
            os.chdir(here)
    print(f"wrote {out} ({out.stat().st_size / 1024:.0f} KiB)")
    return 0
