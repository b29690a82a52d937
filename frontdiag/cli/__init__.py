"""The ``frontdiag`` command line: one typer command per job, errors mapped to exit codes here.

Exit codes: 0 nothing at or above --fail-on, 1 a gate failed, 2 bad input / usage / config,
3 internal error, 130 interrupted. Only this package prints or exits.
"""

from __future__ import annotations

import logging
import sys

import typer
from rich.console import Console
from typer import Abort as _Abort
from typer import Exit as _Exit

from frontdiag.cli._console import make_console
from frontdiag.errors import (
    EXIT_INPUT,
    EXIT_INTERNAL,
    EXIT_INTERRUPTED,
    EXIT_OK,
    FrontdiagError,
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
    logging.basicConfig(level=logging.DEBUG if debug else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")


def _register() -> None:
    from frontdiag.cli import (
        analyze,
        budget,
        eval_,
        explain,
        info,
        loops,
        rules,
        simulate,
    )

    for module in (analyze, info, explain, rules, simulate, eval_, budget, loops):
        module.register(app)


_register()


def hoist_root_flags(args: list[str]) -> list[str]:
    """`frontdiag analyze run.mcap --debug` means the same as `frontdiag --debug analyze ...`:
    move the root's --debug in front of the subcommand (up to a literal `--`)."""
    end = args.index("--") if "--" in args else len(args)
    if "--debug" not in args[:end]:
        return args
    return ["--debug", *[a for a in args[:end] if a != "--debug"], *args[end:]]


def main(argv: list[str] | None = None) -> int:
    """Console entry point; returns the process exit code."""
    args = sys.argv[1:] if argv is None else list(argv)
    args = hoist_root_flags(args)
    debug = "--debug" in args
    err = _err_console()
    try:
        rv = typer.main.get_command(app).main(args=args, prog_name="frontdiag",
                                               standalone_mode=False)
    except FrontdiagError as exc:
        if debug:
            err.print_exception()
        err.print(f"[bold red]error:[/] {exc}", highlight=False, markup=True, soft_wrap=True)
        if exc.hint:
            err.print(f"  {exc.hint}", highlight=False, soft_wrap=True)
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
                      f"{exc_val} (a bug in frontdiag; rerun with --debug for the traceback)",
                      highlight=False, soft_wrap=True)
        return EXIT_INTERNAL
    if isinstance(rv, int):
        return rv
    return EXIT_OK


def _err_console() -> Console:
    return make_console(stderr=True)


def run() -> None:
    sys.exit(main())
