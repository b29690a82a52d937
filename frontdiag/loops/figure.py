"""loops.html: the map with every loop drawn in its verdict's colour, one self-contained page.

The audit's map (the odometry and the verified loops, optimised) is drawn top down (x, y; a 3D
graph is seen from above) with its trajectory in grey and every loop as a segment between its
two poses: refused loops red, warnings orange, kept loops green. Hovering a loop shows its
number, vertices, verdict, rule and residuals. With ``--optimize`` a second panel shows the map
an optimiser returns with every loop believed, rigidly aligned to the map without the refused
loops: where the two differ is the fold the refused loops would have caused.

plotly.js is written into the page, so it opens offline.
"""

from __future__ import annotations

from html import escape
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from frontdiag.loops.audit import LoopAudit
from frontdiag.loops.optimize import align_rigid

LOOPS_HTML = "loops.html"
F = NDArray[np.float64]
_COLOURS = {"ok": "rgba(46, 160, 67, 0.45)", "warn": "rgb(230, 140, 0)", "fail": "rgb(214, 39, 40)"}
_WIDTH = {"ok": 1.0, "warn": 1.8, "fail": 2.4}
_LABEL = {"ok": "kept", "warn": "warning", "fail": "refused"}


def _xy(P: F) -> F:
    d = P.shape[-1] - 1
    return P[:, :2, d]


def _hover(row: pd.Series) -> str:
    rule = f" {row['rule']}" if row["rule"] else ""
    parts = [f"loop {int(row['loop'])}: {int(row['i'])}→{int(row['j'])}",
             f"{row['verdict']}{rule}",
             f"residual {row['residual_m']:.2f} m / {row['residual_deg']:.1f}° "
             f"(χ² {row['chi2']:.3g})"]
    if "map_residual_m" in row.index and np.isfinite(row["map_residual_m"]):
        parts.append(f"against the map: {row['map_residual_m']:.2f} m / "
                     f"{row['map_residual_deg']:.1f}°")
    if np.isfinite(row["displacement_m"]):
        parts.append(f"would move the map by {row['displacement_m']:.2f} m")
    return "<br>".join(escape(p) for p in parts)


def _traces(result: LoopAudit, P: F, col: int, legend: bool) -> list[Any]:
    """Trajectory and loop segments of one panel."""
    import plotly.graph_objects as go

    g = result.graph
    t = result.table
    xy = _xy(P)
    out: list[Any] = [go.Scattergl(
        x=xy[:, 0], y=xy[:, 1], mode="lines", line={"color": "rgb(120, 120, 120)", "width": 1},
        name="trajectory", legendgroup="trajectory", showlegend=legend,
        hovertemplate="pose %{text}<extra></extra>", text=[str(int(v)) for v in g.ids],
        xaxis=f"x{col}", yaxis=f"y{col}")]
    edges = t["edge"].to_numpy()
    for verdict in ("ok", "warn", "fail"):  # refused loops drawn last, on top
        mine = np.flatnonzero(t["verdict"].to_numpy() == verdict)
        if not mine.size:
            continue
        a, b = xy[g.src[edges[mine]]], xy[g.dst[edges[mine]]]
        gap = np.full((mine.size, 2), np.nan)
        seg = np.stack([a, b, gap], axis=1).reshape(-1, 2)  # a, b, break, ...
        text = [_hover(t.iloc[i]) for i in mine.tolist()]
        hover = [s for x in text for s in (x, x, "")]
        out.append(go.Scattergl(
            x=seg[:, 0], y=seg[:, 1], mode="lines",
            line={"color": _COLOURS[verdict], "width": _WIDTH[verdict]},
            name=f"{_LABEL[verdict]} ({mine.size})", legendgroup=verdict, showlegend=legend,
            hovertemplate="%{text}<extra></extra>", text=hover, connectgaps=False,
            xaxis=f"x{col}", yaxis=f"y{col}"))
    return out


def loops_figure(result: LoopAudit, solved: dict[str, F] | None = None) -> Any:
    """The figure of the page (module doc); ``solved``: ``all`` and ``clean`` poses from
    ``--optimize``."""
    from plotly.subplots import make_subplots

    g = result.graph
    if solved is None:
        P = result.map_poses if result.map_poses is not None else result.chain.P
        title = ("the map of the verified loops" if result.map_poses is not None
                 else "the odometry chain (--no-map)")
        fig = make_subplots(rows=1, cols=1, subplot_titles=[title])
        panels = [(P, 1)]
    else:
        clean = solved["clean"]
        every = solved["all"].copy()
        d = g.dim
        every[:, :d, d] = align_rigid(every[:, :d, d], clean[:, :d, d])
        fig = make_subplots(rows=1, cols=2, shared_xaxes=True, shared_yaxes=True,
                            subplot_titles=["every loop believed (what the optimiser returns)",
                                            "without the refused loops"])
        panels = [(every, 1), (clean, 2)]
    for n, (P, col) in enumerate(panels):
        for tr in _traces(result, P, col, legend=n == 0):
            fig.add_trace(tr, row=1, col=col)
    view = " (seen from above: x, y)" if g.dim == 3 else ""
    fig.update_layout(
        title=escape(f"{Path(g.path).name}: {len(result.table)} loops{view}"),
        height=720, template="plotly_white", hovermode="closest",
        legend={"orientation": "h", "y": -0.08})
    for col in range(1, len(panels) + 1):
        fig.update_yaxes(scaleanchor=f"x{'' if col == 1 else col}", scaleratio=1,
                         title_text="y (m)", row=1, col=col)
        fig.update_xaxes(title_text="x (m)", row=1, col=col)
    return fig


def write_loops_html(out_dir: Path, result: LoopAudit, summ: dict[str, Any],
                     solved: dict[str, F] | None = None) -> Path:
    """loops.html in ``out_dir``: the figure, the verdict counts and the notes."""
    fig = loops_figure(result, solved)
    v = summ["verdicts"]
    notes = "".join(f"<li>{escape(str(x))}</li>" for x in summ["notes"])
    head = (f"<p>{v['fail']} refused, {v['warn']} warnings, {v['ok']} kept, of "
            f"{len(result.table)} loops in {escape(result.graph.path)}. Hover a loop for its "
            "verdict and residuals; drag to zoom, double-click to reset.</p>")
    body = fig.to_html(full_html=False, include_plotlyjs=True, include_mathjax=False,
                       config={"displaylogo": False})
    page = ("<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            f"<title>frontdiag loops · {escape(Path(result.graph.path).name)}</title>"
            "<style>body{font-family:system-ui,sans-serif;margin:1.5em;color:#222}</style>"
            f"</head><body><h1>frontdiag loops</h1>{head}{body}"
            + (f"<h2>Notes</h2><ul>{notes}</ul>" if notes else "") + "</body></html>")
    path = Path(out_dir) / LOOPS_HTML
    path.write_text(page, encoding="utf-8")
    return path
