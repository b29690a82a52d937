"""Regenerate docs/loops.png, the picture of `frontdiag loops --optimize --out`'s loops.html.

    python scripts/loops_png.py [--out docs/loops.png]

Simulates the warehouse hall's pose graph (`frontdiag simulate --pose-graph`, 150 s: laps of the
hall with true loops between laps and perceptual-aliasing false loops), audits it with
--optimize into a temporary folder and takes a 1280x860 screenshot of loops.html in headless
Chromium (as scripts/report_png.py does). The left panel is the map an optimiser returns with
every loop believed, the right one the map without the refused loops.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _screenshot import Page, picture_main

ROOT = Path(__file__).resolve().parent.parent


def build(tmp: Path) -> Page | None:
    from frontdiag.cli import main as cli

    if cli(["simulate", "--pose-graph", "hall.g2o", "--seconds", "150"]) != 0:
        return None
    cli(["loops", "hall.g2o", "--optimize", "--out", "hall-audit", "-q"])
    return (tmp / "hall-audit" / "loops.html", 1280, 860,
            "document.querySelectorAll('.plotly-graph-div .main-svg').length > 0")


if __name__ == "__main__":
    sys.exit(picture_main(__doc__, ROOT / "docs" / "loops.png", build))
