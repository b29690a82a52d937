"""What the visual outputs cost on one recording: diagnostics.mcap, report.html, explain --png.

    python benchmarks/bench_visual.py RECORDING [--out DIR] [--long 100]

Analyses RECORDING once (like `analyze --out DIR`) with the diagnostics writer timed from the
inside, so the share of the run it takes is measured in the same run, then builds the report and
one annotated frame. Prints sizes, times and the peak resident memory. With ``--long N`` the
report is also built for the result repeated N times end to end (each copy 2 s after the last,
as after a pause: its episodes its own), which is what a recording N times as long with as many
episodes gives the report to draw.
"""

from __future__ import annotations

import argparse
import resource
import tempfile
import time
from pathlib import Path
from typing import Any


def _mb(n: float) -> str:
    return f"{n / 1e6:.1f} MB"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("recording", type=Path)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--long", type=int, default=0, metavar="N",
                    help="also time the report of the result repeated N times")
    a = ap.parse_args()
    out = a.out or Path(tempfile.mkdtemp(prefix="bench_visual_"))
    out.mkdir(parents=True, exist_ok=True)

    from frontdiag.api import AnalysisOptions, run_analysis
    from frontdiag.output import write_manifest, write_table
    from frontdiag.report import write_episodes, write_rules_snapshot
    from frontdiag.report.mcap_ import DIAGNOSTICS_FILE, DiagnosticsWriter

    spent = {"stream": 0.0}
    writer = DiagnosticsWriter(out / DIAGNOSTICS_FILE)

    def sink(row: dict[str, Any], ann: Any, record: Any) -> None:
        t0 = time.perf_counter()
        writer(row, ann, record)
        spent["stream"] += time.perf_counter() - t0

    t0 = time.perf_counter()
    with writer:
        result = run_analysis(a.recording, AnalysisOptions(), sink=sink)
        t_analysis = time.perf_counter() - t0
        write_table(out, result.table)
        write_manifest(out, result.manifest)
        write_episodes(out, result.verdicts)
        write_rules_snapshot(out, result.ruleset)
        t1 = time.perf_counter()
        writer.finish(result.table, result.verdicts, result.ruleset)
        t_finish = time.perf_counter() - t1
    rss_analyze = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    t = result.table
    n_cam = int((t["sensor"] == "camera").sum())
    n_lid = int((t["sensor"] == "lidar").sum())
    print(f"recording      {a.recording} ({_mb(a.recording.stat().st_size)}), {n_cam} camera "
          f"rows, {n_lid} LiDAR rows")
    print(f"analysis       {t_analysis:.1f} s including {spent['stream']:.1f} s streaming "
          f"annotations/points ({100 * spent['stream'] / t_analysis:.1f} %)")
    print(f"finish         {t_finish:.1f} s (per-row diagnostics, metrics, episode log)")
    print(f"peak RSS       {rss_analyze:.0f} MB (whole process, analysis included)")
    for name in ("frames.parquet", "episodes.parquet", DIAGNOSTICS_FILE):
        print(f"  {name:<18} {_mb((out / name).stat().st_size)}")
    print(f"  per topic: {writer.counts}")

    from frontdiag.report.html import ReportInputs, build_html, load_run
    from frontdiag.verdicts import gate

    t0 = time.perf_counter()
    run = load_run(out)
    inputs = ReportInputs(run, gate=gate(run.verdicts))
    page = build_html(inputs)
    (out / "report.html").write_text(page, encoding="utf-8")
    print(f"report.html    {_mb(len(page.encode()))} in {time.perf_counter() - t0:.1f} s "
          f"({len(run.verdicts.episodes)} episodes)")

    from frontdiag.report.frame_image import encode_png, evidence, render, verdict_lines

    cams = run.table.index[run.table["sensor"] == "camera"]
    if len(cams):  # what `explain --png` does for one frame
        pos = int(cams[len(cams) // 2])
        row = {str(k): v for k, v in run.table.iloc[pos].to_dict().items()}
        t0 = time.perf_counter()
        png = encode_png(render(evidence(out, row, run.manifest), row,
                                verdict_lines(run.verdicts, pos)))
        (out / "frame.png").write_bytes(png)
        print(f"explain --png  {len(png) / 1e3:.0f} kB in {time.perf_counter() - t0:.2f} s")
    if a.long > 1:
        _long_report(out, a.long)
    print(f"results in {out}")


def _long_report(out: Path, copies: int) -> None:
    """The report of the result repeated ``copies`` times, each copy 2 s after the last."""
    import shutil

    import pandas as pd

    from frontdiag.report.html import ReportInputs, build_html, load_run
    from frontdiag.verdicts import gate

    long = out / "long"
    shutil.rmtree(long, ignore_errors=True)
    long.mkdir()
    for name in ("manifest.json", "rules.json"):
        if (out / name).exists():
            shutil.copy(out / name, long / name)
    table = pd.read_parquet(out / "frames.parquet")
    step_s = float(table["t_rel_s"].max()) + 2.0
    n_frames = int(table["frame"].max()) + 1
    parts = []
    for i in range(copies):
        t = table.copy()
        t["frame"] += i * n_frames
        t["t_ns"] += int(i * step_s * 1e9)
        t["t_rel_s"] += i * step_s
        if i:
            t.loc[t.groupby("topic").head(1).index, "status"] = "after_gap"
        parts.append(t)
    pd.concat(parts, ignore_index=True).to_parquet(long / "frames.parquet")
    t0 = time.perf_counter()
    run = load_run(long)
    page = build_html(ReportInputs(run, gate=gate(run.verdicts), thumbnails=False))
    (long / "report.html").write_text(page, encoding="utf-8")
    print(f"report.html x{copies}  {len(run.table)} rows, {len(run.verdicts.episodes)} episodes: "
          f"{_mb(len(page.encode()))} in {time.perf_counter() - t0:.1f} s (thumbnails off: the "
          "copies re-read the same frames)")


if __name__ == "__main__":
    main()
