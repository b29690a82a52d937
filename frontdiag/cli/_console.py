"""Consoles for the commands: never cut a topic, type or path when the output is not a terminal.

Rich lays tables out for 80 columns when stdout is a pipe or a file (``frontdiag info LOG | cat``)
and shortens cells with an ellipsis. Output that goes to a file or another program must keep
every name whole, so off a terminal the console is as wide as the content needs (up to
``WIDE``) instead; on a terminal rich still uses the terminal's width and wraps.
"""

from __future__ import annotations

import os
import sys

from rich.console import Console

WIDE = 400
"""Columns granted off a terminal: wide enough for any topic/type pair, narrow enough that a
rule line or a title does not fill a log with blanks."""


def _is_tty(stream: object) -> bool:
    isatty = getattr(stream, "isatty", None)
    try:
        return bool(isatty and isatty())
    except (ValueError, OSError):  # closed stream
        return False


def make_console(stderr: bool = False, **kwargs: object) -> Console:
    """A rich Console on stdout (or stderr) that does not truncate when not on a terminal.

    ``COLUMNS`` in the environment still wins, as it does for rich itself.
    """
    stream = sys.stderr if stderr else sys.stdout
    if "width" not in kwargs and not _is_tty(stream) and not os.environ.get("COLUMNS"):
        kwargs["width"] = WIDE
    return Console(stderr=stderr, **kwargs)  # type: ignore[arg-type]
