"""The whole `frontdiag analyze` command as a user runs it: start-up, the pass, every output.

The other benchmarks time the pass inside one process with one BLAS thread set beforehand
(``bench_real.py``) or parts of it. This one starts ``frontdiag analyze REC --out DIR`` as a
separate process with the environment it is given (no thread variables set), as a user or a
CI job would, and prints per recording: frames, median wall seconds and frames/s, CPU seconds
(user + sys of the process and its children) and CPU/wall, and peak RSS. A serial pass should
use one core: CPU/wall well above 1 means threads spinning beside it.

With ``--busy`` a second process keeps the other core busy (a pure-Python loop) during every
run, as on a CI runner or a laptop doing something else: a pass that leans on a second thread
slows down there.

With ``--jobs N`` the command runs ``analyze --jobs N`` (time windows on N processes; the
CPU column then counts the workers too, once they have exited).

    python benchmarks/bench_cli.py REC [REC ...] [--runs 5] [--busy] [--jobs N]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any


def _spin(stop: Any) -> None:
    x = 0
    while not stop.is_set():
        for _ in range(100_000):
            x += 1


def one_run(rec: Path, out: Path, jobs: int = 1) -> dict[str, float]:
    """One ``frontdiag analyze`` in a child process: wall and CPU seconds, peak RSS (MiB)."""
    shutil.rmtree(out, ignore_errors=True)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "frontdiag", "analyze", str(rec), "--out",
                           str(out), "--quiet", "--fail-on", "never", "--jobs", str(jobs)],
                          capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"{rec}: frontdiag analyze exited {proc.returncode}: "
                         f"{proc.stderr.strip()[-300:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall": wall, "cpu": cpu, "rss_mib": after.ru_maxrss / 1024}


def frames_of(out: Path) -> int:
    """Rows analysed, every sensor (the manifest's per-topic counts)."""
    counts = json.loads((out / "manifest.json").read_text()).get("counts", {})
    return int(sum(int(c.get("analysed", 0)) for c in counts.values()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("recordings", nargs="+", type=Path)
    ap.add_argument("--runs", type=int, default=5, help="counted runs per recording (after one "
                                                          "not counted)")
    ap.add_argument("--busy", action="store_true",
                    help="keep the other core busy during every run")
    ap.add_argument("--jobs", type=int, default=1, help="analyze --jobs N (default 1)")
    args = ap.parse_args()
    threads = {k: os.environ[k] for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                          "MKL_NUM_THREADS") if k in os.environ}
    print(f"cores {os.cpu_count()}; thread variables set: {threads or 'none'}; "
          f"other core {'busy' if args.busy else 'idle'}; analyze --jobs {args.jobs}")
    stop = mp.Event()
    spinner = mp.Process(target=_spin, args=(stop,), daemon=True) if args.busy else None
    if spinner is not None:
        spinner.start()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            print(f"{'recording':28s} {'frames':>6s} {'wall s':>7s} {'frames/s':>8s} "
                  f"{'cpu s':>6s} {'cpu/wall':>8s} {'peak MiB':>8s}")
            for rec in args.recordings:
                out = Path(tmp) / "out"
                one_run(rec, out, args.jobs)  # warm-up: the file cache, the imports' bytecode
                runs = [one_run(rec, out, args.jobs) for _ in range(args.runs)]
                n = frames_of(out)
                wall = statistics.median(r["wall"] for r in runs)
                cpu = statistics.median(r["cpu"] for r in runs)
                print(f"{rec.name:28s} {n:6d} {wall:7.2f} {n / wall:8.1f} {cpu:6.2f} "
                      f"{cpu / wall:8.2f} {max(r['rss_mib'] for r in runs):8.0f}")
    finally:
        stop.set()
        if spinner is not None:
            spinner.join(timeout=5)


if __name__ == "__main__":
    main()
