"""`frontdiag info LOG`: what a recording holds and what analyze would read."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from frontdiag.cli import EPILOG

HELP = """Show topics, message types, counts, rates and duration of a recording, which topics
analyze would choose, and anything odd (missing CameraInfo, stamp gaps, damage).

Examples:

  frontdiag info run.mcap

  frontdiag info run_db3/ --json
"""


def register(app: typer.Typer) -> None:
    app.command("info", help=HELP, epilog=EPILOG, no_args_is_help=True,
                short_help="Show a recording's topics, rates and duration, and what analyze "
                           "would read.")(info_cmd)


def info_cmd(
    log: Path = typer.Argument(..., help="Recording: .bag, .db3, .mcap, or a bag folder.",
                               show_default=False),
    as_json: bool = typer.Option(False, "--json", help="Machine-readable output on stdout "
                                 "(schema docs/schemas/info.json)."),
) -> int:
    from rich.markup import escape
    from rich.table import Table

    from frontdiag.cli._console import make_console
    from frontdiag.inspect import inspect_recording

    rep = inspect_recording(log)
    if as_json:
        from frontdiag.json_models import InfoDoc, emit

        typer.echo(emit(InfoDoc, json.loads(json.dumps(rep.to_dict(), default=str))))
        return _damage_exit(rep)
    con = make_console()
    dur = f"{rep.duration_s:.2f} s" if rep.duration_s is not None else "unknown"
    con.print(f"[bold]{escape(str(rep.path))}[/]  [dim]{rep.backend} reader[/]  duration {dur}")
    t = Table(show_edge=False, header_style="bold")
    for col, just in (("topic", "left"), ("type", "left"), ("messages", "right"),
                      ("rate (Hz)", "right"), ("max gap (s)", "right"), ("detail", "left")):
        t.add_column(col, justify=just)  # type: ignore[arg-type]
    for tr in rep.topics:
        t.add_row(escape(tr.topic), escape(tr.msgtype), "?" if tr.count is None else str(tr.count),
                  "—" if tr.rate_hz is None else f"{tr.rate_hz:.2f}",
                  "—" if tr.max_gap_s is None else f"{tr.max_gap_s:.3f}", escape(tr.detail))
    con.print(t)
    if rep.choice is not None:
        c = rep.choice
        con.print("[bold]analyze would read[/]: "
                  + escape(f"camera {c.camera or '—'} (CameraInfo {c.camera_info or '—'}), "
                           f"LiDAR {c.lidar or '—'}, odometry {c.odometry or '—'}"),
                  highlight=False)
    else:
        con.print(f"[bold]analyze cannot start on its own[/]: {escape(str(rep.choice_error))}",
                  highlight=False)
    for odd in rep.oddities:
        con.print(f"[yellow]odd:[/] {escape(odd)}", highlight=False)
    return _damage_exit(rep)


def _damage_exit(rep: object) -> int:
    """Damage is a non-zero exit, as `mcap doctor` makes it: exit 2 with the one-line error,
    after the report of what was readable."""
    from frontdiag.errors import EXIT_OK, FrontdiagError

    fault = getattr(rep, "fault", None)
    if fault is None:
        return EXIT_OK
    raise FrontdiagError(str(fault), hint="the report above covers what was readable before it")
