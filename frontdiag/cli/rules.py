"""`frontdiag rules list | explain ID | check [DIR]`: browse and validate the rule files."""

from __future__ import annotations

from pathlib import Path

import typer

from frontdiag.errors import EXIT_INPUT, EXIT_OK

RULES_OPT = typer.Option(None, "--rules", metavar="DIR",
                         help="Rules directory (default: the shipped rules/).")
OVERRIDES_OPT = typer.Option(None, "--overrides", metavar="FILE",
                             help="TOML override file: [FD-CLU-001] threshold.entropy_alarm = 0.55")


def register(app: typer.Typer) -> None:
    """Add `frontdiag rules ...` to the app."""
    rules_app = typer.Typer(name="rules", no_args_is_help=True,
                            help="List, explain and validate the diagnosis rules (rules/*.toml).")

    @rules_app.command("list")
    def list_(
        rules_dir: Path | None = RULES_OPT,
        overrides: Path | None = OVERRIDES_OPT,
        select: list[str] | None = typer.Option(None, "--select", help="Rule IDs, ID prefixes, "
                                                 "conditions or file stems to keep."),
        ignore: list[str] | None = typer.Option(None, "--ignore", help="Same, to drop."),
    ) -> int:
        """One line per rule: ID, severity, condition, sensor, title."""
        from frontdiag.verdicts import load_ruleset

        rs = load_ruleset(rules_dir, overrides, select, ignore)
        for r in rs.rules:
            where = f"{r.sensor}{'-run' if r.scope == 'run' else ''}"
            typer.echo(f"{r.id}  {r.severity:<4}  {r.condition:<23}  {where:<10}  {r.title}")
        typer.echo(f"{len(rs.rules)} rules; `frontdiag rules explain ID` for the full text")
        return EXIT_OK

    @rules_app.command("explain")
    def explain(
        rule_id: str = typer.Argument(..., metavar="ID", help="Rule ID, e.g. FD-CLU-001."),
        rules_dir: Path | None = RULES_OPT,
        overrides: Path | None = OVERRIDES_OPT,
    ) -> int:
        """The full text of one rule, its thresholds with units and reasons."""
        from rich.markup import escape

        from frontdiag.cli._console import make_console
        from frontdiag.metrics import METRICS
        from frontdiag.verdicts import CHECKS, load_ruleset
        from frontdiag.verdicts.operators import describe

        rule = load_ruleset(rules_dir, overrides).get(rule_id.upper())
        con = make_console(soft_wrap=True, highlight=False)
        con.print(f"[bold]{rule.id}[/] {escape(rule.title)}")
        con.print(f"condition {rule.condition} · severity {rule.severity} · {rule.sensor} "
                  f"{'run' if rule.scope == 'run' else 'rows'} · rules/{rule.area}.toml")
        con.print(f"  [dim]severity: {escape(rule.severity_reason)}[/]")
        t = rule.text
        for label, text in (("symptom", t.symptom), ("reveals", t.reveals),
                            ("healthy", t.healthy), ("broken", t.broken),
                            ("distinguish", t.distinguish), ("fix", t.fix),
                            ("wrong fix", t.wrong_fix), ("source", t.source)):
            con.print(f"[bold]{label:>11}[/] {escape(text)}")
        con.print("[bold]thresholds[/] (override: [" + rule.id + "] threshold.NAME = VALUE)")
        for c in rule.when:
            unit = METRICS[c.metric].unit if c.metric in METRICS else ""
            test = describe(c.metric, c.op, c.value, use_abs=c.abs)
            out = f", rules out {c.rules_out}" if c.rules_out else ""
            con.print(f"  {c.name}: {escape(test)} {unit}".rstrip() + f"  [dim]{escape(c.reason)}"
                      f"{out}[/]")
        if rule.check:
            chk = CHECKS[rule.check]
            con.print(f"  check {chk.name}: {escape(chk.summary)}")
            for name, param in rule.params.items():
                metric = chk.param_metrics.get(name, "")
                unit = METRICS[metric].unit if metric in METRICS else ""
                on = f" ({metric}, {unit})" if metric and unit else f" ({metric})" if metric \
                    else ""
                con.print(f"  {name} = {param.value}{on}  [dim]{escape(param.reason)}[/]")
        if rule.persistence:
            p = rule.persistence
            con.print(f"[bold]persistence[/] {p.k} of {p.n} consecutive rows  "
                      f"[dim]{escape(p.reason)}[/]")
        return EXIT_OK

    @rules_app.command("check")
    def check(
        rules_dir: Path | None = typer.Argument(None, metavar="[DIR]",
                                                help="Rules directory (default: the shipped "
                                                "rules/)."),
        overrides: Path | None = OVERRIDES_OPT,
    ) -> int:
        """Validate rule files (metrics, conditions, operators, checks); exit 2 listing problems."""
        from frontdiag.errors import FrontdiagError
        from frontdiag.verdicts import default_rules_dir, load_ruleset, validate_dir

        target = rules_dir or default_rules_dir()
        problems = validate_dir(target)
        if not problems and overrides is not None:
            try:
                load_ruleset(target, overrides)
            except FrontdiagError as exc:
                problems = [str(exc)]
        if problems:
            for p in problems:
                typer.echo(p, err=True)
            return EXIT_INPUT
        n = len(load_ruleset(target).rules)
        files = len(list(Path(target).glob("*.toml")))
        typer.echo(f"{target}: {n} rules in {files} files, all valid")
        return EXIT_OK

    app.add_typer(rules_app)
