"""`frontdiag explain RESULT_DIR --frame N | --t SECONDS`: one frame against every rule."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from frontdiag.errors import EXIT_OK


def _load_rules(result_dir: Path, rules_dir: Path | None, overrides: Path | None) -> Any:
    """--rules/--overrides, else the snapshot the run wrote, else the manifest's dir, else default."""
    import json

    from frontdiag.report.files import RULES_SNAPSHOT
    from frontdiag.verdicts import Ruleset, load_ruleset

    if rules_dir is not None or overrides is not None:
        return load_ruleset(rules_dir, overrides)
    snap = result_dir / RULES_SNAPSHOT
    if snap.is_file():
        try:
            return Ruleset.from_dict(json.loads(snap.read_text()))
        except ValueError:
            pass
    try:
        manifest = json.loads((result_dir / "manifest.json").read_text())
    except (OSError, ValueError):
        manifest = {}
    rules = manifest.get("rules") if isinstance(manifest, dict) else None
    if isinstance(rules, dict) and rules.get("dir") and Path(rules["dir"]).is_dir():
        ov = rules.get("overrides")
        return load_ruleset(Path(rules["dir"]), Path(ov) if ov else None)
    if isinstance(rules, str) and Path(rules).is_dir():
        return load_ruleset(Path(rules))
    return load_ruleset()


def _pick_row(table: Any, frame: int | None, t: float | None, topic: str | None) -> int:
    import numpy as np

    from frontdiag.errors import ConfigError, TopicError
    from frontdiag.verdicts.engine import relative_time

    if (frame is None) == (t is None):
        raise ConfigError("give exactly one of --frame N or --t SECONDS")
    cand = np.arange(len(table))
    if topic is not None:
        if "topic" not in table.columns or not (table["topic"] == topic).any():
            raise TopicError(f"no rows for topic {topic!r} in the result")
        cand = cand[(table["topic"] == topic).to_numpy()]
    if frame is not None:
        cand = cand[(table["frame"].iloc[cand] == frame).to_numpy()]
        if cand.size == 0:
            raise ConfigError(f"no row with frame {frame}"
                              + (f" on {topic}" if topic else ""))
    else:
        rel = relative_time(table)[cand]
        if np.all(np.isnan(rel)):
            raise ConfigError("the table has no t_rel_s or t_ns to look up --t")
        best = np.nanmin(np.abs(rel - t))
        cand = cand[np.abs(rel - t) == best]
    if cand.size > 1 and "topic" in table.columns:
        topics = sorted(set(table["topic"].iloc[cand].astype(str)))
        if len(topics) > 1:
            raise TopicError("several topics have this row; choose one with "
                             + " or ".join(f"--topic {x}" for x in topics), candidates=topics)
    return int(cand[0])


def _fmt(v: Any) -> str:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return str(v)
    if f != f:
        return "n/a"
    return f"{f:.4g}"


def register(app: typer.Typer) -> None:
    """Add `frontdiag explain` to the app."""

    @app.command("explain")
    def explain(
        result_dir: Path = typer.Argument(..., metavar="RESULT_DIR",
                                          help="The --out directory of `frontdiag analyze`."),
        frame: int | None = typer.Option(None, "--frame", help="Frame index (the table's "
                                         "`frame` column)."),
        t: float | None = typer.Option(None, "--t", metavar="SECONDS",
                                       help="Seconds from the recording start (nearest row)."),
        topic: str | None = typer.Option(None, "--topic", help="Topic, when several have the "
                                         "row."),
        rules_dir: Path | None = typer.Option(None, "--rules", metavar="DIR",
                                              help="Rules directory (default: the one the run "
                                              "used, else the shipped rules/)."),
        overrides: Path | None = typer.Option(None, "--overrides", metavar="FILE",
                                              help="Threshold override file."),
    ) -> int:
        """Show one frame: every metric against its thresholds, the rules that fired and the
        look-alikes each value rules out.

        Example: frontdiag explain results/ --frame 412
        """
        import pandas as pd
        from rich.markup import escape

        from frontdiag.cli._console import make_console
        from frontdiag.errors import ConfigError
        from frontdiag.metrics import METRICS
        from frontdiag.verdicts import CHECKS, evaluate
        from frontdiag.verdicts.explain import explain_row

        path = result_dir / "frames.parquet" if result_dir.is_dir() else result_dir
        if not path.is_file():
            raise ConfigError(f"{result_dir}: no frames.parquet",
                              hint="pass the --out directory of `frontdiag analyze`")
        try:
            table = pd.read_parquet(path)
        except Exception as exc:  # pyarrow raises several unrelated types for a bad file
            raise ConfigError(f"{path}: cannot read the table ({exc})") from None
        ruleset = _load_rules(result_dir if result_dir.is_dir() else path.parent,
                              rules_dir, overrides)
        result = evaluate(table, ruleset)
        pos = _pick_row(result.table, frame, t, topic)
        row = result.table.iloc[pos]
        con = make_console(soft_wrap=True, highlight=False)
        conds = ", ".join(row["conditions"]) or "none"
        con.print(f"[bold]frame {row.get('frame')}[/] {row.get('sensor', '')} "
                  f"{row.get('topic', '')} t={_fmt(row.get('t_rel_s'))} s status "
                  f"{row.get('status', '')}: verdict [bold]{row['verdict']}[/], conditions {conds}")
        expl = explain_row(result, pos)
        expl.sort(key=lambda e: (not e.fired, not e.raw, e.rule.id))
        thresholds: dict[str, list[str]] = {}
        for e in expl:
            r = e.rule
            state = ("[bold red]FIRED[/]" if e.fired else
                     "[yellow]holds here, not persistent[/]" if e.raw else "[green]clear[/]")
            con.print(f"\n[bold]{r.id}[/] {r.condition} {escape(f'[{r.severity}]')} {state}: "
                      f"{escape(r.title)}")
            for c in e.clauses:
                mark = "✔" if c.holds else "✘"
                out = ""
                if c.rules_out and c.holds:
                    out = f"  → rules out {c.rules_out}"
                con.print(f"  {mark} {c.metric} = {_fmt(c.value)} {c.unit}; test "
                          f"{escape(c.test)}{out}")
                thresholds.setdefault(c.metric, []).append(f"{r.id} {c.test}")
            for line in e.check_lines:
                con.print(f"  · {escape(line)}")
            if r.check:
                for name, metric in CHECKS[r.check].param_metrics.items():
                    if name in r.params:
                        thresholds.setdefault(metric, []).append(
                            f"{r.id} {name}={r.params[name].value}")
            if r.persistence and e.raw and not e.fired:
                con.print(f"  · needs {r.persistence.k} of {r.persistence.n} consecutive rows")
            if e.fired:
                con.print(f"  [dim]fix: {escape(r.text.fix)}[/]")
        sensor = str(row.get("sensor", "camera"))
        con.print("\n[bold]metrics[/] (value · unit · thresholds that read it)")
        for name, m in METRICS.items():
            if m.sensor not in ("any", sensor) or name not in result.table.columns:
                continue
            if name in ("frame", "sensor", "topic", "status", "conditions", "rules", "verdict",
                        "t_ns"):
                continue
            th = "; ".join(thresholds.get(name, []))
            con.print(f"  {name:<26} {_fmt(row[name]):>10} {m.unit:<10} [dim]{escape(th)}[/]")
        return EXIT_OK
