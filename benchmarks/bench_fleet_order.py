"""Fleet scheduling, A/B in one run: the recordings in the given order on a worker server that
imports only the frontend, against largest first on a server that also preloads what a fleet
worker imports (pandas, Arrow, the rules), with one process as the reference.

    python benchmarks/bench_fleet_order.py --data ../shared/data [--rounds 3] [--frames 90]

The three variants are interleaved, ``--rounds`` times, each from a fresh worker server started
before the planning (as `frontdiag analyze DIR --out DIR --jobs 2` does); the best time of each
is printed with the speed-ups against one process.
"""

from __future__ import annotations

import argparse
import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import real_recordings as rr
from bench_real import fresh_worker_server


def main() -> None:
    import frontdiag.fleet as fleet
    import frontdiag.parallel as parallel
    from frontdiag.api import AnalysisOptions

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=rr.DATA, help="../shared/data")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--frames", type=int, default=90, help="frames per recording")
    args = ap.parse_args()
    largest_first, full = fleet.largest_first, parallel.FLEET_PRELOAD
    variants = {
        "one process": (1, largest_first, full),
        "given order, lean server": (2, lambda tasks: list(range(len(tasks))),
                                     parallel.WINDOW_PRELOAD),
        "largest first, fleet preload": (2, largest_first, full),
    }
    best = dict.fromkeys(variants, float("inf"))
    with tempfile.TemporaryDirectory() as tmpd:
        tmp = Path(tmpd)
        (tmp / "in").mkdir()
        keys = ("kitti", "euroc", "tum")
        logs = [rr.write(tmp / "in" / f"rec{i:02d}.mcap", keys[i % 3], args.frames,
                         root=args.data, first=i) for i in range(10)]
        for r in range(args.rounds):
            for name, (jobs, order, preload) in variants.items():
                fresh_worker_server()
                fleet.largest_first = order  # type: ignore[assignment]
                parallel.FLEET_PRELOAD = preload
                t0 = time.perf_counter()
                if jobs > 1:
                    parallel.prestart(preload)
                tasks = fleet.plan_tasks(logs, tmp / f"round{r}" / name.replace(" ", "_").replace(",", ""),
                                         AnalysisOptions())
                fleet.run_local(tasks, jobs)
                best[name] = min(best[name], time.perf_counter() - t0)
        fleet.largest_first, parallel.FLEET_PRELOAD = largest_first, full
    ref = best["one process"]
    print(f"fleet of 10 recordings x {args.frames} frames, best of {args.rounds} interleaved "
          "rounds:")
    for name, s in best.items():
        print(f"  {name:30s} {s:6.2f} s  speed-up {ref / s:4.2f}x")
    print(f"load average (1 min) at end {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
