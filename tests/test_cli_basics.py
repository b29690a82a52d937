"""The command line starts, shows help and maps errors to the documented exit codes."""

from __future__ import annotations

import subprocess
import sys

from frontdiag.cli import main


def test_help_lists_commands(capsys) -> None:
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    assert "frontdiag" in out
    assert "Exit codes" in out


def test_version(capsys) -> None:
    assert main(["--version"]) == 0
    out = capsys.readouterr().out
    assert "frontdiag 0." in out
    # the libraries whose numbers reach the tables are named with their versions
    import cv2
    import numpy

    assert f"numpy {numpy.__version__}" in out
    assert f"opencv {cv2.__version__}" in out


def test_unknown_command_is_usage_error() -> None:
    assert main(["no-such-command"]) == 2


def test_module_entry_point_runs() -> None:
    proc = subprocess.run([sys.executable, "-m", "frontdiag", "--version"],
                          capture_output=True, text=True, check=False)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("frontdiag ")
