"""Fault-injection campaign: damaged and odd recordings of every container, counted by outcome.

Each case is a copy of a small valid recording (written here, in a temporary folder) with one
damage from ``tests/damage.py`` at seeded random places, or a valid recording under an awkward
name. ``frontdiag analyze`` runs on it in its own process with a time limit, and the outcome is
put in one class:

  exit 0/1 with frames      contract met: the recording was read
  exit 2 one line           contract met: one ``error:`` line naming the file (+ its hint)
  exit 0/1 WITHOUT frames   a pass that analysed nothing
  exit 2 NOT one line       several lines (an error and its hint count as one)
  exit 2 NOT naming the file
  exit 3 / traceback / hang / changed input

Usage (from the repository root)::

    python benchmarks/fuzz_inputs.py --cases 100 --seed 1 --timeout 120 [--jobs 2]

``--cases`` is per container and damage kind. Prints the counts per class and per container,
and every case outside the contract with the command that reproduces it (the damaged files are
kept in ``--keep DIR`` when given). While it runs, stderr says how many cases are done (every
tenth of them) and names each case outside the contract as it is found; stopped by Ctrl-C or
by a ``timeout`` around it (SIGTERM), it lets the running cases finish and prints the summary
of the finished ones.

Parallel windows (``analyze --jobs N``) on damaged input::

    python benchmarks/fuzz_inputs.py --cases 1 --frames 120 --analyze-jobs 2

runs every case twice, with ``--jobs 2`` and serially, and adds one more class, "jobs N differs
from serial", for a case whose exit code, frame indices, verdicts or diagnostics.mcap messages
(topic and log time of each) differ between the two (recordings under 100 frames are never
split, hence ``--frames``).
"""

from __future__ import annotations

import argparse
import hashlib
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter, defaultdict
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from damage import (
    DAMAGE,
    FRAMES,
    GOOD,
    SOURCES,
    Outcome,
    damaged_copy,
    fingerprint,
    make_source,
    odd_copies,
)

DIFFERS = "jobs N differs from serial"


def _table_key(out: Path) -> tuple[object, ...]:
    """What must not depend on the number of workers: frame indices and verdicts."""
    frames = out / "frames.parquet"
    if not frames.exists():
        return ()
    import pandas as pd

    t = pd.read_parquet(frames)
    cols = [c for c in ("sensor", "frame", "status", "verdict", "rules") if c in t.columns]
    return tuple(map(tuple, t[cols].astype(str).to_numpy()))


def _diagnostics_key(out: Path) -> tuple[object, ...]:
    """What diagnostics.mcap must hold whatever the number of workers: every message's topic
    and log time (the annotations and LiDAR points of every frame, the row messages on the
    recording's clock), in log-time order per topic."""
    path = out / "diagnostics.mcap"
    if not path.exists():
        return ()
    from frontdiag.io.readers import stream_mcap

    with open(path, "rb") as f:
        seen = [(channel.topic, msg.log_time) for _, channel, msg in stream_mcap(f, None)]
    return tuple(sorted(seen))


def run_case(rec: Path, out: Path, timeout: float, analyze_jobs: int = 1,
             rules: bool = False) -> tuple[Outcome, float]:
    """One analyze run on ``rec``; with ``analyze_jobs`` > 1 a ``--jobs`` run with the rules,
    then the serial run it must equal (the table, the verdicts, the exit code and the
    messages of diagnostics.mcap)."""
    if analyze_jobs > 1:
        par_out = out.with_name(out.name + "-jobs")
        par, seconds = run_case(rec, par_out, timeout, -analyze_jobs, rules=True)
        ser, _ = run_case(rec, out, timeout, rules=True)
        if (par.klass in GOOD and ser.klass in GOOD
                and (par.code, par.rows, _table_key(par_out), _diagnostics_key(par_out))
                != (ser.code, ser.rows, _table_key(out), _diagnostics_key(out))):
            return Outcome(par.code, par.rows, f"{DIFFERS}: exit {par.code} vs {ser.code}, "
                           f"{par.rows} vs {ser.rows} rows", par.changed, str(rec),
                           forced=DIFFERS), seconds
        return par, seconds
    before = fingerprint(rec)
    extra = ["--jobs", str(-analyze_jobs)] if analyze_jobs < 0 else []
    extra += [] if rules else ["--no-rules"]
    cmd = [sys.executable, "-m", "frontdiag", "analyze", str(rec), "--out", str(out),
           "--fail-on", "never", "-q", *extra]
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        code: int | None = proc.returncode
        err = proc.stderr
    except subprocess.TimeoutExpired:
        code, err = None, ""
    seconds = time.perf_counter() - t0
    rows = 0
    frames = out / "frames.parquet"
    if frames.exists():
        import pandas as pd

        rows = len(pd.read_parquet(frames))
    return Outcome(code, rows, err, fingerprint(rec) != before, str(rec)), seconds


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", type=int, default=20, help="cases per container and damage kind")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--timeout", type=float, default=120.0, help="seconds before a case hangs")
    ap.add_argument("--jobs", type=int, default=1, help="cases run at once")
    ap.add_argument("--frames", type=int, default=FRAMES,
                    help=f"camera frames per source recording (default {FRAMES})")
    ap.add_argument("--analyze-jobs", type=int, default=1,
                    help="also run analyze --jobs N on every case and compare with the serial run")
    ap.add_argument("--keep", type=Path, default=None,
                    help="copy the inputs of cases outside the contract here")
    args = ap.parse_args()
    rng = random.Random(args.seed)
    work = Path(tempfile.mkdtemp(prefix="frontdiag-fuzz-"))
    try:
        sources = {c: make_source(work / "src" / c, c, n=args.frames) for c in SOURCES}
        cases: list[tuple[str, str, Path]] = []  # (container, kind, input)
        for container, src in sources.items():
            for kind in sorted(DAMAGE):
                for i in range(args.cases):
                    a, b = rng.random(), rng.random()
                    dest = work / "cases" / f"{container}-{kind}-{i}" / src.name
                    cases.append((container, f"{kind} a={a:.4f} b={b:.4f}",
                                  damaged_copy(src, dest, kind, a, b)))
            for rec in odd_copies(src, work / "odd" / container, container):
                cases.append((container, f"odd name {rec.name!r}", rec))

        def one(case: tuple[str, str, Path]) -> tuple[str, str, Path, Outcome, float]:
            container, kind, rec = case
            o, s = run_case(rec, rec.parent / "out", args.timeout, args.analyze_jobs)
            return container, kind, rec, o, s

        def stop(signum: int, frame: Any) -> None:
            raise KeyboardInterrupt

        # a `timeout` around the campaign (SIGTERM) or Ctrl-C: the cases finished are counted
        signal.signal(signal.SIGTERM, stop)
        t0 = time.perf_counter()
        results: list[tuple[str, str, Path, Outcome, float]] = []
        step = max(1, len(cases) // 10)
        pool = ThreadPoolExecutor(max(1, args.jobs))
        try:
            for k, r in enumerate(pool.map(one, cases), 1):
                results.append(r)
                if r[3].klass not in GOOD:  # said at once, not only in the summary
                    print(f"OUTSIDE {r[3].klass}: {r[0]} {r[1]}", file=sys.stderr, flush=True)
                if k % step == 0:
                    print(f"{k}/{len(cases)} cases, {time.perf_counter() - t0:.0f} s",
                          file=sys.stderr, flush=True)
        except KeyboardInterrupt:
            print(f"stopped after {len(results)} of {len(cases)} cases (those running are "
                  "left to finish); the summary counts the finished ones", file=sys.stderr,
                  flush=True)
        finally:
            pool.shutdown(wait=True, cancel_futures=True)
        if not results:
            return 1
        wall = time.perf_counter() - t0
        by_class: Counter[str] = Counter()
        by_container: dict[str, Counter[str]] = defaultdict(Counter)
        bad = []
        seconds = sorted(s for *_, s in results)
        for container, kind, rec, o, _ in results:
            klass = o.klass
            by_class[klass] += 1
            by_container[container][klass] += 1
            if klass not in GOOD:
                bad.append((container, kind, rec, klass, o.err.strip().splitlines()[-1:]))
        print(f"{len(results)} cases ({args.cases} per container and damage kind, seed "
              f"{args.seed}, timeout {args.timeout:g} s) in {wall:.0f} s; per case median "
              f"{seconds[len(seconds) // 2]:.2f} s, max {seconds[-1]:.2f} s")
        for klass, n in sorted(by_class.items(), key=lambda kv: (kv[0] not in GOOD, kv[0])):
            print(f"  {n:5d}  {klass}{'' if klass in GOOD else '   <-- outside the contract'}")
        width = max((len(c) for c in by_container), default=0)
        for container, counts in sorted(by_container.items()):
            print(f"  {container:{width}s} " + ", ".join(f"{k}: {v}"
                                                       for k, v in sorted(counts.items())))
        for container, kind, rec, klass, tail in bad:
            print(f"OUTSIDE {klass}: {container} {kind}: {tail}")
            if args.keep is not None:
                dest = args.keep / hashlib.sha1(str(rec).encode()).hexdigest()[:8]
                shutil.copytree(rec.parent, dest, dirs_exist_ok=True)
                print(f"   kept in {dest}")
        return 0 if not bad else 1
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
