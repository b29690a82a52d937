"""Versions of frontdiag and of the libraries whose numbers end up in its tables.

Read from installed distribution metadata, so nothing heavy is imported: ``frontdiag --version``
stays instant. OpenCV in particular changes FAST/ORB corner sets and RANSAC inlier counts between
major versions (see docs/camera.md, "OpenCV versions"), so every result records which one made it.
"""

from __future__ import annotations

import importlib.metadata as md

from frontdiag import __version__

# distribution names in the order they are printed; the first OpenCV wheel found is reported
_DISTRIBUTIONS = ("opencv-python-headless", "opencv-python", "opencv-contrib-python-headless",
                  "opencv-contrib-python", "numpy", "small-gicp", "rosbags", "mcap", "pandas",
                  "pyarrow", "faiss-cpu", "scipy", "typer", "rich")


def versions() -> dict[str, str]:
    """frontdiag's version and each installed library it depends on, by distribution name."""
    out = {"frontdiag": __version__}
    for dist in _DISTRIBUTIONS:
        if dist.startswith("opencv") and any(k.startswith("opencv") for k in out):
            continue
        try:
            out[dist] = md.version(dist)
        except md.PackageNotFoundError:
            continue
    return out


def version_text() -> str:
    """The ``frontdiag --version`` text: frontdiag first, then the libraries on one line."""
    v = versions()
    libs = ", ".join(f"{k} {val}" for k, val in v.items() if k != "frontdiag")
    return f"frontdiag {v['frontdiag']}\n{libs}"
