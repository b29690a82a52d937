"""`frontdiag rules list | explain ID | check [DIR]`: browse and validate the rule files."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer
from typer.core import TyperGroup

from frontdiag.errors import EXIT_INPUT, EXIT_OK

RULES_OPT = typer.Option(None, "--rules", metavar="DIR",
                         help="A directory of your own rule files, added to the shipped rules "
                              "(replacing them with --no-default-rules).")
NO_DEFAULT_OPT = typer.Option(False, "--no-default-rules",
                              help="Use only the --rules directory, not the shipped rules.")
OVERRIDES_OPT = typer.Option(None, "--overrides", metavar="FILE",
                             help="TOML override file: [FD-CLU-001] threshold.entropy_alarm = 0.55")
JSON_OPT = typer.Option(False, "--json", help="Machine-readable output on stdout (schemas in "
                        "docs/schemas/).")


def load_cli_ruleset(rules_dir: Path | None, no_default: bool, overrides: Path | None = None,
                     select: list[str] | None = None, ignore: list[str] | None = None) -> Any:
    """The rules the CLI options ask for: the shipped rules plus --rules DIR, or DIR alone with
    --no-default-rules."""
    from frontdiag.errors import ConfigError
    from frontdiag.verdicts import load_ruleset

    if no_default and rules_dir is None:
        raise ConfigError("--no-default-rules needs --rules DIR (the rules to use instead)")
    if rules_dir is None or no_default:
        return load_ruleset(rules_dir, overrides, select, ignore)
    return load_ruleset(None, overrides, select, ignore, extra_dirs=[rules_dir])


class _RulesGroup(TyperGroup):
    """`frontdiag rules FD-PLN-001` is `frontdiag rules explain FD-PLN-001`: a rule ID where
    the subcommand goes is what a user who wants the rule's text types first."""

    def resolve_command(self, ctx: Any, args: list[str]) -> Any:
        from frontdiag.verdicts.model import looks_like_rule_id

        if args and args[0] not in self.commands and looks_like_rule_id(args[0]):
            args = ["explain", *args]
        return super().resolve_command(ctx, args)


def register(app: typer.Typer) -> None:
    """Add `frontdiag rules ...` to the app."""
    rules_app = typer.Typer(name="rules", no_args_is_help=True, cls=_RulesGroup,
                            help="List, explain and validate the diagnosis rules (rules/*.toml)."
                                 "\n\nExamples:\n\n  frontdiag rules list\n\n"
                                 "  frontdiag rules explain FD-PLN-001\n\n"
                                 "  frontdiag rules FD-PLN-001     # the same: explain is the "
                                 "default for a rule ID\n\n"
                                 "  frontdiag rules check my_rules/")

    @rules_app.command("list")
    def list_(
        rules_dir: Path | None = RULES_OPT,
        no_default: bool = NO_DEFAULT_OPT,
        overrides: Path | None = OVERRIDES_OPT,
        select: list[str] | None = typer.Option(None, "--select", help="Rule IDs, ID prefixes, "
                                                 "conditions or file stems to keep."),
        ignore: list[str] | None = typer.Option(None, "--ignore", help="Same, to drop."),
        as_json: bool = JSON_OPT,
    ) -> int:
        """One line per rule: ID, severity, condition, sensor, title.

        Example: frontdiag rules list --rules my_rules/ --json
        """
        rs = load_cli_ruleset(rules_dir, no_default, overrides, select, ignore)
        if as_json:
            from frontdiag.json_models import RulesListDoc, emit

            typer.echo(emit(RulesListDoc, {"sources": list(rs.sources), "rules": [
                {"id": r.id, "severity": r.severity, "condition": r.condition,
                 "sensor": r.sensor, "scope": r.scope, "title": r.title, "file": r.area}
                for r in rs.rules]}))
            return EXIT_OK
        for r in rs.rules:
            where = f"{r.sensor}{'-run' if r.scope == 'run' else ''}"
            typer.echo(f"{r.id}  {r.severity:<4}  {r.condition:<23}  {where:<10}  {r.title}")
        typer.echo(f"{len(rs.rules)} rules; `frontdiag rules explain ID` for the full text")
        return EXIT_OK

    @rules_app.command("explain")
    def explain(
        rule_id: str = typer.Argument(..., metavar="ID", help="Rule ID, e.g. FD-CLU-001."),
        rules_dir: Path | None = RULES_OPT,
        no_default: bool = NO_DEFAULT_OPT,
        overrides: Path | None = OVERRIDES_OPT,
        as_json: bool = JSON_OPT,
    ) -> int:
        """The full text of one rule, its thresholds with units and reasons.

        Example: frontdiag rules explain FD-PLN-001
        """
        from rich.markup import escape

        from frontdiag.cli._console import make_console
        from frontdiag.metrics import METRICS
        from frontdiag.verdicts import CHECKS
        from frontdiag.verdicts.operators import describe

        rule = load_cli_ruleset(rules_dir, no_default, overrides).get(rule_id.upper())
        if as_json:
            from frontdiag.json_models import RulesExplainDoc, emit

            read = [c.metric for c in rule.when]
            if rule.check:
                read += [m for m in CHECKS[rule.check].param_metrics.values() if m]
            units = {m: METRICS[m].unit for m in read if m in METRICS}
            typer.echo(emit(RulesExplainDoc, {"rule": rule.model_dump(mode="json"),
                                              "units": units}))
            return EXIT_OK
        con = make_console(soft_wrap=True, highlight=False)
        con.print(f"[bold]{rule.id}[/] {escape(rule.title)}")
        con.print(f"condition {rule.condition} · severity {rule.severity} · {rule.sensor} "
                  f"{'run' if rule.scope == 'run' else 'rows'} · {rule.area}.toml")
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
            con.print(f"[bold]persistence[/] {p.describe()}  "
                      f"[dim]{escape(p.reason)}[/]")
        return EXIT_OK

    @rules_app.command("check")
    def check(
        rules_dir: Path | None = typer.Argument(None, metavar="[DIR]",
                                                help="Rules directory (default: the shipped "
                                                "rules/)."),
        overrides: Path | None = OVERRIDES_OPT,
        with_default: bool = typer.Option(False, "--with-default-rules",
                                          help="Check DIR together with the shipped rules "
                                               "(as `analyze --rules DIR` loads them)."),
        as_json: bool = JSON_OPT,
    ) -> int:
        """Validate rule files (metrics, conditions, operators, checks); exit 2 listing problems.

        Example: frontdiag rules check my_rules/ --with-default-rules
        """
        from frontdiag.errors import FrontdiagError
        from frontdiag.verdicts import default_rules_dir, load_ruleset, validate_dir

        target = rules_dir or default_rules_dir()
        dirs = [target]
        problems = validate_dir(target)
        extra: list[Path] = []
        if with_default and rules_dir is not None:
            dirs = [default_rules_dir(), target]
            extra = [target]
        if not problems and (overrides is not None or extra):
            try:
                load_ruleset(None if extra else target, overrides, extra_dirs=extra)
            except FrontdiagError as exc:
                problems = [str(exc)]
        n = files = 0
        if not problems:
            n = len(load_ruleset(None if extra else target, extra_dirs=extra).rules)
            files = sum(len(list(Path(d).glob("*.toml"))) for d in dirs)
        if as_json:
            from frontdiag.json_models import RulesCheckDoc, emit

            typer.echo(emit(RulesCheckDoc, {"dirs": [str(d) for d in dirs],
                                            "valid": not problems, "rules": n, "files": files,
                                            "problems": problems}))
            return EXIT_INPUT if problems else EXIT_OK
        if problems:
            for p in problems:
                typer.echo(p, err=True)
            return EXIT_INPUT
        typer.echo(f"{' + '.join(str(d) for d in dirs)}: {n} rules in {files} files, all valid")
        return EXIT_OK

    app.add_typer(rules_app)
