"""The ``frontdiag`` command line: one typer command per job, errors mapped to exit codes here.

Exit codes: 0 nothing at or above --fail-on, 1 a gate failed, 2 bad input / usage / config,
3 internal error, 130 interrupted. Only this package prints or exits.
"""

from __future__ import annotations

import logging
import sys
from typing import Any, ClassVar

import typer
from rich.console import Console
from rich.markup import escape
from typer import Abort as _Abort
from typer import Exit as _Exit

from frontdiag.cli._console import make_console
from frontdiag.errors import (
    EXIT_INPUT,
    EXIT_INTERNAL,
    EXIT_INTERRUPTED,
    EXIT_OK,
    FrontdiagError,
    interrupt_on_signal,
)

# typer >= 0.20 vendors click; older releases depend on it.
try:  # pragma: no cover - depends on the installed typer
    from typer._click.exceptions import ClickException as _ClickException
except ImportError:  # pragma: no cover
    from click.exceptions import ClickException as _ClickException  # type: ignore[assignment]

EPILOG = (
    "Exit codes: 0 ok · 1 gate failed · 2 bad input, usage or config · 3 internal error · "
    "130 interrupted. Add --debug for a traceback."
)

app = typer.Typer(
    name="frontdiag",
    help="Diagnose SLAM frontends from recordings (ROS 1 .bag, ROS 2 .db3/.mcap, plain MCAP).\n\n"
    "Re-runs the camera and LiDAR frontend frame by frame and names the failure with the "
    "secondary metric that reveals it.\n\n"
    "Examples:\n\n"
    "  frontdiag info run.mcap\n\n"
    "  frontdiag analyze run.mcap --out results/\n\n"
    "  frontdiag explain results/ --frame 120\n\n"
    "  frontdiag analyze logs/ --out fleet/ --jobs 2     # every recording in a folder\n\n"
    "  frontdiag loops map.g2o --out audit/\n\n"
    "  frontdiag budget --target orin-nano",
    epilog=EPILOG,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=True,
    rich_markup_mode="rich",
)

_state = {"debug": False}




def _version_callback(value: bool) -> None:
    if value:
        from frontdiag.versions import version_text

        typer.echo(version_text())
        raise typer.Exit(0)


@app.callback()
def _root(
    debug: bool = typer.Option(False, "--debug", help="Show tracebacks and debug logging."),
    version: bool = typer.Option(False, "--version", callback=_version_callback,
                                 is_eager=True, help="Print the version and exit."),
) -> None:
    _state["debug"] = debug
    if debug:
        logging.basicConfig(level=logging.DEBUG, format="%(levelname)s %(name)s: %(message)s")
    else:
        install_console_warnings()


class ConsoleWarnings(logging.Handler):
    """The library's warnings (a damaged index read sequentially, a scan that failed) as one
    console line each on stderr, ``warning: ...``, instead of raw ``WARNING module:`` log
    records; the logger name and traceback stay for --debug."""

    pending: ClassVar[list[str]] = []
    """Warnings of the running command, printed when it ends (after the progress bar)."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = record.getMessage()
        except Exception:  # a malformed record must not stop the command
            text = str(record.msg)
        if text not in self.pending:
            self.pending.append(text)

    @classmethod
    def flush(cls, superseded_by: str | None = None) -> None:
        """Print the pending warnings; a warning about the file a fatal error names is left
        out, so damage that stops a command is one line (the error), not a warning and an
        error about the same thing."""
        from rich.markup import escape

        err = make_console(stderr=True)
        for text in cls.pending:
            path = text.split(":", 1)[0].split(" ", 1)[0]
            if superseded_by is not None and path and path in superseded_by:
                continue
            err.print(f"[yellow]warning:[/] {escape(text)}", highlight=False, soft_wrap=True)
        cls.pending.clear()


def install_console_warnings() -> None:
    """Route frontdiag's WARNING records (and worse) to :class:`ConsoleWarnings`, once. They
    still propagate, so a root handler an embedding application (or pytest) installs sees them;
    the CLI itself installs none, so nothing prints twice."""
    root = logging.getLogger("frontdiag")
    if not any(isinstance(h, ConsoleWarnings) for h in root.handlers):
        handler = ConsoleWarnings(logging.WARNING)
        root.addHandler(handler)
    if root.level == logging.NOTSET or root.level > logging.WARNING:
        root.setLevel(logging.WARNING)


def _register() -> None:
    from frontdiag.cli import (
        analyze,
        budget,
        eval_,
        explain,
        info,
        loops,
        report,
        rules,
        simulate,
    )

    for module in (analyze, info, explain, rules, simulate, eval_, budget, loops, report):
        module.register(app)


_register()


def hoist_root_flags(args: list[str]) -> list[str]:
    """`frontdiag analyze run.mcap --debug` means the same as `frontdiag --debug analyze ...`:
    move the root's --debug in front of the subcommand (up to a literal `--`)."""
    end = args.index("--") if "--" in args else len(args)
    if "--debug" not in args[:end]:
        return args
    return ["--debug", *[a for a in args[:end] if a != "--debug"], *args[end:]]


def _terminate_as_interrupt() -> Any:
    """SIGTERM (a CI job's timeout, ``timeout``, a supervisor stopping the job) ends the run
    the way Ctrl-C does: the frames analysed so far are kept and written, exit 130. Only when
    nothing else handles SIGTERM (an embedding program's handler is left alone); returns the
    handler to restore, or None."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return None
    try:
        previous = signal.getsignal(signal.SIGTERM)
        if previous is not signal.SIG_DFL:
            return None
        signal.signal(signal.SIGTERM, interrupt_on_signal)
    except (AttributeError, ValueError, OSError):
        return None
    return previous


def _command() -> Any:
    """The click command tree of ``app``, with the value type taken off the flags' help rows:
    typer shows ``<bool>`` beside ``--json`` or ``--no-mutual`` as if the flag took a value."""
    root = typer.main.get_command(app)

    def walk(cmd: Any) -> None:
        # the --help option is made on first use, from the command's context settings
        ctx = cmd.context_class(cmd, **(cmd.context_settings or {}))
        for param in [*cmd.params, cmd.get_help_option(ctx)]:
            # typer's own Option class (it vendors click): read the flag attribute, not the type
            if param is not None and getattr(param, "is_flag", False) and param.metavar is None:
                param.metavar = ""
        for sub in getattr(cmd, "commands", {}).values():
            walk(sub)

    walk(root)
    return root


def main(argv: list[str] | None = None) -> int:
    """Console entry point; returns the process exit code."""
    import signal

    args = sys.argv[1:] if argv is None else list(argv)
    args = hoist_root_flags(args)
    debug = "--debug" in args
    err = _err_console()
    restore = _terminate_as_interrupt()
    try:
        rv = _command().main(args=args, prog_name="frontdiag",
                                               standalone_mode=False)
    except FrontdiagError as exc:
        ConsoleWarnings.flush(superseded_by=str(exc))
        if debug:
            err.print_exception()
        err.print(f"[bold red]error:[/] {escape(str(exc))}", highlight=False, soft_wrap=True)
        if exc.hint:
            err.print(f"  {escape(exc.hint)}", highlight=False, soft_wrap=True)
        return exc.exit_code
    except (_Abort, KeyboardInterrupt):
        err.print("interrupted")
        return EXIT_INTERRUPTED
    except _Exit as exc:
        return int(exc.exit_code)
    except _ClickException as exc:
        exc.show()
        return EXIT_INPUT
    except Exception:
        if debug:
            err.print_exception()
        else:
            exc_type, exc_val, _ = sys.exc_info()
            err.print(f"[bold red]internal error:[/] {exc_type.__name__ if exc_type else ''}: "
                      f"{escape(str(exc_val))} (a bug in frontdiag; rerun with --debug for the traceback)",
                      highlight=False, soft_wrap=True)
        return EXIT_INTERNAL
    finally:
        ConsoleWarnings.flush()
        if restore is not None:
            signal.signal(signal.SIGTERM, restore)
    if isinstance(rv, int):
        return rv
    return EXIT_OK


def _err_console() -> Console:
    return make_console(stderr=True)


def run() -> None:
    sys.exit(main())
