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
    python benchmarks/bench_memory.py --phases      # also where the main process's peak is

With ``--phases`` the ``--jobs 1`` runs also sample the main process's RSS from inside it (a
thread, every 20 ms) and print its peak during each phase of the run: the pass over the
recording, building the table, the rules, writing the result files, and writing
diagnostics.mcap's per-row messages; "start-up" is the command before the pass (imports, the
recording opened), "other" the rest of it between and after these (the summary, the gate).
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

PHASES = (("pass", "frontdiag.api", "run_stream"), ("table", "frontdiag.api", "_table"),
          ("rules", "frontdiag.verdicts", "evaluate"),
          ("result files", "frontdiag.cli.analyze", "_write_results"),
          ("diagnostics.mcap rows", "frontdiag.report.mcap_", "DiagnosticsWriter.finish"))
"""The phases ``--phases`` reports: (name, module, function it runs in)."""


def phase_child(argv: list[str]) -> None:
    """``frontdiag analyze ARGV`` in this process, printing the peak RSS of each phase (MiB) as
    one JSON line on stdout at the end."""
    import importlib
    import json
    import os
    import threading

    from frontdiag.cli import app

    proc = psutil.Process(os.getpid())
    state: dict[str, Any] = {"phase": "start-up", "peaks": {}}

    def sample() -> None:
        while True:
            rss = proc.memory_info().rss / 2**20
            peaks = state["peaks"]
            peaks[state["phase"]] = max(peaks.get(state["phase"], 0.0), rss)
            time.sleep(0.02)

    def wrap(name: str, fn: Any) -> Any:
        def run(*a: Any, **k: Any) -> Any:
            before, state["phase"] = state["phase"], name
            try:
                return fn(*a, **k)
            finally:
                time.sleep(0.05)  # a sample at the phase's end
                # back in the command: after the first phase, that is the rest of it
                state["phase"] = "other" if before == "start-up" else before
        return run

    for name, module, attr in PHASES:
        owner: Any = importlib.import_module(module)
        *path, fn_name = attr.split(".")
        for part in path:
            owner = getattr(owner, part)
        setattr(owner, fn_name, wrap(name, getattr(owner, fn_name)))
    threading.Thread(target=sample, daemon=True).start()
    with contextlib.suppress(SystemExit):
        app(["analyze", *argv])
    time.sleep(0.05)
    print(json.dumps(state["peaks"]), flush=True)


def one_run(rec: Path, out: Path, jobs: int, phases: bool = False) -> dict[str, Any]:
    shutil.rmtree(out, ignore_errors=True)
    args = [str(rec), "--out", str(out), "-q", "--fail-on", "never", "--jobs", str(jobs)]
    cmd = [sys.executable, "-m", "frontdiag", "analyze", *args]
    if phases:
        cmd = [sys.executable, str(Path(__file__).resolve()), "--phase-child", *args]
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE if phases else None, text=True)
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
    by_phase: dict[str, float] = {}
    if phases:
        import json

        assert p.stdout is not None
        by_phase = json.loads(p.stdout.read().strip().splitlines()[-1])
    table = pd.read_parquet(out / "frames.parquet")
    workers = sorted(peak_child.values(), reverse=True)
    return {"frames": len(table), "wall": wall, "main": peak_main, "workers": workers,
            "table_kib_per_frame": table.memory_usage(deep=True).sum() / 1024 / len(table),
            "phases": by_phase}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=None, help="../shared/data")
    ap.add_argument("--frames", type=int, default=3000, help="1x length (10x is also run)")
    ap.add_argument("--jobs", default="1,2", help="comma list of --jobs values")
    ap.add_argument("--phases", action="store_true",
                    help="also the main process's peak RSS in each phase (--jobs 1 runs)")
    args = ap.parse_args()
    jobs = [int(j) for j in args.jobs.split(",") if j]
    res: dict[tuple[int, int], dict[str, Any]] = {}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for mult in (1, 10):
            rec = rr.write(tmp / f"len{mult}.mcap", "tum160", args.frames * mult,
                           root=args.data)
            for j in jobs:
                res[(mult, j)] = one_run(rec, tmp / f"out{mult}_{j}", j,
                                         phases=args.phases and j == 1)
                r = res[(mult, j)]
                ws = ", ".join(f"{w:.0f}" for w in r["workers"]) or "-"
                print(f"{r['frames']:>7} frames  --jobs {j}  {r['wall']:7.1f} s  main peak "
                      f"{r['main']:6.0f} MiB  workers {ws} MiB", flush=True)
                if r["phases"]:
                    print("         peak by phase: " + ", ".join(
                        f"{k} {v:.0f} MiB" for k, v in r["phases"].items()), flush=True)
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
    if len(sys.argv) > 1 and sys.argv[1] == "--phase-child":
        phase_child(sys.argv[2:])
    else:
        main()
