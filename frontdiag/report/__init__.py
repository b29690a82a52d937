"""Renderers of verdicts: console summary, JUnit XML, JSON, episodes.parquet.

REPORTERS maps a file reporter's name to its writer `(path_or_dir, result, ...)`.

The names are imported on first use (PEP 562): a window worker of ``analyze --jobs N`` imports
``frontdiag.report.mcap_`` to stream its part of diagnostics.mcap, and should not load pandas,
Arrow and the renderers with it (about 80 MiB per worker).
"""

from __future__ import annotations

import importlib
from typing import Any

_WHERE = {
    "reanalyse_command": "console",
    "render_console_summary": "console",
    "write_episodes": "files",
    "write_rules_snapshot": "files",
    "to_json": "json_",
    "write_junit": "junit",
}

__all__ = ["REPORTERS", *sorted(_WHERE)]


def __getattr__(name: str) -> Any:
    if name == "REPORTERS":
        return {"junit": __getattr__("write_junit"), "episodes": __getattr__("write_episodes")}
    where = _WHERE.get(name)
    if where is None:
        raise AttributeError(f"module 'frontdiag.report' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"frontdiag.report.{where}"), name)
    globals()[name] = value
    return value
