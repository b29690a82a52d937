"""``frontdiag report``: one self-contained HTML file from a result directory.

Order: the verdict summary and the gate, then per sensor one plot per metric over time (every
metric a rule reads, and the frame time) with the rules' thresholds drawn and the episodes
shaded, then per episode the worst frame as an annotated thumbnail with the explanation, then
the latency budget projected onto a target. ``--baseline`` overlays a second run on every plot.

Plots are Plotly figures; plotly.js ships inside the plotly wheel and is written into the page
once, so the file opens offline and makes no network request (no CDN, no web fonts, images as
data: URIs). Everything is read from the result directory (frames.parquet, episodes,
manifest.json, rules.json, diagnostics.mcap); no metric is recomputed.
"""

from __future__ import annotations

import base64
import html
import itertools
import json
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from frontdiag.metrics import METRICS
from frontdiag.report.thresholds import Threshold, rule_thresholds

log = logging.getLogger(__name__)

SEVERITY_COLOR = {"fail": "#d62728", "warn": "#ff9f1c", "ok": "#2ca02c"}
MAX_EPISODES = 12
"""Episodes shown with a thumbnail (worst first); the rest are listed in one table."""
MAX_PLOT_POINTS = 4000
"""Points per line of a plot: a longer series is drawn as the lowest and the highest value of
each of MAX_PLOT_POINTS / 2 consecutive stretches, so a one-frame spike stays in the picture
(a 30 Hz hour has 108 000 rows; drawn as they are, 24 plots of them stall the browser)."""
MAX_LABELLED_SPANS = 40
"""Shaded stretches that carry their condition's name on a plot; with more, the names would
overlap into a smear, and the episode list below the plots names every one."""


@dataclass
class RunData:
    """One result directory, read once."""

    path: Path
    table: pd.DataFrame
    manifest: dict[str, Any]
    verdicts: Any
    ruleset: Any
    label: str = "this run"


@dataclass
class ReportInputs:
    run: RunData
    baseline: RunData | None = None
    gate: Any = None  # frontdiag.verdicts.gate.GateResult
    budget_grids: list[Any] = field(default_factory=list)  # frontdiag.budget.render.Grid
    budget_error: str | None = None
    thumbnails: bool = True


def load_run(result_dir: Path, label: str = "this run") -> RunData:
    """Read a result directory and evaluate its rules snapshot over its table."""
    from frontdiag.output import read_manifest, read_table
    from frontdiag.report.files import RULES_SNAPSHOT
    from frontdiag.verdicts import Ruleset, evaluate, load_ruleset

    table = read_table(result_dir)
    manifest = read_manifest(result_dir)
    table.attrs["manifest"] = manifest
    snap = Path(result_dir) / RULES_SNAPSHOT
    # the rules the run used (after its overrides), else the shipped ones
    ruleset = (Ruleset.from_dict(json.loads(snap.read_text())) if snap.is_file()
               else load_ruleset())
    verdicts = evaluate(table, ruleset)
    return RunData(Path(result_dir), verdicts.table, manifest, verdicts, ruleset, label)


# --------------------------------------------------------------------------------------------
# plots
# --------------------------------------------------------------------------------------------

def plotted_metrics(table: pd.DataFrame, sensor: str, thresholds: Sequence[Threshold]
                    ) -> list[str]:
    """Every numeric metric a rule of this sensor reads, in the catalogue's order, then the
    frame time (the latency the budget is about)."""
    read = {t.metric for t in thresholds if t.sensor == sensor}
    names = [m for m in METRICS if m in read and m in table.columns]
    if "ms_total" in table.columns and "ms_total" not in names:
        names.append("ms_total")
    rows = table[table["sensor"] == sensor]
    return [m for m in names if pd.api.types.is_numeric_dtype(rows[m])
            and np.isfinite(rows[m].to_numpy(dtype=float, na_value=np.nan)).any()]


def envelope(v: np.ndarray, max_points: int = MAX_PLOT_POINTS) -> np.ndarray:
    """Positions to draw of a series of ``len(v)`` values: all of them up to ``max_points``;
    beyond, in each of ``max_points // 2`` consecutive stretches the lowest and the highest
    finite value, in time order (a stretch with none keeps its first row, so a gap stays a
    gap)."""
    n = len(v)
    if n <= max_points:
        return np.arange(n)
    edges = np.linspace(0, n, max_points // 2 + 1).astype(np.intp)
    keep: list[int] = []
    for a, b in itertools.pairwise(edges.tolist()):
        part = v[a:b]
        ok = np.isfinite(part)
        if not ok.any():
            keep.append(int(a))
            continue
        lo = int(np.argmin(np.where(ok, part, np.inf)))
        hi = int(np.argmax(np.where(ok, part, -np.inf)))
        keep.extend(sorted({a + lo, a + hi}))
    return np.asarray(keep, dtype=np.intp)


def _points(t: np.ndarray, v: np.ndarray) -> tuple[list[float], list[float | None]]:
    """Plot coordinates: times to 0.1 ms, values to 6 digits (None where not finite)."""
    return [round(float(x), 4) for x in t], [None if not math.isfinite(y) else float(f"{y:.6g}")
                                            for y in v]


def _series(rows: pd.DataFrame, metric: str) -> tuple[list[float], list[float | None],
                                                      np.ndarray]:
    """Times, values (None where not finite) and the row positions drawn (:func:`envelope`)."""
    v = rows[metric].to_numpy(dtype=float, na_value=np.nan)
    pos = envelope(v)
    return (*_points(rows["t_rel_s"].to_numpy(dtype=float)[pos], v[pos]), pos)


def episode_spans(eps: pd.DataFrame, t0: float, t1: float, min_s: float = 0.05
                  ) -> list[tuple[float, float, str, list[str]]]:
    """The shaded stretches of a plot over ``t0``-``t1`` s: ``(x0, x1, severity, conditions)``.

    An episode shorter than ``min_s`` is widened to it, so that one frame shows. Episodes of
    one severity that overlap, or lie closer than a 2000th of the plot's width (under a pixel),
    are one stretch: a long recording's hundreds of episodes are then as many shapes as the
    picture can show, not one each (Plotly validates every shape anew as one is added)."""
    join = max(t1 - t0, 0.0) / 2000
    out: list[tuple[float, float, str, list[str]]] = []
    for sev in dict.fromkeys(eps["severity"].astype(str)):
        mine = eps[eps["severity"].astype(str) == sev]
        x0s = mine["start_t_rel_s"].to_numpy(dtype=float)
        x1s = mine["end_t_rel_s"].to_numpy(dtype=float)
        short = x1s - x0s < min_s
        x0s = np.where(short, x0s - min_s / 2, x0s)
        x1s = np.where(short, x1s + min_s / 2, x1s)
        conds = mine["condition"].astype(str).to_numpy()
        cur: list[Any] | None = None
        for i in np.argsort(x0s, kind="stable"):
            if cur is not None and x0s[i] <= cur[1] + join:
                cur[1] = max(cur[1], float(x1s[i]))
                if conds[i] not in cur[3]:
                    cur[3].append(str(conds[i]))
                continue
            if cur is not None:
                out.append((cur[0], cur[1], cur[2], cur[3]))
            cur = [float(x0s[i]), float(x1s[i]), sev, [str(conds[i])]]
        if cur is not None:
            out.append((cur[0], cur[1], cur[2], cur[3]))
    return out


def _line_label(value: float, ths: Sequence[Threshold]) -> str:
    """Short text on a threshold line: its value and the rules drawn there (full text on hover);
    four rules' full labels on one line ran across the whole plot."""
    rules = list(dict.fromkeys(t.rule for t in ths))
    if len(rules) == 1:
        return ths[0].label
    return f"{value:.4g}: " + ", ".join(rules)


def metric_figure(run: RunData, baseline: RunData | None, sensor: str, topic: str,
                  metric: str, thresholds: Sequence[Threshold]) -> Any:
    import plotly.graph_objects as go

    rows = run.table[(run.table["sensor"] == sensor) & (run.table["topic"] == topic)]
    m = METRICS.get(metric)
    unit = m.unit if m else ""
    fig = go.Figure()
    if baseline is not None:
        b = baseline.table[(baseline.table["sensor"] == sensor)
                           & (baseline.table["topic"] == topic)]
        if metric in b.columns and len(b):
            bt, bv, _ = _series(b, metric)
            fig.add_trace(go.Scatter(x=bt, y=bv, mode="lines", name=baseline.label,
                                     line={"color": "#9aa0a6", "width": 1.2}))
    t, v, pos = _series(rows, metric)
    fig.add_trace(go.Scatter(x=t, y=v, mode="lines", name=run.label,
                             line={"color": "#1f77b4", "width": 1.4},
                             customdata=rows["frame"].to_numpy()[pos].tolist(),
                             hovertemplate="t %{x:.2f} s, frame %{customdata}<br>"
                                           f"{metric} %{{y:.4g}} {unit}<extra></extra>"))
    verdict = rows["verdict"].astype(str).to_numpy() if "verdict" in rows.columns else None
    if verdict is not None:
        vals = rows[metric].to_numpy(dtype=float, na_value=np.nan)
        times = rows["t_rel_s"].to_numpy(dtype=float)
        for sev in ("warn", "fail"):
            sel = np.flatnonzero(verdict == sev)
            if sel.size:
                sel = sel[envelope(vals[sel])]  # as the line: each stretch's extremes
                xs, ys = _points(times[sel], vals[sel])
                fig.add_trace(go.Scatter(
                    x=xs, y=ys, mode="markers", name=f"{sev} rows",
                    marker={"color": SEVERITY_COLOR[sev], "size": 4}, hoverinfo="skip"))
    lines: dict[float, list[Threshold]] = {}
    for th in thresholds:
        if th.metric == metric and th.sensor == sensor:
            lines.setdefault(th.value, []).append(th)
    for value, ths in lines.items():  # one line per value, naming every rule drawn there
        sev = "fail" if any(t.severity == "fail" for t in ths) else ths[0].severity
        fig.add_hline(y=value, line={"color": SEVERITY_COLOR.get(sev, "#555"), "dash": "dash",
                                     "width": 1},
                      annotation={"text": html.escape(_line_label(value, ths)),
                                  "hovertext": "<br>".join(html.escape(t.label) for t in ths),
                                  "font": {"size": 10, "color": "#444"}},
                      annotation_position="top left")
    finite = np.array([y for y in v if y is not None], dtype=float)
    log_axis = bool(finite.size and finite.min() > 0 and finite.max() / finite.min() > 1e3
                    and all(x > 0 for x in lines))
    eps = run.verdicts.episodes if run.verdicts is not None else pd.DataFrame()
    if not eps.empty:
        mine = eps[(eps["sensor"] == sensor) & (eps["topic"] == topic)]
        all_t = rows["t_rel_s"].to_numpy(dtype=float)
        spans = episode_spans(mine, float(all_t.min()), float(all_t.max())) \
            if len(mine) and len(all_t) else []
        # one layout update with every shape (add_vrect re-validates all shapes at each call:
        # minutes for a few hundred episodes)
        shapes = [{"type": "rect", "xref": "x", "yref": "y domain", "x0": x0, "x1": x1,
                   "y0": 0, "y1": 1, "fillcolor": SEVERITY_COLOR.get(sev, "#999"),
                   "opacity": 0.13, "line": {"width": 0}, "layer": "below"}
                  for x0, x1, sev, _ in spans]
        labels = [{"text": html.escape(" + ".join(conds)), "x": x0, "xref": "x", "y": 1,
                   "yref": "y domain", "xanchor": "left", "yanchor": "top", "showarrow": False,
                   "font": {"size": 9, "color": "#777"}, "textangle": -90}
                  for x0, _, _, conds in spans] if len(spans) <= MAX_LABELLED_SPANS else []
        fig.update_layout(shapes=[*fig.layout.shapes, *shapes],
                          annotations=[*fig.layout.annotations, *labels])
    fig.update_layout(
        height=230, margin={"l": 60, "r": 20, "t": 34, "b": 34},
        title={"text": f"{metric} <span style='font-size:11px;color:#666'>"
                       f"[{html.escape(unit)}] {html.escape(m.meaning[:110] if m else '')}</span>",
               "font": {"size": 14}, "x": 0.01},
        xaxis={"title": {"text": "seconds from the recording start", "font": {"size": 11}}},
        yaxis={"title": {"text": unit + (" (log)" if log_axis else ""), "font": {"size": 11}},
               "type": "log" if log_axis else "linear"},
        showlegend=baseline is not None, legend={"orientation": "h", "y": 1.18, "x": 1,
                                                 "xanchor": "right"},
        plot_bgcolor="#fbfbfd", font={"family": "sans-serif"})
    return fig


# --------------------------------------------------------------------------------------------
# page
# --------------------------------------------------------------------------------------------

_CSS = """
body{font-family:-apple-system,"Segoe UI",Roboto,Helvetica,Arial,sans-serif;margin:0;
 color:#1d1d1f;background:#f4f5f7}
main{max-width:1180px;margin:0 auto;padding:18px 22px 60px}
h1{font-size:22px;margin:6px 0 2px}h2{font-size:18px;margin:28px 0 8px;border-bottom:1px solid
 #ddd;padding-bottom:4px}h3{font-size:15px;margin:18px 0 6px}
.meta{color:#555;font-size:13px}.card{background:#fff;border-radius:8px;padding:12px 16px;
 margin:10px 0;box-shadow:0 1px 2px rgba(0,0,0,.08)}
.pill{display:inline-block;border-radius:12px;padding:2px 10px;font-weight:600;color:#fff;
 margin-right:6px;font-size:13px}
.fail{background:#d62728}.warn{background:#ff9f1c}.ok{background:#2ca02c}
table{border-collapse:collapse;font-size:13px;margin:6px 0}
td,th{border-bottom:1px solid #e3e3e3;padding:3px 10px;text-align:left;vertical-align:top}
th{background:#fafafa}td.num{text-align:right;font-variant-numeric:tabular-nums}
.gate-pass{border-left:6px solid #2ca02c}.gate-fail{border-left:6px solid #d62728}
.episode{display:flex;gap:16px;flex-wrap:wrap}.episode img{max-width:560px;width:100%;
 border-radius:4px;border:1px solid #ccc}.episode .text{flex:1;min-width:300px;font-size:13px}
pre{white-space:pre-wrap;font-size:12px;background:#f7f7f9;padding:8px;border-radius:4px}
.plot{background:#fff;border-radius:6px;margin:6px 0}
"""


def _e(text: Any) -> str:
    return html.escape(str(text))


def _fmt(v: Any) -> str:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return _e(v)
    return "n/a" if not math.isfinite(f) else f"{f:.4g}"


def _summary_html(inp: ReportInputs) -> str:
    from frontdiag.report.json_ import condition_counts
    from frontdiag.verdicts.gate import no_pose

    run = inp.run
    t = run.table
    parts = []
    for sensor in ("camera", "lidar"):
        rows = t[t["sensor"] == sensor]
        if rows.empty:
            continue
        counts = rows["verdict"].value_counts()
        pills = "".join(f"<span class='pill {k}'>{int(counts.get(k, 0))} {k}</span>"
                        for k in ("ok", "warn", "fail"))
        topics = ", ".join(sorted(set(rows["topic"].astype(str))))
        lost = no_pose(rows)
        nopose = (f"<br><span class='meta'>no pose on {lost.frames} of {lost.expected} frames "
                  f"({_e(lost.breakdown)}): the frontend lost track there; {lost.unnamed} of "
                  "them carry no condition</span>" if lost.frames else "")
        parts.append(f"<p><b>{sensor}</b> <span class='meta'>{_e(topics)}, {len(rows)} rows"
                     f"</span><br>{pills}{nopose}</p>")
    conds = {k: v for k, v in condition_counts(run.verdicts).items() if v["frames"]}
    if conds:
        body = "".join(f"<tr><td>{_e(k)}</td><td class='num'>{v['frames']}</td>"
                       f"<td class='num'>{v['share']:.1%}</td><td class='num'>{v['episodes']}"
                       "</td></tr>" for k, v in conds.items())
        parts.append("<table><tr><th>condition</th><th>frames</th><th>share</th>"
                     f"<th>episodes</th></tr>{body}</table>")
    else:
        parts.append("<p>No condition fired.</p>")
    gate_html = ""
    if inp.gate is not None:
        g = inp.gate
        cls = "gate-pass" if g.passed else "gate-fail"
        head = (f"gate passed (fail-on {g.fail_on})" if g.passed else
                f"gate failed (fail-on {g.fail_on}, exit {g.exit_code})")
        reasons = "".join(f"<li>{_e(r)}</li>" for r in g.reasons)
        gate_html = (f"<div class='card {cls}'><b>{_e(head)}</b>"
                     + (f"<ul>{reasons}</ul>" if reasons else "") + "</div>")
    findings = [f for f in run.verdicts.run_findings if f.fired]
    find_html = "".join(f"<li><b>{_e(f.rule)}</b> [{_e(f.severity)}] {_e(f.message)}</li>"
                        for f in findings)
    return (f"<section id='summary'><h2>Verdict</h2>{gate_html}<div class='card'>"
            + "".join(parts) + (f"<p>Run-level findings:</p><ul>{find_html}</ul>"
                                if find_html else "") + "</div></section>")


def _worst_row(run: RunData, e: pd.Series) -> int | None:
    """Position in run.table of the episode's worst frame: where the worst rule's first peak
    metric reaches the episode's peak value (``peak_<metric>`` in episodes)."""
    from frontdiag.verdicts.engine import peak_spec

    t = run.table
    frames = t["frame"].to_numpy(dtype=float)
    span = np.flatnonzero((t["topic"].astype(str).to_numpy() == str(e["topic"]))
                          & (frames >= int(e["start_frame"])) & (frames <= int(e["end_frame"])))
    if span.size == 0:
        return None
    rules_col = t["rules"].to_numpy()
    fired = np.array([e["rule"] in list(rules_col[i]) for i in span], dtype=bool)
    cand = span[fired] if fired.any() else span
    rule = next((r for r in run.ruleset.frame_rules if r.id == e["rule"]), None)
    for metric in peak_spec(rule) if rule is not None else {}:
        peak = e.get(f"peak_{metric}")
        if metric not in t.columns or peak is None or not np.isfinite(float(peak)):
            continue
        vals = t[metric].to_numpy(dtype=float, na_value=np.nan)[cand]
        if np.isfinite(vals).any():
            return int(cand[int(np.nanargmin(np.abs(vals - float(peak))))])
    return int(cand[len(cand) // 2])


def _episode_html(run: RunData, e: pd.Series, thumbnails: bool) -> str:
    from frontdiag.report.frame_image import encode_jpeg, evidence, render, verdict_lines

    pos = _worst_row(run, e)
    img = ""
    lines: list[str] = []
    if pos is not None:
        row = {str(k): v for k, v in run.table.iloc[pos].to_dict().items()}
        lines = verdict_lines(run.verdicts, pos, max_lines=10)
        if thumbnails and str(row.get("sensor")) == "camera":
            ev = evidence(run.path, row, run.manifest)
            if ev.gray is not None or ev.annotation is not None:
                jpg = encode_jpeg(render(ev, row, lines[:3]), width=720)
                img = (f"<img alt='frame {row.get('frame')}' src='data:image/jpeg;base64,"
                       f"{base64.b64encode(jpg).decode()}'>")
    rule = next((r for r in run.ruleset.frame_rules if r.id == e["rule"]), None)
    text = ""
    if rule is not None:
        text = (f"<p><b>symptom</b>: {_e(rule.text.symptom)}<br><b>fix</b>: {_e(rule.text.fix)}"
                f"<br><b>not the fix</b>: {_e(rule.text.wrong_fix)}</p>")
    worst = f"worst frame {run.table['frame'].to_numpy()[pos]}" if pos is not None else ""
    sev = str(e["severity"])
    return (f"<div class='card'><h3><span class='pill {sev}'>{_e(sev)}</span>"
            f"{_e(e['condition'])} · {_e(e['rule'])} · {float(e['start_t_rel_s']):.2f}–"
            f"{float(e['end_t_rel_s']):.2f} s · {_e(worst)}</h3><div class='episode'>{img}"
            f"<div class='text'><p>{_e(e['summary'])}</p><pre>{_e(chr(10).join(lines))}</pre>"
            f"{text}</div></div></div>")


def _episodes_html(inp: ReportInputs) -> str:
    eps = inp.run.verdicts.episodes
    if eps.empty:
        return "<section id='episodes'><h2>Episodes</h2><p>None.</p></section>"
    shown = eps.head(MAX_EPISODES)
    parts = [_episode_html(inp.run, e, inp.thumbnails) for _, e in shown.iterrows()]
    rest = eps.iloc[MAX_EPISODES:]
    if not rest.empty:
        body = "".join(f"<tr><td>{_e(e['severity'])}</td><td>{_e(e['summary'])}</td></tr>"
                       for _, e in rest.iterrows())
        parts.append(f"<div class='card'><p>{len(rest)} more episodes:</p><table>{body}"
                     "</table></div>")
    return (f"<section id='episodes'><h2>Episodes ({len(eps)}, worst first)</h2>"
            + "".join(parts) + "</section>")


def _budget_html(inp: ReportInputs) -> str:
    if inp.budget_error:
        return (f"<section id='budget'><h2>Latency budget</h2><p>{_e(inp.budget_error)}</p>"
                "</section>")
    if not inp.budget_grids:
        return ""
    parts = []
    for g in inp.budget_grids:
        head = "".join(f"<th>{_e(h)}</th>" for h in g.headers)
        body = "".join("<tr>" + "".join(
            f"<td class='num'>{_e(c)}</td>" if i else f"<td>{_e(c)}</td>"
            for i, c in enumerate(r)) + "</tr>" for r in g.rows)
        notes = "".join(f"<p class='meta'>{_e(n)}</p>" for n in g.notes)
        parts.append(f"<div class='card'><h3>{_e(g.title)}</h3><table><tr>{head}</tr>{body}"
                     f"</table>{notes}</div>")
    return "<section id='budget'><h2>Latency budget</h2>" + "".join(parts) + "</section>"


def _plots_html(inp: ReportInputs) -> tuple[str, int]:
    run = inp.run
    thresholds = rule_thresholds(run.ruleset)
    parts = []
    n = 0
    for sensor in ("camera", "lidar"):
        rows = run.table[run.table["sensor"] == sensor]
        for topic in sorted(set(rows["topic"].astype(str))):
            metrics = plotted_metrics(run.table, sensor, thresholds)
            parts.append(f"<h3>{sensor} · {_e(topic)}</h3>")
            for metric in metrics:
                fig = metric_figure(run, inp.baseline, sensor, topic, metric, thresholds)
                parts.append("<div class='plot'>" + fig.to_html(
                    full_html=False, include_plotlyjs=False, include_mathjax=False,
                    div_id=f"plot-{n}", config={"displaylogo": False, "responsive": True,
                                                "displayModeBar": False})
                    + "</div>")
                n += 1
    longest = int(run.table.groupby(["sensor", "topic"]).size().max()) if len(run.table) else 0
    legend = ("<p class='meta'>Dashed lines: the rules' thresholds (red fail, amber warn). "
              "Shaded: episodes (named where a plot has at most "
              f"{MAX_LABELLED_SPANS}). Dots: rows with a warn / fail verdict."
              + (f" A series longer than {MAX_PLOT_POINTS} rows is drawn as the lowest and "
                 "highest value of each stretch of rows, so no spike is lost."
                 if longest > MAX_PLOT_POINTS else "")
              + (" Grey: the baseline run." if inp.baseline is not None else "") + "</p>")
    return "<section id='metrics'><h2>Metrics over time</h2>" + legend + "".join(parts) \
        + "</section>", n


PLOTLY_FILE = "plotly.min.js"
"""A fleet's report writes plotly.js once, beside its recordings' folders (see build_html)."""


def build_html(inp: ReportInputs, plotly_src: str | None = None) -> str:
    """The whole page as one string, plotly.js inside it; or, with ``plotly_src``, loaded from
    that relative path (a fleet's pages share one copy, 4.8 MB, in the fleet's folder, whose
    index already links them by relative paths: the folder is read as a whole)."""
    from plotly.offline import get_plotlyjs

    from frontdiag import __version__

    run = inp.run
    man = run.manifest
    inp_info = man.get("input") or {}
    name = Path(str(inp_info.get("path", run.path))).name
    span = ""
    if inp_info.get("start_ns") and inp_info.get("end_ns"):
        span = f", {(int(inp_info['end_ns']) - int(inp_info['start_ns'])) / 1e9:.1f} s"
    base = (f"<p class='meta'>Baseline: {_e(inp.baseline.path)}</p>"
            if inp.baseline is not None else "")
    plots, n_plots = _plots_html(inp)
    body = (f"<h1>frontdiag report · {_e(name)}</h1><p class='meta'>{_e(inp_info.get('path', ''))}"
            f"{_e(span)} · result {_e(run.path)} · analysed with frontdiag "
            f"{_e(man.get('frontdiag_version', '?'))}, report by {__version__}</p>{base}"
            + _summary_html(inp) + plots + _episodes_html(inp) + _budget_html(inp))
    notes = man.get("notes") or []
    if notes:
        body += ("<section><h2>Notes</h2><ul>" + "".join(f"<li>{_e(x)}</li>" for x in notes)
                 + "</ul></section>")
    meta = json.dumps({"plots": n_plots})
    return ("<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            "<meta name='viewport' content='width=device-width, initial-scale=1'>"
            f"<title>frontdiag report · {_e(name)}</title><style>{_CSS}</style>"
            f"<script type='application/json' id='frontdiag-meta'>{meta}</script>"
            + (f"<script src='{html.escape(plotly_src, quote=True)}'></script>" if plotly_src
               else f"<script>{get_plotlyjs()}</script>")
            + f"</head><body><main>{body}</main></body></html>")


def fleet_index_html(out: Path, summary: pd.DataFrame, pages: dict[str, str]) -> str:
    """One page over a fleet run's ``--out`` folder: a row per recording (status, frames,
    coverage, verdict counts, episodes by condition, gate), linking each recording's own
    report (``pages``: recording name -> path of its page relative to the index)."""
    from frontdiag import __version__

    rows = []
    for r in summary.itertuples(index=False):
        name = str(r.recording)
        by_cond = ""
        ep_file = out / name / "episodes.parquet"
        if ep_file.is_file():
            counts = pd.read_parquet(ep_file, columns=["condition"])["condition"].value_counts()
            by_cond = ", ".join(f"{_e(c)} {int(n)}" for c, n in counts.items())
        link = (f"<a href='{_e(pages[name])}'>{_e(name)}</a>" if name in pages else _e(name))
        gate = str(r.gate or "")
        cls = "gate-pass" if gate == "passed" else "gate-fail" if gate else ""
        c = pd.to_numeric(pd.Series([r.coverage]), errors="coerce").iloc[0]
        cov = f"{100 * float(c):.0f} %" if pd.notna(c) else ""
        err = f"<br><span class='meta'>{_e(r.error)}</span>" if str(r.error or "") else ""
        rows.append(
            f"<tr class='{cls}'><td>{link}{err}</td><td>{_e(r.status)}</td>"
            f"<td class='num'>{_e(r.frames)}</td><td class='num'>{cov}</td>"
            f"<td class='num'>{_e(r.ok)}</td><td class='num'>{_e(r.warn)}</td>"
            f"<td class='num'>{_e(r.fail)}</td><td class='num'>{_e(r.episodes)}</td>"
            f"<td>{by_cond}</td><td>{_e(gate)}</td></tr>")
    failed = int((summary["gate"] == "failed").sum()) if "gate" in summary else 0
    errors = int((summary["status"] == "error").sum()) if "status" in summary else 0
    head = ("<tr><th>recording</th><th>status</th><th>frames</th><th>coverage</th><th>ok</th>"
            "<th>warn</th><th>fail</th><th>episodes</th><th>episodes by condition</th>"
            "<th>gate</th></tr>")
    body = (f"<h1>frontdiag fleet · {_e(out.name)}</h1>"
            f"<p class='meta'>{_e(out)} · {len(summary)} recordings, {failed} with a failed "
            f"gate, {errors} not analysed · report by frontdiag {__version__}</p>"
            f"<section><table>{head}{''.join(rows)}</table></section>")
    return ("<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            "<meta name='viewport' content='width=device-width, initial-scale=1'>"
            f"<title>frontdiag fleet · {_e(out.name)}</title><style>{_CSS}</style></head>"
            f"<body><main>{body}</main></body></html>")
