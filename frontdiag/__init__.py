"""frontdiag: diagnose SLAM frontends from recordings.

The library API mirrors the CLI: ``frontdiag.analyze(path, ...)`` returns the per-frame table as
a pandas DataFrame. Heavy modules load lazily so ``import frontdiag`` stays cheap.
"""

from __future__ import annotations

from typing import Any

__version__ = "0.1.0"

__all__ = ["__version__", "analyze"]


def analyze(*args: Any, **kwargs: Any) -> Any:
    """Re-run the frontend on a recording; see :func:`frontdiag.api.analyze`."""
    from frontdiag.api import analyze as _analyze

    return _analyze(*args, **kwargs)
