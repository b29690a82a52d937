"""Versions of frontdiag and of the libraries whose numbers end up in its tables.

Read from installed distribution metadata, except OpenCV, whose version is read from the module
that is actually loaded (an environment can shadow the installed wheel; 0.15 s to import). OpenCV changes FAST/ORB corner sets and RANSAC inlier counts between
major versions (see docs/camera.md, "OpenCV versions"), so every result records which one made it.
"""

from __future__ import annotations

import importlib.metadata as md

from frontdiag import __version__

# distribution names in the order they are printed, after OpenCV
_DISTRIBUTIONS = ("numpy", "small-gicp", "rosbags", "mcap", "pandas",
                  "pyarrow", "faiss-cpu", "scipy", "qdldl", "cvxopt", "typer", "rich")


def versions() -> dict[str, str]:
    """frontdiag's version and each installed library it depends on, by distribution name."""
    import cv2

    out = {"frontdiag": __version__, "opencv": cv2.__version__}
    for dist in _DISTRIBUTIONS:
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
