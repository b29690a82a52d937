"""`frontdiag analyze DIR_OR_GLOB... --out DIR`: many recordings, one result folder each."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import typer

from frontdiag.errors import EXIT_INTERRUPTED, ConfigError


def is_fleet(logs: list[Path], scheduler: str | None) -> bool:
    """Several inputs, a glob, a folder of recordings, or a scheduler: a fleet run."""
    import glob

    from frontdiag.fleet import is_recording

    if len(logs) > 1 or scheduler is not None or (glob.has_magic(str(logs[0]))
                                                   and not logs[0].exists()):
        return True
    p = logs[0]
    return p.is_dir() and not is_recording(p)


def run_fleet(logs: list[Path], out: Path | None, opts: Any, *, jobs: int,
              scheduler: str | None, fail_on: str, csv: bool, force: bool, as_json: bool,
              quiet: bool, junit: Path | None = None) -> int:
    from rich.markup import escape
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from frontdiag import fleet
    from frontdiag.cli._console import make_console
    from frontdiag.output import prepare_out_dir

    if out is None:
        if len(logs) == 1 and logs[0].is_dir() and not fleet.discover_quietly(logs[0]):
            # a folder that is neither a recording nor holds one: say what it is instead
            from frontdiag.io.readers import plan

            plan(logs[0])
        raise ConfigError("several recordings need --out DIR (one result folder each)")
    if jobs > 1 and not scheduler:
        from frontdiag.parallel import FLEET_PRELOAD, prestart

        prestart(FLEET_PRELOAD)  # the workers' imports overlap the planning (content hashes)
    skipped: list[Path] = []
    tasks = fleet.plan_tasks(logs, out, opts, fail_on=fail_on, csv=csv, force=force,
                             skipped=skipped)
    if junit is not None:  # checked before anything is written or analysed
        from frontdiag.output import check_output_file

        check_output_file(junit, "--junit", [t.path for t in tasks])
    out = prepare_out_dir(out, [t.path for t in tasks])
    err = make_console(stderr=True)
    show = not quiet and not as_json
    if skipped and not quiet:
        names = ", ".join(p.name for p in skipped[:3]) + (", ..." if len(skipped) > 3 else "")
        err.print(f"[dim]left out {len(skipped)} file(s) that are not recordings: "
                  f"{escape(names)}[/]", highlight=False)
    # one bar for the recordings, and one for each recording under way (its frames)
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TextColumn("{task.fields[unit]}"), TimeElapsedColumn(), console=err,
                  transient=True, disable=not show) as bar:
        task = bar.add_task("[bold]fleet[/]", total=len(tasks), unit="recordings")
        under_way: dict[str, Any] = {}  # result name -> its bar

        def on_frames(i: int, done: int, expected: int | None) -> None:
            name = tasks[i].out.name
            if name not in under_way:
                under_way[name] = bar.add_task(f"  {escape(name)}", total=expected,
                                               unit="frames")
            bar.update(under_way[name], completed=done, total=expected)

        def on_row(row: dict[str, Any]) -> None:
            bar.advance(task)
            if row["recording"] in under_way:
                bar.remove_task(under_way.pop(row["recording"]))
            if row["status"] == "error":
                err.print(f"[red]error[/] {escape(str(row['error']))}")

        if scheduler:
            rows = fleet.run_dask(tasks, scheduler, jobs, on_row)
        else:
            rows = fleet.run_local(tasks, jobs, on_row, on_frames)
    path = fleet.write_summary(out, rows)
    if junit is not None:
        from frontdiag.output import guarded_write
        from frontdiag.report.junit import write_fleet_junit

        guarded_write(junit, lambda: write_fleet_junit(junit, out, rows, fail_on))
    code = fleet.worst_exit(rows)
    not_run = len(tasks) - len(rows)
    stopped = not_run > 0 or any(fleet.interrupted(r) for r in rows)
    if stopped:
        code = max(code, EXIT_INTERRUPTED)
    if as_json:
        typer.echo(json.dumps({"summary": str(path), "exit_code": code, "interrupted": stopped,
                               "not_analysed": not_run, "recordings": rows},
                              indent=2, default=str))
    elif not quiet:
        render_summary(make_console(), rows, path)
    if stopped:
        err.print(f"[yellow]interrupted[/]: {len(rows)} of {len(tasks)} recordings in the "
                  f"summary, {not_run} not analysed; run the same command again to go on "
                  "(finished recordings are skipped, interrupted ones analysed again)")
    return code


def render_summary(con: Any, rows: list[dict[str, Any]], path: Path) -> None:
    from rich.markup import escape
    from rich.table import Table

    t = Table(title=f"fleet: {len(rows)} recordings", title_justify="left")
    for c, j in (("recording", "left"), ("status", "left"), ("frames", "right"),
                 ("coverage", "right"), ("ok", "right"), ("warn", "right"), ("fail", "right"),
                 ("no pose", "right"), ("episodes", "right"), ("gate", "left"), ("s", "right")):
        t.add_column(c, justify=j, min_width=len(c),  # type: ignore[arg-type]
                     overflow="fold")
    for r in rows:
        cov = "" if r["coverage"] is None else f"{100 * r['coverage']:.0f} %"
        status = {"ok": "ok", "skipped": "[dim]skipped[/]",
                  "error": "[red]error[/]"}[r["status"]]
        gate = {"passed": "[green]passed[/]", "failed": "[red]failed[/]",
                "incomplete": "[yellow]incomplete[/]"}.get(r["gate"], "")
        t.add_row(escape(r["recording"]), status, str(r["frames"]), cov, str(r["ok"]),
                  str(r["warn"]), str(r["fail"]),
                  "" if r.get("no_pose") is None else str(r["no_pose"]), str(r["episodes"]), gate,
                  f"{r['seconds']:.1f}")
    con.print(t)
    errors = [r for r in rows if r["status"] == "error"]
    for r in errors:
        con.print(f"[red]error[/] {escape(str(r['error']))}")
    n_skipped = sum(r["status"] == "skipped" for r in rows)
    skipped = (f"; {n_skipped} skipped: their results were current, the same recording and rules "
               "(--force analyses them again)") if n_skipped else ""
    con.print(f"summary: {escape(str(path))} (one result folder per recording beside it"
              f"{skipped})")
