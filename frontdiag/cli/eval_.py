"""`frontdiag eval`: score per-frame verdicts against labelled intervals."""

from __future__ import annotations

from pathlib import Path

import typer

from frontdiag.errors import ConfigError

_RECORDING_SUFFIXES = (".mcap", ".bag", ".db3")


def _is_recording(p: Path) -> bool:
    if p.is_file():
        return p.suffix in _RECORDING_SUFFIXES
    return p.is_dir() and (p / "metadata.yaml").is_file()


def _fmt(v: float | None, pct: bool = False) -> str:
    if v is None:
        return "—"
    return f"{100 * v:.1f} %" if pct else f"{v:.2f}"


def register(app: typer.Typer) -> None:
    """Add the command to the app."""

    @app.command("eval", epilog="Scoring rules: docs/simulate.md#scoring.")
    def eval_cmd(
        target: Path = typer.Argument(..., help="An `analyze --out` directory, a frames "
                                      ".parquet/.csv, or a recording (analysed first)."),
        labels: Path = typer.Option(None, "--labels", "-l",
                                    help="Labels CSV (default: <recording>.labels.csv)."),
        json_: bool = typer.Option(False, "--json", help="Machine-readable output on stdout."),
    ) -> int:
        """Score verdicts against labels: episode recall, frame precision/F1, false alarms.

        Example: frontdiag eval results/ --labels sample_logs/healthy_loop.mcap.labels.csv
        """
        import pandas as pd

        from frontdiag.scoring import normalise_frames, read_frames, read_labels, score
        from frontdiag.sim.run import labels_path_for

        if not target.exists():
            raise ConfigError(f"{target}: not found")
        if _is_recording(target):
            if labels is None:
                labels = labels_path_for(target)
            try:
                from frontdiag.api import analyze
            except ImportError as exc:
                raise ConfigError("scoring a recording needs `frontdiag analyze`, which this "
                                  "installation does not provide",
                                  hint="run `frontdiag analyze REC --out DIR` and eval DIR") from exc
            table = analyze(target)
            frames = normalise_frames(pd.DataFrame(table), source=str(target))
        else:
            frames = read_frames(target)
        if labels is None:
            raise ConfigError("missing --labels", hint="the simulator writes <recording>."
                              "labels.csv beside each recording")
        report = score(frames, read_labels(labels))
        if json_:
            import json

            typer.echo(json.dumps(report.as_dict(), indent=2))
            return 0
        from rich import box
        from rich.table import Table

        from frontdiag.cli._console import make_console

        console = make_console()
        t = Table(title=f"frontdiag eval — {target}", box=box.SIMPLE_HEAD, pad_edge=False,
                  caption="found: episodes with ≥ 50 % of frames flagged · frames: labelled "
                          "frames · FA: false alarms / healthy frames · each condition on the "
                          "rows of its sensor (registration_degeneracy: LiDAR, others: camera)")
        t.add_column("condition", no_wrap=True)
        for col in ("found", "frames", "flagged", "precision", "F1", "FA"):
            t.add_column(col, justify="right", no_wrap=True)
        for c in report.conditions:
            t.add_row(c.condition, f"{c.episodes_found}/{c.episodes}", str(c.frames_labelled),
                      str(c.frames_flagged), _fmt(c.precision), _fmt(c.f1),
                      f"{c.false_alarms}/{c.healthy_frames}")
        console.print(t)
        console.print(f"{report.frames} frames, {report.labelled_frames} labelled, "
                      f"{report.healthy_frames} healthy; false alarms on healthy frames: "
                      f"{report.false_alarms} ({_fmt(report.false_alarm_rate, pct=True)})",
                      highlight=False)
        if report.unknown_predicted:
            console.print(f"ignored unknown condition names: "
                          f"{', '.join(report.unknown_predicted)}", highlight=False)
        return 0
