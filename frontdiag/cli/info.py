"""`frontdiag info LOG`: what a recording holds and what analyze would read."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from frontdiag.cli import EPILOG

HELP = """Show topics, message types, counts, rates and duration of a recording, which
topics analyze would choose, and anything odd (missing CameraInfo, stamp
gaps, damage).

Examples:

  frontdiag info run.mcap

  frontdiag info run_db3/ --json
"""


def register(app: typer.Typer) -> None:
    app.command("info", help=HELP, epilog=EPILOG, no_args_is_help=True,
                short_help="Show a recording's topics, rates and duration, and what analyze "
                           "would read.")(info_cmd)


def info_cmd(
    log: Path = typer.Argument(..., help="Recording: .bag, .db3, .mcap, or a bag folder; a "
                               "folder of recordings lists one line each.",
                               show_default=False),
    as_json: bool = typer.Option(False, "--json", help="Machine-readable output on stdout "
                                 "(schema docs/schemas/info.json)."),
) -> int:
    from rich.markup import escape
    from rich.table import Table

    from frontdiag.cli._console import make_console
    from frontdiag.fleet import is_recording
    from frontdiag.inspect import inspect_recording

    if log.is_dir() and not is_recording(log):
        return _folder(log, as_json)
    rep = inspect_recording(log)
    if as_json:
        from frontdiag.json_models import InfoDoc, emit

        typer.echo(emit(InfoDoc, json.loads(json.dumps(rep.to_dict(), default=str))))
        return _damage_exit(rep)
    con = make_console()
    dur = f"{rep.duration_s:.2f} s" if rep.duration_s is not None else "unknown"
    read = f"{escape(rep.container)}, {rep.backend} reader" if rep.container else \
        f"{rep.backend} reader"
    con.print(f"[bold]{escape(str(rep.path))}[/]  [dim]{read}[/]  duration {dur}")
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
                           f"LiDAR {c.lidar or '—'}, odometry "
                           + (c.odometry or (f"from {c.tf} (an odometry frame chained to the "
                                             "LiDAR's frame, if one is)" if c.tf else "—"))
                           + (f", placed at the LiDAR by {c.tf_static} where it joins their "
                              "frames" if c.odometry and c.tf_static else "")),
                  highlight=False)
    else:
        con.print(f"[bold]analyze cannot start on its own[/]: {escape(str(rep.choice_error))}",
                  highlight=False)
    for odd in rep.oddities:
        con.print(f"[yellow]odd:[/] {escape(odd)}", highlight=False)
    return _damage_exit(rep)


def _folder(folder: Path, as_json: bool) -> int:
    """A folder of recordings: one line each (what `info` says of it), before a fleet run."""
    from rich.markup import escape
    from rich.table import Table

    from frontdiag.cli._console import make_console
    from frontdiag.errors import EXIT_INPUT, EXIT_OK, FrontdiagError
    from frontdiag.fleet import discover
    from frontdiag.inspect import inspect_recording

    reports, errors = [], []
    for path in discover([folder]):
        try:
            reports.append(inspect_recording(path))
        except FrontdiagError as exc:
            errors.append({"path": str(path), "error": str(exc)})
    code = EXIT_INPUT if errors or any(r.fault for r in reports) else EXIT_OK
    if as_json:
        from frontdiag.json_models import InfoFleetDoc, emit

        docs = [json.loads(json.dumps(r.to_dict(), default=str)) for r in reports]
        typer.echo(emit(InfoFleetDoc, {"folder": str(folder), "recordings": docs,
                                       "errors": errors}))
        return code
    con = make_console()
    con.print(f"[bold]{escape(str(folder))}[/]: {len(reports) + len(errors)} recordings")
    t = Table(show_edge=False, header_style="bold")
    for col, just in (("recording", "left"), ("reader", "left"), ("duration (s)", "right"),
                      ("camera (Hz)", "left"), ("LiDAR (Hz)", "left"), ("odd", "left")):
        t.add_column(col, justify=just)  # type: ignore[arg-type]
    for r in reports:
        rates = {tr.topic: tr.rate_hz for tr in r.topics}

        def topic(name: str | None, rates: dict = rates) -> str:
            if not name:
                return "—"
            hz = rates.get(name)
            return f"{name} ({hz:.1f})" if hz else name

        c = r.choice
        odd = ([f"damaged: {r.fault}"] if r.fault else []) + list(r.oddities)
        t.add_row(escape(r.path.name), r.backend,
                  "—" if r.duration_s is None else f"{r.duration_s:.1f}",
                  escape(topic(c.camera if c else None)) if c else
                  f"[red]{escape(str(r.choice_error))}[/]",
                  escape(topic(c.lidar if c else None)),
                  escape(odd[0] + (f" (+{len(odd) - 1})" if len(odd) > 1 else "")) if odd
                  else "")
    for e in errors:
        t.add_row(escape(Path(e["path"]).name), "—", "—", f"[red]{escape(e['error'])}[/]", "",
                  "")
    con.print(t)
    con.print("[dim]one recording's detail: frontdiag info FILE · analyse them all: "
              "frontdiag analyze FOLDER --out OUT --jobs N[/]")
    return code


def _damage_exit(rep: object) -> int:
    """Damage is a non-zero exit, as `mcap doctor` makes it: exit 2 with the one-line error,
    after the report of what was readable."""
    from frontdiag.errors import EXIT_OK, FrontdiagError

    fault = getattr(rep, "fault", None)
    if fault is None:
        return EXIT_OK
    raise FrontdiagError(str(fault), hint="the report above covers what was readable before it")
