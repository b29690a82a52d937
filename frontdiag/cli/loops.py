"""`frontdiag loops GRAPH`: test every loop closure of a pose graph before optimisation."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import typer

from frontdiag.cli import EPILOG

HELP = """Test the loop closures of a pose graph (g2o, TORO) before optimisation.

Each loop is checked against the odometry chain between its two poses
(residual in m and deg, Mahalanobis chi-square under chain + loop
covariance), against the neighbouring loops (pairwise consistency, the
largest consistent set as in PCM), and against the map optimised from the
loops that passed. A false loop with information 100 against a 54-link chain
of stiffness 1/54 takes f = 0.99981 of its claim: a 3 m lie leaves 0.6 mm
after optimisation. The residual before optimisation shows it; this command
ranks such loops by the displacement they would cause. Edges that claim an
impossible certainty (information a million times the graph's median on an
axis, FD-LOP-005) are named with their file line; they stall every
Levenberg-Marquardt, so the audit runs with them capped.

Examples:

  frontdiag loops run.g2o

  frontdiag loops run.g2o --out audit/ --fail-on warn --junit loops.xml

  frontdiag loops intel.graph --layout toro          # TORO information order

  frontdiag loops M3500.g2o --sqrt-info              # files storing sqrt(information)

  frontdiag loops run.g2o --explain 17               # the stiffness arithmetic of loop 17

  frontdiag loops run.g2o --explain 58-4             # the loop between vertices 58 and 4

  frontdiag loops run.g2o --optimize                 # solve with and without flagged loops

  frontdiag loops run.g2o --optimize --out audit/    # audit/loops.html: the fold, side by side

  frontdiag loops run.g2o --calibrate                # covariances scaled by the short cycles

Exit codes: 0 nothing at or above --fail-on, 1 a loop at or above --fail-on,
2 bad input / usage / config, 3 internal error."""


def register(app: typer.Typer) -> None:
    app.command("loops", help=HELP, epilog=EPILOG, no_args_is_help=True)(loops_cmd)


def loops_cmd(
    graph_file: Path = typer.Argument(..., metavar="GRAPH", show_default=False,
                                      help="Pose graph: .g2o (SE2 / SE3:QUAT) or TORO .graph."),
    out: Path | None = typer.Option(None, "--out", "-o",
                                    help="Result directory: loops.parquet, loops.html (the map with "
                                         "every loop in its verdict's colour), manifest.json."),
    sqrt_info: bool = typer.Option(False, "--sqrt-info",
                                   help="The file stores the square root of the information."),
    layout: str = typer.Option("auto", "--layout", metavar="[auto|g2o|toro]",
                               help="2D information order: auto (by tag), g2o or toro."),
    odom_max_gap: int = typer.Option(1, "--odom-max-gap",
                                     help="Edges spanning at most this many vertices in id "
                                          "order are odometry (not audited); the chain joins "
                                          "vertices adjacent in id order."),
    rules_file: Path | None = typer.Option(None, "--rules",
                                           help="Loop rules TOML instead of rules/loops/loops.toml."),
    explain: str | None = typer.Option(None, "--explain", metavar="ID",
                                       help="Explain one loop: its number or I-J vertex ids."),
    no_map: bool = typer.Option(False, "--no-map",
                                help="Skip the re-test against the optimised map (FD-LOP-003)."),
    calibrate: bool = typer.Option(False, "--calibrate",
                                   help="Scale the file's covariances by what the short cycles "
                                        "of neighbouring loops show (when the file's "
                                        "information is known to be off by a factor)."),
    optimize: bool = typer.Option(False, "--optimize",
                                  help="Solve with and without the flagged loops; report each "
                                       "flagged loop's residual before/after and the ATE."),
    fail_on: str = typer.Option("fail", "--fail-on", metavar="[warn|fail|never]",
                                help="Exit 1 when a loop of this severity exists: warn, fail, "
                                     "never."),
    junit: Path | None = typer.Option(None, "--junit", help="Write JUnit XML (one case per rule)."),
    as_json: bool = typer.Option(False, "--json", help="Print a machine-readable summary."),
    top: int = typer.Option(10, "--top", help="Flagged loops listed in the summary."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress or table."),
    force: bool = typer.Option(False, "--force",
                               help="Replace an earlier result in --out (refused without it)."),
) -> int:
    from frontdiag.cli._console import make_console
    from frontdiag.errors import ConfigError
    from frontdiag.loops import audit, read_graph, summary
    from frontdiag.loops.report import gate_loops, render_loops, write_loops_junit
    from frontdiag.loops.rules import load_loop_rules
    from frontdiag.output import (
        check_output_file,
        guarded_write,
        prepare_out_dir,
        refuse_overwrite,
        write_manifest,
    )

    if fail_on not in ("warn", "fail", "never"):
        raise ConfigError(f"--fail-on {fail_on!r}: choose warn, fail or never")
    if odom_max_gap < 1:
        raise ConfigError(f"--odom-max-gap {odom_max_gap}: need at least 1")
    if out is not None:
        refuse_overwrite(out, force)  # an earlier audit's, or an analysis's manifest.json
    out_dir = prepare_out_dir(out, [graph_file]) if out is not None else None
    if junit is not None:
        check_output_file(junit, "--junit", [graph_file], what="graph")
    rules = load_loop_rules(rules_file)
    err = make_console(stderr=True)
    show = not quiet and not as_json
    graph = read_graph(graph_file, sqrt_info=sqrt_info, layout=layout)
    with err.status("auditing loops", spinner="dots") if show else _Null() as status:
        def progress(msg: str) -> None:
            if status is not None:
                status.update(msg)

        result = audit(graph, rules, odom_max_gap=odom_max_gap, verify=not no_map,
                       calibrate=calibrate, progress=progress)
    if explain is not None:
        from frontdiag.loops.explain import explain_loop, pick_loop

        typer.echo(explain_loop(result, pick_loop(result, explain)))
        return 0
    opt: dict[str, Any] | None = None
    solved: dict[str, Any] = {}
    if optimize:
        from frontdiag.loops.optimize import compare_solutions

        if show:
            err.print("optimising with and without the flagged loops")
        opt = compare_solutions(result, solved)
    gate_result = gate_loops(result, fail_on)  # type: ignore[arg-type]
    summ = summary(result, top=top)
    if out_dir is not None:
        from frontdiag.loops.report import write_loops_table

        write_loops_table(out_dir, result)
        from frontdiag.loops.figure import write_loops_html

        write_loops_html(out_dir, result, summ, solved or None)
        write_manifest(out_dir, {"command": "loops", "input": {"path": str(graph_file)},
                                 "options": {"sqrt_info": sqrt_info, "layout": layout,
                                             "odom_max_gap": odom_max_gap,
                                             "map_test": not no_map,
                                             "calibrate": calibrate},
                                 "rules": rules.model_dump(mode="json"),
                                 "summary": summ, "optimize": opt})
    if junit is not None:
        guarded_write(junit, lambda: write_loops_junit(junit, result, gate_result))
    if as_json:
        from frontdiag.report.json_ import plain

        payload = {**summ, "gate": {"exit_code": gate_result.exit_code,
                                    "passed": gate_result.passed, "fail_on": fail_on,
                                    "reasons": gate_result.reasons}}
        if opt is not None:
            payload["optimize"] = opt
        typer.echo(json.dumps(plain(payload), indent=2, default=str))
    elif not quiet:
        render_loops(make_console(), result, summ, gate_result, out_dir, opt, top,
                     rerun=_rerun(graph_file, sqrt_info=sqrt_info, layout=layout,
                                  odom_max_gap=odom_max_gap, rules_file=rules_file,
                                  no_map=no_map, calibrate=calibrate))
    return gate_result.exit_code


def _rerun(graph_file: Path, *, sqrt_info: bool, layout: str, odom_max_gap: int,
           rules_file: Path | None, no_map: bool, calibrate: bool) -> str:
    """The command that reads and audits the graph as this run did (the options that change
    the verdicts), quoted for the shell: what --explain is added to."""
    import shlex

    args = ["frontdiag", "loops", str(graph_file)]
    if sqrt_info:
        args.append("--sqrt-info")
    if layout != "auto":
        args += ["--layout", layout]
    if odom_max_gap != 1:
        args += ["--odom-max-gap", str(odom_max_gap)]
    if rules_file is not None:
        args += ["--rules", str(rules_file)]
    if no_map:
        args.append("--no-map")
    if calibrate:
        args.append("--calibrate")
    return shlex.join(args)


class _Null:
    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> None:
        return None
