"""Renderers of verdicts: console summary, JUnit XML, JSON, episodes.parquet.

REPORTERS maps a file reporter's name to its writer `(path_or_dir, result, ...)`.
"""

from __future__ import annotations

from frontdiag.report.console import reanalyse_command, render_console_summary
from frontdiag.report.files import write_episodes, write_rules_snapshot
from frontdiag.report.json_ import to_json
from frontdiag.report.junit import write_junit

REPORTERS = {
    "junit": write_junit,
    "episodes": write_episodes,
}

__all__ = [
    "REPORTERS",
    "reanalyse_command",
    "render_console_summary",
    "to_json",
    "write_episodes",
    "write_junit",
    "write_rules_snapshot",
]
