"""The terminal summary of verdicts: conditions, episodes worst first, run findings, the gate."""

from __future__ import annotations

import shlex
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pandas as pd
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from frontdiag.report.json_ import condition_counts
from frontdiag.verdicts.engine import Verdicts
from frontdiag.verdicts.gate import GateResult

_STYLE = {"fail": "bold red", "warn": "yellow", "ok": "green"}


def reanalyse_command(recording: str, episode: pd.Series | dict[str, Any],
                      pad_s: float = 0.5, out_base: Path | str | None = None) -> str:
    """`frontdiag analyze LOG --start A --end B --out DIR` around one episode (seconds from the
    start), so that `frontdiag explain DIR` can read the re-analysis afterwards.

    The result goes to ``OUT_BASE/RULE-START`` (OUT_BASE: the run's own --out, else
    ``frontdiag-episodes``), a directory of its own, so it never replaces the run's result.
    """
    start = max(float(episode["start_t_rel_s"]) - pad_s, 0.0)
    end = float(episode["end_t_rel_s"]) + pad_s
    topic = episode.get("topic") if hasattr(episode, "get") else None
    flag = "--lidar-topic" if episode.get("sensor") == "lidar" else "--camera-topic"
    topic_part = f" {flag} {shlex.quote(str(topic))}" if topic else ""
    base = Path(out_base) if out_base is not None else Path("frontdiag-episodes")
    out = base / f"{episode.get('rule', 'episode')}-{start:.1f}s"
    return (f"frontdiag analyze {shlex.quote(recording)} --start {start:.1f} --end {end:.1f}"
            f"{topic_part} --out {shlex.quote(str(out))}")


def no_pose_line(t: pd.DataFrame) -> str | None:
    """How many rows the frontend estimated no motion on, and how many of those no rule names:
    a verdict of ok there means no condition was recognised, not that the frame was fine."""
    from frontdiag.verdicts.gate import no_pose

    lost = no_pose(t)
    if not lost.frames:
        return None
    return (f"[yellow]no pose[/] on {lost.frames} of {lost.expected} frames "
            f"({escape(lost.breakdown)}): the frontend lost track there, and "
            f"{lost.unnamed} of them carry no condition (ok there means no cause was recognised). "
            "`frontdiag explain RESULT --frame N` shows a frame's readings; "
            "--max-fraction nopose=SHARE gates on it")


def render_console_summary(console: Console, result: Verdicts, gate_result: GateResult,
                           reanalyse_cmd: Callable[[pd.Series], str] | None = None,
                           max_episodes: int = 10) -> None:
    """Print what fired, the worst episodes first (each with its re-analysis command), the gate."""
    t = result.table
    counts = t["verdict"].value_counts()
    console.print(f"[bold]{len(t)} rows[/]: " + ", ".join(
        f"[{_STYLE[k]}]{int(counts.get(k, 0))} {k}[/]" for k in ("ok", "warn", "fail")))
    line = no_pose_line(t)
    if line:
        console.print(line, highlight=False)
    cond = {k: v for k, v in condition_counts(result).items() if v["frames"]}
    if cond:
        table = Table("condition", "frames", "share", "episodes", box=None, pad_edge=False)
        for name, c in cond.items():
            table.add_row(escape(name), str(c["frames"]), f"{c['share']:.1%}", str(c["episodes"]))
        console.print(table)
    eps = result.episodes
    if not eps.empty:
        console.print(f"[bold]episodes[/] (worst first, {min(len(eps), max_episodes)} of "
                      f"{len(eps)}):")
        for _, e in eps.head(max_episodes).iterrows():
            style = _STYLE.get(str(e["severity"]), "")
            console.print(f"  [{style}]{e['severity']:>4}[/] {escape(str(e['rule']))} {escape(str(e['summary']))}",
                          highlight=False, soft_wrap=True)
            if reanalyse_cmd is not None:
                console.print(f"       [dim]{escape(reanalyse_cmd(e))}[/]", highlight=False,
                              soft_wrap=True)
    for f in result.run_findings:
        if not f.evaluated:
            mark = "[dim]not evaluated[/]"
        else:
            mark = f"[{_STYLE[f.severity]}]{f.severity}[/]" if f.fired else "[green]ok[/]"
        console.print(f"  run {escape(f.rule)} {mark}: {escape(f.message)}", highlight=False, soft_wrap=True)
    if gate_result.incomplete:
        console.print(f"[bold yellow]gate not passed[/] (exit {gate_result.exit_code}): "
                      f"{escape(gate_result.incomplete)}", highlight=False, soft_wrap=True)
        for r in gate_result.reasons:
            if r != gate_result.incomplete:
                console.print(f"  - {escape(r)}", highlight=False, soft_wrap=True)
    elif gate_result.passed:
        console.print(f"[green]gate passed[/] (fail-on {gate_result.fail_on})")
    else:
        console.print(f"[bold red]gate failed[/] (fail-on {gate_result.fail_on}, exit "
                      f"{gate_result.exit_code}):")
        for r in gate_result.reasons:
            console.print(f"  - {escape(r)}", highlight=False, soft_wrap=True)
