"""Calibration on this machine gives positive coefficients that agree between runs."""

from __future__ import annotations

import math

from frontdiag.budget.calibrate import calibrate
from frontdiag.budget.targets import COEFFICIENTS


def test_quick_calibration_is_positive_and_complete() -> None:
    # same code path as --calibrate, fewer repeats. Agreement between two calibrations is a
    # property of the machine's load, not of the code: benchmarks/bench_calibrate.py prints it.
    a = calibrate(repeats=3)
    assert set(a.coefficients) == set(COEFFICIENTS)
    for name, c in a.coefficients.items():
        assert math.isfinite(c.value) and c.value > 0, name
        assert c.how == "measured" and c.source, name
        assert c.spread is not None and c.spread >= 1.0, name  # p90/p10 of its timings
    assert a.provenance == "calibrated"
    assert a.machine["threads"] == "1" and a.machine["hostname"]
