"""Fault injection inside the messages: damaged H.264 pictures, Foxglove images and Velodyne
packets in containers that are themselves intact, counted by outcome.

``fuzz_inputs.py`` damages the bytes of whole recordings, which the containers' own checks
(chunk CRCs, record lengths, the bag index) mostly catch before a decoder sees anything. This
campaign writes valid containers whose message payloads are damaged, so that the damage reaches
the decoders: FFmpeg's H.264 decoder, the Foxglove Protobuf and JSON adapters, and the Velodyne
packet reader. Each source is written afresh per case with a seeded random generator:

  video        24 H.264 access units (keyframe every 6) as Foxglove CompressedVideo in
               Protobuf MCAP; a quarter of the units damaged (bits flipped, cut short,
               emptied, zeroed, replaced by random bytes, or doubled), one in twenty under a
               wrong ``format`` string
  pb-image     9 Foxglove RawImage or CompressedImage (PNG) frames with CameraCalibration,
  json-image   Protobuf or JSON encoding; a third of the messages have one field damaged
               (bytes as above, integers set to 0, -1, doubled or 2^31-1, strings replaced,
               arrays shortened)
  velo-bag     4 VLP-16 revolutions (76 packets each) as velodyne_msgs/VelodyneScan; half of
  velo-mcap    the scans with a fifth of their packets damaged in place (a packet keeps its
               1206 bytes: the message type fixes its size), one in ten cut to fewer packets

``frontdiag analyze`` then runs on each case in its own process, and the outcome is put in the
classes of ``fuzz_inputs.py`` (tests/damage.py): exit 0/1 with frames and exit 2 with one line
naming the file meet the contract; a traceback, exit 3, a hang or a changed input do not.
Damage the writer itself refuses (a negative image width in Protobuf's unsigned field) is
counted as "not writable" and not run.

    python benchmarks/fuzz_payloads.py --cases 40 --seed 1
"""

from __future__ import annotations

import argparse
import random
import shutil
import sys
import tempfile
import time
from collections import Counter, defaultdict
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))
sys.path.insert(0, str(HERE))

from damage import GOOD
from fuzz_inputs import run_case
from payload_damage import NOT_WRITABLE_ERRORS, PAYLOAD_SOURCES

NOT_WRITABLE = "not writable"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", type=int, default=20, help="cases per source")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--timeout", type=float, default=120.0, help="seconds before a case hangs")
    ap.add_argument("--only", default="", help="comma list of sources (default: all)")
    ap.add_argument("--show-errors", action="store_true",
                    help="also print the error line of every exit-2 case (to read them)")
    args = ap.parse_args()
    names = [s for s in args.only.split(",") if s] or list(PAYLOAD_SOURCES)
    work = Path(tempfile.mkdtemp(prefix="frontdiag-payloads-"))
    by_source: dict[str, Counter[str]] = defaultdict(Counter)
    bad: list[str] = []
    t0 = time.perf_counter()
    try:
        for name in names:
            suffix, make = PAYLOAD_SOURCES[name]
            for i in range(args.cases):
                rng = random.Random(f"{args.seed}-{name}-{i}")
                rec = work / f"{name}-{i}" / f"{name}{suffix}"
                rec.parent.mkdir(parents=True)
                try:
                    make(rec, rng)
                except NOT_WRITABLE_ERRORS:
                    by_source[name][NOT_WRITABLE] += 1
                    continue
                o, _ = run_case(rec, rec.parent / "out", args.timeout, rules=True)
                by_source[name][o.klass] += 1
                if args.show_errors and o.code == 2:
                    print(f"{name} case {i}: {o.err.strip().splitlines()[0]}")
                if o.klass not in GOOD:
                    tail = o.err.strip().splitlines()[-1:] if o.err.strip() else []
                    bad.append(f"OUTSIDE {o.klass}: {name} case {i} (seed {args.seed}): {tail}")
        total: Counter[str] = Counter()
        for c in by_source.values():
            total.update(c)
        print(f"{sum(total.values())} cases ({args.cases} per source, seed {args.seed}) in "
              f"{time.perf_counter() - t0:.0f} s")
        for klass, n in sorted(total.items(), key=lambda kv: (kv[0] not in GOOD, kv[0])):
            mark = "" if klass in GOOD or klass == NOT_WRITABLE else "   <-- outside the contract"
            print(f"  {n:5d}  {klass}{mark}")
        for name, counts in by_source.items():
            print(f"  {name:10s} " + ", ".join(f"{k}: {v}" for k, v in sorted(counts.items())))
        for line in bad:
            print(line)
        return 0 if not bad else 1
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
