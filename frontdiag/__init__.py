"""frontdiag: diagnose SLAM frontends from recordings.

The library API mirrors the CLI: ``frontdiag.analyze(path, ...)`` takes the options of
``frontdiag analyze`` as keywords and returns a :class:`frontdiag.result.Result` (table,
episodes, gate, manifest; ``.to_pandas()`` for the DataFrame). Heavy modules load lazily so
``import frontdiag`` stays cheap.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

__version__ = "0.1.0"

__all__ = ["Result", "__version__", "analyze"]

if TYPE_CHECKING:
    from frontdiag.result import Result, analyze
else:
    def __getattr__(name: str) -> object:
        if name in ("analyze", "Result"):
            from frontdiag import result

            return getattr(result, name)
        raise AttributeError(f"module 'frontdiag' has no attribute {name!r}")
