"""`frontdiag explain RESULT_DIR --frame N | --time SECONDS`: one frame against every rule."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from frontdiag.errors import EXIT_OK

STATUS_MEANING = {
    "ok": "the frontend evaluated this frame",
    "first_frame": "the first frame: nothing to match it against yet, so most metrics are empty",
    "first_scan": "the first scan: nothing to register it against yet",
    "after_gap": "the first row after a gap in the recording: the frontend started afresh",
    "size_changed": "the first row after the image size changed: the frontend started afresh, "
                    "with K fitted to the new size (see the run's notes)",
    "no_features": "no keypoints were detected, so nothing else could be computed",
    "too_few_matches": "too few matches with the reference to estimate geometry",
    "no_intrinsics": "no camera intrinsics, so E, parallax and pose information were skipped",
    "essential_failed": "the essential-matrix estimate failed on this frame",
    "too_few_points": "too few points in the scan to register it",
    "low_overlap": "too small a share of the scan's points matched the map to trust the "
                   "registration",
}
"""What each frontend status says about a row (the verdict is the rules' finding, separately)."""


def status_meaning(status: str) -> str:
    if status.startswith("error"):
        return "the frontend raised an error on this row; its metrics are empty"
    return STATUS_MEANING.get(status, "see the status column in docs")


def matching_facts(row: Any, gap_s: float | None) -> str:
    """What matching did on a camera row that got no pose: keypoints, the ratio test's refusals
    (with two close candidates, or with none close), the matches kept, and the time since the
    previous frame; facts only, the rules name causes."""
    def num(name: str) -> float:
        try:
            return float(row.get(name))
        except (TypeError, ValueError):
            return float("nan")

    n, rej, amb, kept = (num(c) for c in ("n_keypoints", "ratio_reject_rate",
                                          "ratio_ambiguous_rate", "n_matches"))
    parts = []
    if n == n:
        parts.append(f"{n:.0f} keypoints")
    if rej == rej:
        close = (f" ({amb:.0%} with two close candidates, {rej - amb:.0%} with none close)"
                 if amb == amb else "")
        parts.append(f"the ratio test refused {rej:.0%}{close}")
    if kept == kept:
        parts.append(f"{kept:.0f} matches kept")
    copies = num("in_frame_twin_rate")
    if copies == copies:
        parts.append(f"{copies:.0%} of the keypoints have a copy in the same view")
    if gap_s is not None and gap_s == gap_s:
        parts.append(f"the previous frame is {gap_s:.3g} s earlier")
    return "; ".join(parts)


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


def _frame_range(table: Any, topic: str | None) -> str:
    rows = table if topic is None or "topic" not in table.columns else \
        table[table["topic"] == topic]
    parts = []
    for top, g in rows.groupby("topic", sort=True) if "topic" in rows.columns else [("", rows)]:
        frames = g["frame"]
        parts.append(f"{top + ': ' if top else ''}frames {int(frames.min())}-{int(frames.max())} "
                     f"({len(frames)} rows)")
    return "; ".join(parts)


def _pick_row(table: Any, frame: int | None, t: float | None, topic: str | None
              ) -> tuple[int, list[str]]:
    """The row to explain, and the other topics that have a row of this frame (or time).

    Frame numbers count per topic, so a camera + LiDAR run has a frame 10 on each. With no
    --topic, the camera's row is taken where exactly one camera topic has it (the others are
    named for --topic); two cameras (a stereo rig) are ambiguous and must be chosen."""
    import numpy as np

    from frontdiag.errors import ConfigError, TopicError
    from frontdiag.verdicts.engine import relative_time

    if (frame is None) == (t is None):
        raise ConfigError("give exactly one of a frame (FRAME or --frame N) or --time SECONDS",
                          hint=f"this result holds {_frame_range(table, topic)}")
    cand = np.arange(len(table))
    if topic is not None:
        if "topic" not in table.columns or not (table["topic"] == topic).any():
            raise TopicError(f"no rows for topic {topic!r} in the result")
        cand = cand[(table["topic"] == topic).to_numpy()]
    if frame is not None:
        cand = cand[(table["frame"].iloc[cand] == frame).to_numpy()]
        if cand.size == 0:
            raise ConfigError(f"no row with frame {frame}" + (f" on {topic}" if topic else ""),
                              hint=f"this result holds {_frame_range(table, topic)} (frames "
                              "skipped by --stride or outside --start/--end have no row)")
    else:
        rel = relative_time(table)[cand]
        if np.all(np.isnan(rel)):
            raise ConfigError("the table has no t_rel_s or t_ns to look up --time")
        best = np.nanmin(np.abs(rel - t))
        cand = cand[np.abs(rel - t) == best]
    if cand.size > 1 and "topic" in table.columns:
        names = table["topic"].iloc[cand].astype(str).to_numpy()
        topics = sorted(set(names))
        if len(topics) > 1:
            sensors = table["sensor"].iloc[cand].astype(str).to_numpy() \
                if "sensor" in table.columns else np.full(cand.size, "")
            cams = sorted(set(names[sensors == "camera"]))
            if len(cams) != 1:
                raise TopicError("several topics have this row; choose one with "
                                 + " or ".join(f"--topic {x}" for x in topics),
                                 candidates=topics)
            return int(cand[names == cams[0]][0]), [x for x in topics if x != cams[0]]
    return int(cand[0]), []


def _fmt(v: Any) -> str:
    if isinstance(v, list | tuple):
        return "(" + ", ".join(_fmt(x) for x in v) + ")"
    try:
        f = float(v)
    except (TypeError, ValueError):
        return str(v)
    if f != f:
        return "n/a"
    text = f"{f:.4g}"
    return text[1:] if text.startswith("-") and float(text) == 0 else text


def _plain(v: Any) -> Any:
    import numpy as np

    if isinstance(v, np.ndarray | list | tuple):
        return [float(x) for x in v]
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and v != v:
        return None
    return v


def _is_recording(path: Path) -> bool:
    if path.is_dir():
        return (path / "metadata.yaml").is_file() or any(path.glob("*.bag")) or \
            any(path.glob("*.db3")) or any(path.glob("*.mcap"))
    return path.suffix.lower() in (".mcap", ".bag", ".db3")


def build_explanation(result_dir: Path, frame: int | None, t: float | None,
                      topic: str | None, rules_dir: Path | None,
                      overrides: Path | None) -> dict[str, Any]:
    """Everything `explain` prints, as plain data (the --json document without its schema)."""
    import pandas as pd

    from frontdiag.errors import ConfigError
    from frontdiag.metrics import METRICS
    from frontdiag.verdicts import CHECKS, evaluate
    from frontdiag.verdicts.engine import frame_rate
    from frontdiag.verdicts.explain import explain_row

    if not result_dir.exists():
        from frontdiag.verdicts.model import looks_like_rule_id

        if looks_like_rule_id(str(result_dir)):
            # `explain FD-PLN-001`: a rule, not a run
            raise ConfigError(f"{result_dir}: no such file or directory; it reads as a rule ID",
                              hint=f"a rule's text and thresholds: `frontdiag rules explain "
                              f"{str(result_dir).upper()}`; one frame of a run: `frontdiag "
                              "explain DIR --frame N` with the --out directory of `frontdiag "
                              "analyze`")
        raise ConfigError(f"{result_dir}: no such file or directory",
                          hint="pass the --out directory of `frontdiag analyze`")
    path = result_dir / "frames.parquet" if result_dir.is_dir() else result_dir
    if not path.is_file() or path.suffix != ".parquet":
        if _is_recording(result_dir):
            raise ConfigError(f"{result_dir} is a recording, not a result directory",
                              hint=f"run `frontdiag analyze {result_dir} --out DIR` first, then "
                              "`frontdiag explain DIR --frame N`")
        from frontdiag.output import result_dir_hint

        raise ConfigError(f"{result_dir}: no frames.parquet",
                          hint=result_dir_hint(result_dir, "pass the --out directory of "
                                               "`frontdiag analyze`"))
    try:
        table = pd.read_parquet(path)
    except Exception as exc:  # pyarrow raises several unrelated types for a bad file
        raise ConfigError(f"{path}: cannot read the table ({exc})") from None
    ruleset = _load_rules(result_dir if result_dir.is_dir() else path.parent,
                          rules_dir, overrides)
    result = evaluate(table, ruleset)
    pos, also_on = _pick_row(result.table, frame, t, topic)
    row = result.table.iloc[pos]
    row_topic = str(row.get("topic", ""))
    same = result.table[result.table["topic"] == row_topic] if "topic" in result.table.columns \
        else result.table
    expl = explain_row(result, pos)
    expl.sort(key=lambda e: (not e.fired, not e.raw, e.rule.id))
    thresholds: dict[str, list[str]] = {}
    rules_out = []
    for e in expl:
        r = e.rule
        clauses = []
        for c in e.clauses:
            clauses.append({"metric": c.metric, "value": _plain(c.value), "unit": c.unit,
                            "test": c.test, "holds": bool(c.holds),
                            "rules_out": c.rules_out if c.holds else None,
                            "in_table": c.metric in result.table.columns})
            thresholds.setdefault(c.metric, []).append(f"{r.id} {c.test}")
        if r.check:
            for name, metric in CHECKS[r.check].param_metrics.items():
                if name in r.params:
                    thresholds.setdefault(metric, []).append(
                        f"{r.id} {name}={r.params[name].value}")
        check = list(e.check_lines)
        if r.persistence and e.raw and not e.fired:
            check.append(f"needs {r.persistence.describe(frame_rate(same))}")
        if r.sensor == "lidar" and str(row.get("lidar_weak_dir", "")) not in ("", "nan", "None"):
            check.append(f"weakest direction: {row['lidar_weak_dir']} "
                         f"(axis {row.get('lidar_weak_axis', '')})")
        rules_out.append({"id": r.id, "condition": r.condition, "severity": r.severity,
                          "title": r.title,
                          "state": "fired" if e.fired else
                          "holds_not_persistent" if e.raw else "clear",
                          "clauses": clauses, "check": check,
                          "fix": r.text.fix if e.fired else None})
    sensor = str(row.get("sensor", "camera"))
    metrics = []
    for name, m in METRICS.items():
        if m.sensor not in ("any", sensor) or name not in result.table.columns:
            continue
        if name in ("frame", "sensor", "topic", "status", "conditions", "rules", "verdict",
                    "t_ns"):
            continue
        metrics.append({"name": name, "value": _plain(row[name]), "unit": m.unit,
                        "thresholds": thresholds.get(name, [])})
    status = str(row.get("status", ""))
    meaning = status_meaning(status)
    if sensor == "camera" and status in ("too_few_matches", "essential_failed"):
        gap = None
        if "t_rel_s" in same:
            earlier = same["t_rel_s"][same["frame"] < row["frame"]]
            gap = float(row["t_rel_s"]) - float(earlier.max()) if len(earlier) else None
        facts = matching_facts(row, gap)
        meaning += f" ({facts})" if facts else ""
    return {"result": str(result_dir), "frame": int(row["frame"]), "sensor": sensor,
            "topic": row_topic, "t_rel_s": _plain(row.get("t_rel_s")), "status": status,
            "status_meaning": meaning, "verdict": str(row["verdict"]),
            "conditions": list(row["conditions"]),
            "frame_range": {"first": int(same["frame"].min()), "last": int(same["frame"].max())},
            "also_on": also_on, "rules": rules_out, "metrics": metrics}


def render(data: dict[str, Any]) -> None:
    from rich.markup import escape

    from frontdiag.cli._console import make_console

    con = make_console(soft_wrap=True, highlight=False)
    conds = ", ".join(data["conditions"]) or "none"
    t = data["t_rel_s"]
    con.print(f"[bold]frame {data['frame']}[/] {data['sensor']} {escape(data['topic'])} "
              f"t={_fmt(t)} s  [dim](frames {data['frame_range']['first']}-"
              f"{data['frame_range']['last']} on this topic)[/]")
    for other in data.get("also_on", []):
        con.print(f"  [dim]{escape(other)} has a row here too: add --topic {escape(other)} "
                  "to explain that one[/]")
    con.print(f"  frontend status: [bold]{escape(data['status'])}[/] — "
              f"{escape(data['status_meaning'])}")
    fired = [r["id"] for r in data["rules"] if r["state"] == "fired"]
    found = f"rules fired: {', '.join(fired)}; conditions {conds}" if fired else \
        "no rule fired on this row"
    con.print(f"  verdict (what the rules found): [bold]{data['verdict']}[/] — {found}")
    for r in data["rules"]:
        state = {"fired": "[bold red]FIRED[/]",
                 "holds_not_persistent": "[yellow]holds here, not persistent[/]",
                 "clear": "[green]clear[/]"}[r["state"]]
        con.print(f"\n[bold]{r['id']}[/] {r['condition']} {escape('[' + r['severity'] + ']')} "
                  f"{state}: {escape(r['title'])}")
        for c in r["clauses"]:
            mark = "✔" if c["holds"] else "✘"
            out = f"  → rules out {c['rules_out']}" if c["rules_out"] else ""
            if not c.get("in_table", True):
                con.print(f"  {mark} {c['metric']} not in this table (written by an older "
                          f"frontdiag): re-run `frontdiag analyze` to read it; test "
                          f"{escape(c['test'])}")
                continue
            con.print(f"  {mark} {c['metric']} = {_fmt(c['value'])} {c['unit']}; test "
                      f"{escape(c['test'])}{out}")
        for line in r["check"]:
            con.print(f"  · {escape(line)}")
        if r["fix"]:
            con.print(f"  [dim]fix: {escape(r['fix'])}[/]")
    con.print("\n[bold]metrics[/] (value · unit · thresholds that read it)")
    for m in data["metrics"]:
        th = "; ".join(m["thresholds"])
        con.print(f"  {m['name']:<26} {_fmt(m['value']):>10} {m['unit']:<14} [dim]{escape(th)}[/]")


def register(app: typer.Typer) -> None:
    """Add `frontdiag explain` to the app."""

    @app.command("explain", short_help="Show one frame: every metric against its thresholds "
                                       "and the rules that fired.")
    def explain(
        result_dir: Path = typer.Argument(..., metavar="RESULT_DIR",
                                          help="The --out directory of `frontdiag analyze` "
                                          "(not the recording)."),
        frame_arg: int | None = typer.Argument(None, metavar="[FRAME]", show_default=False,
                                               help="Frame index: the same as --frame."),
        frame: int | None = typer.Option(None, "--frame", help="Frame index (the table's "
                                         "`frame` column)."),
        t: float | None = typer.Option(None, "--time", "--t", metavar="SECONDS",
                                       help="Seconds from the recording start (nearest row)."),
        topic: str | None = typer.Option(None, "--topic", help="Topic, when several have the "
                                         "row (default: the camera's, when one camera has "
                                         "it)."),
        rules_dir: Path | None = typer.Option(None, "--rules", metavar="DIR",
                                              help="Rules directory (default: the one the run "
                                              "used, else the shipped rules/)."),
        overrides: Path | None = typer.Option(None, "--overrides", metavar="FILE",
                                              help="Threshold override file."),
        as_json: bool = typer.Option(False, "--json", help="Machine-readable output on stdout "
                                     "(schema docs/schemas/explain.json)."),
        png: Path | None = typer.Option(None, "--png", metavar="FILE",
                                        help="Also draw the frame: keypoints (E inliers, "
                                        "outliers), 8x6 grid counts, flow to the reference, "
                                        "verdict."),
    ) -> int:
        """Show one frame: every metric against its thresholds, the rules that fired and the
        look-alikes each value rules out.

        Examples:

          frontdiag analyze run.mcap --out results/ && frontdiag explain results/ --frame 412

          frontdiag explain results/ --time 12.5 --topic /lidar/points --json

          frontdiag explain results/ --frame 412 --png frame412.png  # the picture too

          frontdiag explain results/ 412           # the frame as argument: --frame 412
        """
        from rich.markup import escape

        from frontdiag.cli._console import make_console
        from frontdiag.errors import ConfigError

        if png is not None and not png.parent.is_dir():
            raise ConfigError(f"--png {png}: folder {png.parent} does not exist")
        if frame_arg is not None:
            if frame is not None and frame != frame_arg:
                raise ConfigError(f"two frames: {frame_arg} and --frame {frame}; give one")
            frame = frame_arg
        data = build_explanation(result_dir, frame, t, topic, rules_dir, overrides)
        if png is not None:
            from frontdiag.report.frame_image import explain_png

            for note in explain_png(png, result_dir if result_dir.is_dir() else
                                    result_dir.parent, data):
                make_console(stderr=True).print(f"[yellow]note[/]: {escape(note)}")
            if not as_json:
                make_console().print(f"picture: {escape(str(png))}")
        if as_json:
            from frontdiag.json_models import ExplainDoc, emit

            typer.echo(emit(ExplainDoc, data))
            return EXIT_OK
        render(data)
        return EXIT_OK
