"""Terminal rendering of an analysis: a short summary table per sensor, with units."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from rich.console import Console
from rich.markup import escape
from rich.table import Table

# (column, label with unit, format)
CAMERA_SUMMARY = [
    ("n_keypoints", "keypoints", "{:.0f}"),
    ("entropy_norm", "entropy H/Hmax", "{:.3f}"),
    ("ratio_reject_rate", "ratio-test reject", "{:.0%}"),
    ("n_matches", "matches", "{:.0f}"),
    ("inlier_ratio", "inlier ratio w", "{:.2f}"),
    ("h_over_e", "H/E inliers", "{:.2f}"),
    ("parallax_med_deg", "parallax (deg)", "{:.2f}"),
    ("pose_info_cond", "pose info λmax/λmin", "sig"),
    ("d_mean_intensity", "Δ mean (grey lvl)", "{:+.1f}"),
    ("photo_residual_med", "photo residual (grey lvl)", "{:.1f}"),
    ("ms_total", "latency (ms)", "{:.1f}"),
]
LIDAR_SUMMARY = [
    ("n_points", "points", "{:.0f}"),
    ("n_points_used", "points used", "{:.0f}"),
    ("deskew_m", "deskew (m)", "{:.3f}"),
    ("icp_fitness", "fitness", "{:.2f}"),
    ("icp_rmse_m", "RMSE (m)", "{:.3f}"),
    ("lidar_eig_min", "λmin (points of 20,000)", "sig"),
    ("lidar_cond", "condition number λmax/λmin", "sig"),
    ("ms_total", "latency (ms)", "{:.1f}"),
]


def fmt_value(fmt: str, value: float) -> str:
    """Format a summary value: ``"sig"`` keeps three significant figures without an exponent
    (λmin 0.456 must not print as 0, nor 2400 as 2.4e+03); a value that rounds to zero never
    prints as -0.000."""
    if fmt == "sig":
        if value == 0 or not np.isfinite(value):
            text = f"{value:g}"
        else:
            digits = max(0, 2 - int(np.floor(np.log10(abs(value)))))
            text = f"{value:.{digits}f}"
    else:
        text = fmt.format(value)
    if text.startswith("-") and float(text.rstrip("%")) == 0:
        text = text[1:]
    return text


def _stats(s: pd.Series) -> dict[str, float] | None:
    v = pd.to_numeric(s, errors="coerce").to_numpy(dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return None
    return {"p10": float(np.percentile(v, 10)), "median": float(np.median(v)),
            "p90": float(np.percentile(v, 90)), "n": int(v.size)}


def sensor_summaries(table: pd.DataFrame) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if table.empty:
        return out
    for sensor, spec in (("camera", CAMERA_SUMMARY), ("lidar", LIDAR_SUMMARY)):
        rows = table[table["sensor"] == sensor]
        if rows.empty:
            continue
        out[sensor] = {
            "frames": len(rows),
            "status": {str(k): int(v) for k, v in rows["status"].value_counts().items()},
            "metrics": {col: _stats(rows[col]) for col, _, _ in spec if col in rows},
        }
    return out


def weak_direction_line(rows: pd.DataFrame) -> str | None:
    """The LiDAR's weakest direction over the run, by the categorical axis: "x (forward) in 41
    of 60 scans" and the words of the most common reading."""
    if "lidar_weak_axis" not in rows or rows.empty:
        return None
    axes = rows["lidar_weak_axis"].astype(str)
    axes = axes[axes.str.len() > 0]
    if axes.empty:
        return None
    counts = axes.value_counts()
    top = str(counts.index[0])
    words = rows.loc[axes.index][axes == top]["lidar_weak_dir"].astype(str).value_counts()
    shown = ", ".join(f"{k} {int(v)}" for k, v in counts.items())
    return (f"weakest direction (smallest eigenvalue's eigenvector): {top} in {int(counts.iloc[0])}"
            f" of {len(rows)} scans ({words.index[0]}); by axis: {shown}")


def render_analysis(console: Console, result: Any, out_dir: Path | None,
                    written: list[Path] | None = None) -> None:
    table = result.table
    man = result.manifest
    topics = man["topics"]
    src = f"{escape(str(man['input']['path']))}  [dim]({man['input']['backend']})[/]"
    console.print(f"[bold]frontdiag analyze[/] {src}")
    for sensor, spec in (("camera", CAMERA_SUMMARY), ("lidar", LIDAR_SUMMARY)):
        rows = table[table["sensor"] == sensor] if not table.empty else table
        if rows.empty:
            continue
        topic = topics.get(sensor)
        status = ", ".join(f"{k} {v}" for k, v in rows["status"].value_counts().items())
        # the heading is its own line: as the table's title it wrapped at the table's width
        console.print(escape(f"{sensor} {topic}: {len(rows)} frames ({status})"),
                      style="italic", highlight=False)
        t = Table(show_edge=False, header_style="bold")
        t.add_column("metric")
        for c in ("p10", "median", "p90"):
            t.add_column(c, justify="right")
        for col, label, fmt in spec:
            if col not in rows:
                continue
            st = _stats(rows[col])
            if st is None:
                t.add_row(label, "—", "—", "—")
                continue
            t.add_row(label, *(fmt_value(fmt, st[k]) for k in ("p10", "median", "p90")))
        console.print(t)
        if sensor == "lidar":
            line = weak_direction_line(rows)
            if line:
                console.print(f"[dim]{escape(line)}[/]", highlight=False)
    for topic, c in (man.get("coverage") or {}).items():
        repeats = c.get("repeats") or 0
        also = f" ({repeats} repeated the picture before: see the notes)" if repeats else ""
        line = escape(f"{c['sensor']} {topic}: {c['frames_analysed']} of {c['frames_present']} "
                      f"frames measured{also}")
        console.print(f"[dim]coverage[/] {line}", highlight=False)
    if man.get("intrinsics"):
        console.print(f"[dim]intrinsics: {escape(str(man['intrinsics']['source']))}[/]")
    for note in result.notes:
        console.print(f"[yellow]note:[/] {escape(note)}", highlight=False)
    if written:
        console.print("[green]wrote[/] " + ", ".join(escape(str(p)) for p in written),
                      highlight=False)
    elif out_dir is None:
        console.print("[yellow]nothing saved[/]: pass --out DIR to keep the table "
                      "(frames.parquet, episodes.parquet, manifest.json) for `frontdiag explain "
                      "DIR --frame N`, `frontdiag eval DIR` and `--baseline DIR`", highlight=False)
