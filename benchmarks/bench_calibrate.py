"""Repeatability of `frontdiag budget --calibrate` on this machine.

    python benchmarks/bench_calibrate.py [--runs 3] [--repeats 15]

Runs the calibration (the same code path as `frontdiag budget --calibrate`) several times and
prints, per coefficient, every run's value, its own spread (p90/p10 of its timed repeats, which
the budget output reports as UNRELIABLE above 2) and the largest ratio between runs. A
calibration is only as good as its repeatability: on a quiet machine the runs agree within a
few per cent; on a loaded one the spread column says which figures not to trust. A script that
prints figures, not a test: timing agreement is a property of the machine's load, not of the
code.
"""

from __future__ import annotations

import argparse
import os
import time

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from frontdiag.budget.calibrate import calibrate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3, help="calibrations to compare (default 3)")
    ap.add_argument("--repeats", type=int, default=15,
                    help="timed repeats per coefficient in each run (default 15, as --calibrate)")
    args = ap.parse_args()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"load average (1 min) at start: {load:.2f}")
    runs = []
    for k in range(args.runs):
        t0 = time.perf_counter()
        runs.append(calibrate(repeats=args.repeats))
        print(f"run {k + 1}: {time.perf_counter() - t0:.1f} s")
    names = list(runs[0].coefficients)
    width = max(len(n) for n in names)
    head = "  ".join(f"run {k + 1:<2d} (spread)" for k in range(args.runs))
    print(f"\n{'coefficient':<{width}}  {head}  max/min")
    worst = 1.0
    for name in names:
        vals = [r.coefficients[name].value for r in runs]
        cells = "  ".join(f"{v:9.4g} ({r.coefficients[name].spread or 1.0:4.1f})"
                          for v, r in zip(vals, runs, strict=True))
        ratio = max(vals) / min(vals)
        worst = max(worst, ratio)
        print(f"{name:<{width}}  {cells}  {ratio:6.2f}x")
    print(f"\nlargest disagreement between runs: {worst:.2f}x")


if __name__ == "__main__":
    main()
