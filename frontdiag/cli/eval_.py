"""`frontdiag eval`: score per-frame verdicts against labelled intervals, and gate on accuracy."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from frontdiag.errors import EXIT_GATE, EXIT_OK, ConfigError


def _is_recording(p: Path) -> bool:
    if p.is_file():
        from frontdiag.io.readers import RECORDING_SUFFIXES  # not at `--help` time

        return p.suffix.lower() in RECORDING_SUFFIXES
    return p.is_dir() and (p / "metadata.yaml").is_file()


def _fmt(v: float | None, pct: bool = False) -> str:
    if v is None:
        return "—"
    return f"{100 * v:.1f} %" if pct else f"{v:.2f}"


def _ci(v: tuple[float, float] | None, pct: bool = False) -> str:
    from frontdiag.scoring import format_interval

    return format_interval(v, pct=pct, dash="–", missing="—")


def find_labels(target: Path, labels: Path | None) -> tuple[Path, Path | None]:
    """The labels file to score against, and the recording they belong to (when known).

    An explicit --labels wins. For a recording the default is ``<recording>.labels.csv``; for a
    result directory the recording is read from its manifest.json (``input.path``)."""
    from frontdiag.output import read_manifest
    from frontdiag.sim.run import labels_path_for

    recording: Path | None = target if _is_recording(target) else None
    if recording is None and target.is_dir():
        src = (read_manifest(target).get("input") or {}).get("path")
        recording = Path(src) if src else None
    if labels is not None:
        found = labels
    elif recording is not None:
        found = labels_path_for(recording)
    else:
        raise ConfigError(f"{target}: no --labels given and no recording to find them beside",
                          hint="pass --labels FILE (the simulator writes <recording>.labels.csv)")
    if not found.is_file():
        raise ConfigError(f"labels file not found: {found}",
                          hint="pass --labels FILE; `frontdiag simulate` writes "
                          "<recording>.labels.csv beside each recording")
    return found, recording


def fleet_reports(out: Path) -> tuple[list[tuple[str, Any]], list[str]]:
    """Each finished recording of a fleet run's ``--out`` folder scored against the labels
    beside the recording (``<recording>.labels.csv``): ``(name, report)`` pairs, and the names
    left out with why (no labels, not analysed)."""

    from frontdiag.conditions import CONDITIONS
    from frontdiag.fleet import read_summary
    from frontdiag.scoring import read_frames, read_labels, score
    from frontdiag.sim.run import labels_path_for

    summary = read_summary(out)
    scored, left = [], []
    for row in summary.itertuples(index=False):
        name = str(row.recording)
        folder = out / name
        if not (folder / "frames.parquet").is_file():
            left.append(f"{name} (not analysed: {row.status})")
            continue
        labels = labels_path_for(Path(str(row.path)))
        if not labels.is_file():
            left.append(f"{name} (no {labels.name} beside it)")
            continue
        # every condition on every recording, so that a condition's false alarms count all
        # healthy frames of the fleet, not only those of recordings where it was labelled
        scored.append((name, score(read_frames(folder), read_labels(labels),
                                   conditions=CONDITIONS)))
    return scored, left


def accuracy_gate(report: Any, min_recall: float | None, min_precision: float | None,
                  max_false_alarm: float | None) -> list[str]:
    """Reasons the scores miss the requested gates (empty: passed). Recall is episode recall
    per labelled condition, precision frame precision, false alarms the share of healthy frames
    flagged with anything."""
    reasons = []
    for c in report.conditions:
        if not c.episodes:
            continue
        if min_recall is not None and (c.episode_recall or 0.0) < min_recall:
            reasons.append(f"{c.condition}: episode recall {_fmt(c.episode_recall)} < "
                           f"--min-recall {min_recall:g}")
        if min_precision is not None and (c.precision or 0.0) < min_precision:
            reasons.append(f"{c.condition}: frame precision {_fmt(c.precision)} < "
                           f"--min-precision {min_precision:g}")
    rate = report.false_alarm_rate
    if max_false_alarm is not None and rate is not None and rate > max_false_alarm:
        reasons.append(f"false alarms on {_fmt(rate, pct=True)} of healthy frames > "
                       f"--max-false-alarm {max_false_alarm:g}")
    return reasons


def _analyse(recording: Path, quiet: bool) -> Any:
    from frontdiag.api import AnalysisOptions, run_analysis
    from frontdiag.cli._console import make_console

    if quiet:
        return run_analysis(recording, AnalysisOptions())
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

    with Progress(TextColumn("[bold]analyze[/] {task.description}"), BarColumn(),
                  MofNCompleteColumn(), TextColumn("frames"),
                  console=make_console(stderr=True), transient=True) as bar:
        task = bar.add_task(recording.name, total=None)

        def progress(done: int, expected: int | None) -> None:
            bar.update(task, completed=done, total=expected)

        return run_analysis(recording, AnalysisOptions(), progress=progress)


def _share(value: float, name: str) -> float:
    if not 0.0 <= value <= 1.0:
        raise ConfigError(f"{name} {value:g}: choose a share between 0 and 1")
    return value


def register(app: typer.Typer) -> None:
    """Add the command to the app."""

    @app.command("eval", epilog="Scoring rules: docs/simulate.md#scoring.")
    def eval_cmd(
        target: Path = typer.Argument(..., help="An `analyze --out` directory, a frames "
                                      ".parquet/.csv, a recording (analysed first), or a "
                                      "fleet's --out folder (each recording against the "
                                      "labels beside it, pooled)."),
        labels: Path = typer.Option(None, "--labels", "-l",
                                    help="Labels CSV (default: <recording>.labels.csv, the "
                                    "recording found from the result's manifest)."),
        min_recall: float = typer.Option(None, "--min-recall", metavar="SHARE",
                                         help="Exit 1 when a labelled condition's episode "
                                         "recall is below SHARE."),
        min_precision: float = typer.Option(None, "--min-precision", metavar="SHARE",
                                            help="Exit 1 when a labelled condition's frame "
                                            "precision is below SHARE."),
        max_false_alarm: float = typer.Option(None, "--max-false-alarm", metavar="SHARE",
                                              help="Exit 1 when more than SHARE of healthy "
                                              "frames are flagged."),
        json_: bool = typer.Option(False, "--json", help="Machine-readable output on stdout "
                                   "(schema docs/schemas/eval.json)."),
        markdown: bool = typer.Option(False, "--markdown", help="The table as Markdown on "
                                      "stdout (a pull-request comment, a README); a failed "
                                      "accuracy gate's reasons go to stderr."),
        quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
    ) -> int:
        """Score verdicts against labels: episode recall, frame precision/F1, false alarms.

        Examples:

          frontdiag eval results/                       # labels found via the manifest

          frontdiag eval run.mcap --min-recall 1 --max-false-alarm 0.01   # CI accuracy gate

          frontdiag eval fleet/     # a fleet's --out: every recording with labels, pooled

          frontdiag eval results/ --markdown > scores.md   # a table to paste
        """
        import pandas as pd

        from frontdiag.scoring import normalise_frames, read_frames, read_labels, score

        if json_ and markdown:
            raise ConfigError("--json and --markdown both ask for stdout: choose one")
        for value, name in ((min_recall, "--min-recall"), (min_precision, "--min-precision"),
                            (max_false_alarm, "--max-false-alarm")):
            if value is not None:
                _share(value, name)
        if not target.exists():
            raise ConfigError(f"{target}: not found")
        per_recording: list[tuple[str, Any]] = []
        left: list[str] = []
        from frontdiag.fleet import is_fleet_out

        if is_fleet_out(target):
            if labels is not None:
                raise ConfigError(f"{target} is a fleet run's folder: each recording is scored "
                                  "against its own <recording>.labels.csv",
                                  hint="drop --labels, or pass one recording's folder with it")
            from frontdiag.scoring import pool

            per_recording, left = fleet_reports(target)
            if not per_recording:
                raise ConfigError(f"{target}: no recording of this fleet has labels beside it "
                                  f"({'; '.join(left[:3])})",
                                  hint="write <recording>.labels.csv beside each recording "
                                  "(t_start_ns,t_end_ns,condition)")
            report = pool(r for _, r in per_recording)
            labels_name = f"the labels of {len(per_recording)} recordings (pooled)"
        else:
            labels_file, _ = find_labels(target, labels)
            label_table = read_labels(labels_file)  # checked before any analysis
            if _is_recording(target):
                result = _analyse(target, quiet or json_)
                frames = normalise_frames(pd.DataFrame(result.table), source=str(target))
            else:
                frames = read_frames(target)
            report = score(frames, label_table)
            labels_name = labels_file.name
        reasons = accuracy_gate(report, min_recall, min_precision, max_false_alarm)
        code = EXIT_GATE if reasons else EXIT_OK
        if json_:
            from frontdiag.json_models import EvalDoc, emit

            doc = {**report.as_dict(), "gate": {"passed": not reasons, "reasons": reasons}}
            if per_recording or left:
                doc["recordings"] = [{"recording": n, **r.as_dict()} for n, r in per_recording]
                doc["not_scored"] = left
            typer.echo(emit(EvalDoc, doc))
            return code
        if markdown:
            from frontdiag.scoring import format_markdown

            typer.echo(format_markdown(report))
            for r in reasons:
                typer.echo(f"accuracy gate failed: {r}", err=True)
            return code
        from rich import box
        from rich.markup import escape
        from rich.table import Table

        from frontdiag.cli._console import make_console

        console = make_console()
        t = Table(title=f"frontdiag eval — {escape(str(target))} against "
                  f"{escape(labels_name)}", box=box.SIMPLE_HEAD, pad_edge=False,
                  caption="found: episodes with ≥ 50 % of frames flagged · recall 95 %: "
                          "Wilson interval of found/episodes · frames: labelled frames · FA: "
                          "false alarms / healthy frames · each condition on the rows of its "
                          "sensor (registration_degeneracy: LiDAR, others: camera)")
        t.add_column("condition", no_wrap=True)
        for col in ("found", "recall 95 %", "frames", "flagged", "precision", "F1", "FA"):
            t.add_column(col, justify="right", no_wrap=True)
        for c in report.conditions:
            if per_recording and not (c.episodes or c.frames_flagged):
                continue  # a fleet scores every condition; show those that occur
            t.add_row(c.condition, f"{c.episodes_found}/{c.episodes}",
                      _ci(c.episode_recall_ci95), str(c.frames_labelled),
                      str(c.frames_flagged), _fmt(c.precision), _fmt(c.f1),
                      f"{c.false_alarms}/{c.healthy_frames}")
        console.print(t)
        console.print(f"{report.frames} frames, {report.labelled_frames} labelled, "
                      f"{report.healthy_frames} healthy; false alarms on healthy frames: "
                      f"{report.false_alarms} ({_fmt(report.false_alarm_rate, pct=True)}, "
                      f"95 % interval {_ci(report.false_alarm_rate_ci95, pct=True)})",
                      highlight=False)
        if per_recording:
            console.print("per recording (found/labelled episodes of all conditions; false "
                          "alarms / healthy frames):", highlight=False)
            for name, r in per_recording:
                found = sum(c.episodes_found for c in r.conditions)
                eps = sum(c.episodes for c in r.conditions)
                console.print(f"  {escape(name)}: {found}/{eps} episodes, "
                              f"{r.false_alarms}/{r.healthy_frames} false alarms",
                              highlight=False)
        if left:
            console.print(f"[dim]not scored: {escape('; '.join(left))}[/]", highlight=False)
        if report.unknown_predicted:
            console.print(f"ignored unknown condition names: "
                          f"{', '.join(report.unknown_predicted)}", highlight=False)
        if reasons:
            console.print("[bold red]accuracy gate failed[/]:")
            for r in reasons:
                console.print(f"  - {escape(r)}", highlight=False)
        elif any(v is not None for v in (min_recall, min_precision, max_false_alarm)):
            console.print("[green]accuracy gate passed[/]")
        return code
