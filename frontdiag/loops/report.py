"""Renderers of a loop audit: loops.parquet, the console summary, JUnit XML, the gate.

The gate is the one of ``analyze`` (:class:`~frontdiag.verdicts.gate.GateResult`, severities
ranked by ``SEVERITY_RANK``): exit 1 when a loop's verdict is at or above --fail-on.
"""

from __future__ import annotations

import shlex
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import pandas as pd
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from frontdiag.errors import EXIT_GATE, EXIT_OK
from frontdiag.loops.audit import TABLE_COLUMNS, LoopAudit
from frontdiag.verdicts.gate import FailOn, GateResult
from frontdiag.verdicts.model import SEVERITY_RANK

LOOPS_FILE = "loops.parquet"
_STYLE = {"fail": "bold red", "warn": "yellow", "ok": "green"}


def gate_loops(result: LoopAudit, fail_on: FailOn = "fail") -> GateResult:
    """Exit 1 when a loop's verdict is at or above ``fail_on`` (never: always 0)."""
    if fail_on == "never":
        return GateResult(EXIT_OK, [], fail_on, [])
    t = result.table
    rank = t["verdict"].map(SEVERITY_RANK).to_numpy()
    hit = t[rank >= SEVERITY_RANK[fail_on]]
    reasons: list[str] = []
    failed: list[str] = []
    for r in result.rules.rule:
        mine = hit[hit["rule"] == r.id]
        if len(mine):
            failed.append(r.id)
            worst = mine.sort_values("displacement_m", ascending=False, na_position="last")
            ex = worst.iloc[0]
            reasons.append(f"{r.id} {r.title}: {len(mine)} loop(s), e.g. loop {int(ex['loop'])} "
                           f"({int(ex['i'])}->{int(ex['j'])})")
    return GateResult(EXIT_GATE if reasons else EXIT_OK, reasons, fail_on, failed)


def write_loops_table(out_dir: Path, result: LoopAudit) -> Path:
    """loops.parquet: the contract columns first, then the supporting statistics."""
    t = result.table
    rest = [c for c in t.columns if c not in TABLE_COLUMNS]
    path = Path(out_dir) / LOOPS_FILE
    t[TABLE_COLUMNS + rest].to_parquet(path, index=False)
    return path


def _fmt(v: Any, spec: str) -> str:
    try:
        if pd.isna(v):
            return "—"
    except (TypeError, ValueError):
        pass
    return format(v, spec)


def _n(count: int, noun: str) -> str:
    return f"{count} {noun}{'' if count == 1 else 's'}"


def render_loops(console: Console, result: LoopAudit, summ: dict[str, Any], gate: GateResult,
                 out_dir: Path | None, opt: dict[str, Any] | None, top: int,
                 rerun: str | None = None) -> None:
    """The console summary. ``rerun``: the command line that reads the graph as this run did
    (its path quoted for the shell, the reading options), for the --explain hint."""
    g = result.graph
    v = summ["verdicts"]
    console.print(f"[bold]frontdiag loops[/] {escape(g.path)}  [dim]SE({g.dim}), "
                  f"{g.n_vertices} poses, {int(result.odometry.sum())} odometry, "
                  f"{_n(len(result.table), 'loop')}; {_n(result.n_pairs, 'pair')} tested, "
                  f"{_n(result.n_conflicts, 'conflict')}; {summ['timings_s'].get('total_s', 0):.2f} s[/]")
    console.print(", ".join(f"[{_STYLE[k]}]{v[k]} {k}[/]" for k in ("ok", "warn", "fail")))
    for r in result.rules.rule:
        n = summ["rules"].get(r.id, 0)
        if n:
            console.print(f"  {r.id} [{_STYLE[r.severity]}]{r.severity}[/] {n:>5}  "
                          f"{escape(r.title)}", highlight=False)
    over = summ.get("overconfident_edges") or {}
    if over.get("odometry"):  # not loops, so in no verdict count above: said here
        console.print(f"  {result.rules.by_statistic('stiffness').id} [yellow]note[/] "
                      f"{over['odometry']:>5}  odometry edge(s) claim an impossible certainty"
                      + (" (capped for the audit; see the note below)" if over["capped"]
                         else " (see the note below)"), highlight=False)
    worst = summ["worst"]
    if worst:
        t = Table(title=f"loops that would move the map most if believed ({len(worst)} shown)",
                  title_justify="left", show_edge=False, header_style="bold")
        for c in ("loop", "i→j", "residual m", "deg", "χ²", "f", "moves map m", "verdict"):
            t.add_column(c, justify="right" if c not in ("verdict",) else "left")
        for w in worst:
            t.add_row(str(w["loop"]), f"{w['i']}→{w['j']}", _fmt(w["residual_m"], ".2f"),
                      _fmt(w["residual_deg"], ".1f"), _fmt(w["chi2"], ".3g"),
                      _fmt(w["f"], ".5f"), _fmt(w["displacement_m"], ".2f"),
                      f"[{_STYLE[w['verdict']]}]{w['verdict']}[/] {w['rule']}")
        console.print(t)
        cmd = rerun or f"frontdiag loops {shlex.quote(g.path)}"
        console.print(f"[dim]{escape(cmd)} --explain {worst[0]['loop']}   # the stiffness "
                      "arithmetic of the worst loop[/]", highlight=False, soft_wrap=True)
    if opt is not None:
        _render_opt(console, opt)
    for note in summ["notes"]:
        console.print(f"[yellow]note:[/] {escape(note)}", highlight=False)
    if out_dir is not None:
        console.print("[green]wrote[/] " + ", ".join(
            escape(str(out_dir / name)) for name in (LOOPS_FILE, "loops.html", "manifest.json")),
            highlight=False, soft_wrap=True)
    if gate.passed:
        console.print(f"[green]gate passed[/] (fail-on {gate.fail_on})")
    else:
        console.print(f"[bold red]gate failed[/] (fail-on {gate.fail_on}, exit {gate.exit_code}):")
        for line in gate.reasons:
            console.print(f"  - {escape(line)}", highlight=False, soft_wrap=True)


def _render_opt(console: Console, opt: dict[str, Any]) -> None:
    console.print(f"[bold]optimised[/] ({escape(str(opt['solver']))}): map change between the "
                  f"solution with all loops and without the flagged ones: ATE "
                  f"{opt['ate_m']:.3f} m (max {opt['max_displacement_m']:.3f} m)")
    rows = opt["flagged"][:10]
    if rows:
        t = Table(show_edge=False, header_style="bold")
        for c in ("loop", "i→j", "before opt m", "after opt (all loops) m", "vs clean map m"):
            t.add_column(c, justify="right")
        for r in rows:
            t.add_row(str(r["loop"]), f"{r['i']}→{r['j']}", f"{r['residual_before_m']:.3f}",
                      f"{r['residual_after_m']:.4f}", f"{r['residual_clean_m']:.3f}")
        console.print(t)
        console.print("[dim]after optimisation with the loop included its residual is small: "
                      "the map moved instead[/]")


def write_loops_junit(path: Path, result: LoopAudit, gate: GateResult) -> Path:
    """One test case per loop rule, failing when loops at or above --fail-on fired it."""
    t = result.table
    suite = ET.Element("testsuite", name="frontdiag.loops")
    failures = 0
    for r in result.rules.rule:
        mine = t[t["rule"] == r.id]
        case = ET.SubElement(suite, "testcase", classname="frontdiag.loops",
                             name=f"{r.id}: {r.title}")
        lines = [f"loop {lo} {i}->{j} [{v}]: {why}" for lo, i, j, v, why in
                 zip(mine["loop"], mine["i"], mine["j"], mine["verdict"], mine["reason"],
                     strict=True)]
        if r.id in gate.failed_rules:
            failures += 1
            fail = ET.SubElement(case, "failure", message=f"{len(mine)} loop(s)", type=r.severity)
            fail.text = "\n".join(lines) + f"\n\nfix: {r.text.fix}\nwrong fix: {r.text.wrong_fix}"
        elif lines:
            ET.SubElement(case, "system-out").text = "\n".join(lines)
    n = len(result.rules.rule)
    suite.set("tests", str(n))
    suite.set("failures", str(failures))
    suite.set("errors", "0")
    root = ET.Element("testsuites", tests=str(n), failures=str(failures), errors="0")
    root.append(suite)
    tree = ET.ElementTree(root)
    ET.indent(tree)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tree.write(path, encoding="utf-8", xml_declaration=True)
    return path
