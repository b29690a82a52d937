"""Peak memory of `frontdiag analyze` against the length of the recording.

A recording ten times longer should not need much more memory: the frames are streamed, and the
per-frame rows the table is built from are the only thing that grows. This benchmark writes two
recordings of real photographs (TUM fr3 long office shrunk to 160x120, so that 30 000 frames
take minutes, not an hour; the rows do not depend on the picture size) of N and 10N frames,
runs the whole command on each as a user does (its own process, every output written) with
``--jobs 1`` and ``--jobs 2``, and prints per run: frames, wall seconds, peak RSS of the main
process and of each worker (polled every 50 ms), and the growth of the main process's peak per
frame between the two lengths. The reference, from the same run: the table itself, as pandas
holds it (frames.parquet read back), per frame: what any process that builds the table in
memory must hold at least.

    python benchmarks/bench_memory.py [--data ../shared/data] [--frames 3000] [--jobs 1,2]
"""

from __future__ import annotations

import argparse
import contextlib
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import pandas as pd
import psutil

sys.path.insert(0, str(Path(__file__).resolve().parent))
import real_recordings as rr


def one_run(rec: Path, out: Path, jobs: int) -> dict[str, Any]:
    shutil.rmtree(out, ignore_errors=True)
    cmd = [sys.executable, "-m", "frontdiag", "analyze", str(rec), "--out", str(out), "-q",
           "--fail-on", "never", "--jobs", str(jobs)]
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd)
    main = psutil.Process(p.pid)
    peak_main, peak_child = 0.0, {}
    while p.poll() is None:
        with contextlib.suppress(psutil.Error):
            peak_main = max(peak_main, main.memory_info().rss / 2**20)
            # the workers are forked by the worker server (its resource tracker beside it):
            # the main process's grandchildren
            for c in main.children(recursive=True):
                with contextlib.suppress(psutil.Error):
                    if c.ppid() != p.pid:
                        peak_child[c.pid] = max(peak_child.get(c.pid, 0.0),
                                                c.memory_info().rss / 2**20)
        time.sleep(0.05)
    wall = time.perf_counter() - t0
    if p.returncode not in (0, 1):
        raise SystemExit(f"{' '.join(cmd)} exited {p.returncode}")
    table = pd.read_parquet(out / "frames.parquet")
    workers = sorted(peak_child.values(), reverse=True)
    return {"frames": len(table), "wall": wall, "main": peak_main, "workers": workers,
            "table_kib_per_frame": table.memory_usage(deep=True).sum() / 1024 / len(table)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=None, help="../shared/data")
    ap.add_argument("--frames", type=int, default=3000, help="1x length (10x is also run)")
    ap.add_argument("--jobs", default="1,2", help="comma list of --jobs values")
    args = ap.parse_args()
    jobs = [int(j) for j in args.jobs.split(",") if j]
    res: dict[tuple[int, int], dict[str, Any]] = {}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for mult in (1, 10):
            rec = rr.write(tmp / f"len{mult}.mcap", "tum160", args.frames * mult,
                           root=args.data)
            for j in jobs:
                res[(mult, j)] = one_run(rec, tmp / f"out{mult}_{j}", j)
                r = res[(mult, j)]
                ws = ", ".join(f"{w:.0f}" for w in r["workers"]) or "-"
                print(f"{r['frames']:>7} frames  --jobs {j}  {r['wall']:7.1f} s  main peak "
                      f"{r['main']:6.0f} MiB  workers {ws} MiB", flush=True)
            rec.unlink()
    print()
    for j in jobs:
        a, b = res[(1, j)], res[(10, j)]
        grow = (b["main"] - a["main"]) * 1024 / max(1, b["frames"] - a["frames"])
        wa, wb = max(a["workers"], default=0.0), max(b["workers"], default=0.0)
        wgrow = f", largest worker {wa:.0f} -> {wb:.0f} MiB" if a["workers"] else ""
        print(f"--jobs {j}: main peak {a['main']:.0f} -> {b['main']:.0f} MiB from "
              f"{a['frames']} to {b['frames']} frames: {grow:.2f} KiB per frame{wgrow}; "
              f"the table itself {b['table_kib_per_frame']:.2f} KiB per frame")


if __name__ == "__main__":
    main()
