"""`frontdiag report RESULT_DIR`: one self-contained HTML page of a result."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from frontdiag.cli import EPILOG

HELP = """Write one self-contained HTML report of an `analyze --out` directory.

The verdict and the gate first, then one plot per metric over time
(thresholds drawn, episodes shaded), the worst frame of each episode
annotated (keypoints, E inliers and outliers, the 8x6 grid counts, flow to
the reference) with its explanation, and the latency budget when a target is
given. The page makes no network request: open it offline, attach it to a CI
job.

Thumbnails re-read their frames from the recording named in manifest.json;
without it they show the annotations on grey.

Examples:

  frontdiag report results/

  frontdiag report results/ -o run.html --target orin-nano

  frontdiag report new/ --baseline old/ -o regression.html     # overlay an earlier run

  frontdiag report fleet/       # a fleet's --out: fleet/index.html, NAME/report.html each
                                # (sharing fleet/plotly.min.js: keep the folder whole)
"""


def register(app: typer.Typer) -> None:
    app.command("report", help=HELP, epilog=EPILOG, no_args_is_help=True)(report_cmd)


def report_cmd(
    result_dir: Path = typer.Argument(..., metavar="RESULT_DIR",
                                      help="The --out directory of `frontdiag analyze` (of one "
                                           "recording, or of a fleet)."),
    output: Path | None = typer.Option(None, "--output", "-o", metavar="FILE",
                                       help="HTML file to write [default: RESULT_DIR/report.html]."),
    baseline: Path | None = typer.Option(None, "--baseline", metavar="DIR",
                                         help="An earlier result of the same recording: drawn "
                                              "under every plot, and gated for regressions."),
    target: str | None = typer.Option(None, "--target",
                                      help="Project the measured stage times onto this target "
                                           "(see `frontdiag budget --list-targets`)."),
    fail_on: str = typer.Option("fail", "--fail-on",
                                help="Gate shown in the report: warn, fail or never."),
    no_thumbnails: bool = typer.Option(False, "--no-thumbnails",
                                       help="Skip re-reading the recording for thumbnails."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print nothing on success."),
) -> int:
    from rich.markup import escape

    from frontdiag.cli._console import make_console
    from frontdiag.errors import EXIT_OK, ConfigError

    if fail_on not in ("warn", "fail", "never"):
        raise ConfigError(f"--fail-on {fail_on!r}: choose warn, fail or never")
    from frontdiag.fleet import is_fleet_out

    if is_fleet_out(result_dir):
        if baseline is not None or target is not None:
            raise ConfigError(f"{result_dir} is a fleet run's folder: --baseline and --target "
                              "apply to one recording's result",
                              hint=f"pass one recording's folder, e.g. {result_dir}/NAME")
        return _fleet_report(result_dir, output, fail_on, no_thumbnails, quiet)
    for d, flag in ((result_dir, "RESULT_DIR"), (baseline, "--baseline")):
        if d is not None and not (d / "frames.parquet").is_file():
            from frontdiag.output import result_dir_hint

            raise ConfigError(f"{flag} {d}: no frames.parquet there",
                              hint=result_dir_hint(d, "pass the --out directory of "
                                                   "`frontdiag analyze`"))
    out = output if output is not None else result_dir / "report.html"
    if not out.parent.is_dir():
        raise ConfigError(f"--output {out}: folder {out.parent} does not exist")
    if out.is_dir():
        raise ConfigError(f"--output {out}: is a directory; name the HTML file")
    try:
        import plotly  # noqa: F401
    except ImportError:
        raise ConfigError("frontdiag report needs plotly",
                          hint="pip install 'plotly>=5.20'") from None
    from frontdiag.report.html import ReportInputs, build_html, load_run
    from frontdiag.verdicts import gate

    err = make_console(stderr=True)
    with err.status("reading the result"):
        run = load_run(result_dir)
        base = load_run(baseline, label="baseline") if baseline is not None else None
        inputs = ReportInputs(run, base, thumbnails=not no_thumbnails)
        inputs.gate = gate(run.verdicts, fail_on=fail_on,  # type: ignore[arg-type]
                           baseline=baseline)
    if target is not None:
        with err.status(f"projecting the stage times onto {target}"):
            inputs.budget_grids = _budget_grids(result_dir, target)
    with err.status("drawing"):
        page = build_html(inputs)
    out.write_text(page, encoding="utf-8")
    if not quiet:
        make_console().print(f"report: {escape(str(out))} ({len(page.encode()) / 1e6:.1f} MB)")
    return EXIT_OK


def _fleet_report(out_dir: Path, output: Path | None, fail_on: str, no_thumbnails: bool,
                  quiet: bool) -> int:
    """A fleet run's folder: each finished recording's own report (NAME/report.html) and one
    index page over them (index.html, or --output)."""
    import os
    from functools import partial

    from rich.markup import escape
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

    from frontdiag.cli._console import make_console
    from frontdiag.errors import EXIT_OK, ConfigError
    from frontdiag.fleet import read_summary
    from frontdiag.output import guarded_write
    from frontdiag.report.html import ReportInputs, build_html, fleet_index_html, load_run
    from frontdiag.verdicts import gate

    index = output if output is not None else out_dir / "index.html"
    if not index.parent.is_dir():
        raise ConfigError(f"--output {index}: folder {index.parent} does not exist")
    if index.is_dir():
        raise ConfigError(f"--output {index}: is a directory; name the HTML file")
    summary = read_summary(out_dir)
    names = [str(n) for n in summary["recording"] if (out_dir / str(n) / "frames.parquet").is_file()]
    pages: dict[str, str] = {}
    if names:  # one copy of plotly.js for every page of the fleet (NAME/report.html: one up)
        from plotly.offline import get_plotlyjs

        from frontdiag.report.html import PLOTLY_FILE

        shared = out_dir / PLOTLY_FILE
        guarded_write(shared, lambda: shared.write_text(get_plotlyjs(), encoding="utf-8"))
    with Progress(TextColumn("[bold]report[/] {task.description}"), BarColumn(),
                  MofNCompleteColumn(), TextColumn("recordings"),
                  console=make_console(stderr=True), transient=True, disable=quiet) as bar:
        task = bar.add_task(out_dir.name, total=len(names))
        for name in names:
            run = load_run(out_dir / name)
            inputs = ReportInputs(run, None, thumbnails=not no_thumbnails)
            inputs.gate = gate(run.verdicts, fail_on=fail_on)  # type: ignore[arg-type]
            page = out_dir / name / "report.html"
            guarded_write(page, partial(page.write_text,
                                        build_html(inputs, plotly_src=f"../{PLOTLY_FILE}"),
                                        encoding="utf-8"))
            pages[name] = Path(os.path.relpath(page, index.parent)).as_posix()
            bar.advance(task)
    text = fleet_index_html(out_dir, summary, pages)
    guarded_write(index, lambda: index.write_text(text, encoding="utf-8"))
    if not quiet:
        make_console().print(f"report: {escape(str(index))} over {len(names)} recordings "
                             f"(each one's page: {escape(str(out_dir))}/NAME/report.html)")
    return EXIT_OK


def _budget_grids(result_dir: Path, target_name: str) -> list[Any]:
    """The measured projection `frontdiag budget --target T --from DIR` prints, as grids."""
    from frontdiag.budget import measured, model, render
    from frontdiag.budget.targets import load_target
    from frontdiag.cli.budget import _machine

    target = load_target(target_name)
    machine, note = _machine({"machine": None, "recalibrate": False, "repeats": 3})
    rep = measured.measured_report(result_dir, model.Workload().validate(), target, machine,
                                   note)
    return render.measured_grids(rep)
