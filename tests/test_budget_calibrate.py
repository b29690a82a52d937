"""Calibration on this machine gives positive coefficients that agree between runs."""

from __future__ import annotations

import math

from frontdiag.budget.calibrate import calibrate
from frontdiag.budget.targets import COEFFICIENTS


def test_quick_calibration_is_positive_and_stable() -> None:
    # same code path as --calibrate, fewer repeats; no wall-clock limits, only agreement
    a, b = calibrate(repeats=3), calibrate(repeats=3)
    assert set(a.coefficients) == set(COEFFICIENTS)
    for name, c in a.coefficients.items():
        other = b.coefficients[name].value
        assert math.isfinite(c.value) and c.value > 0, name
        assert c.how == "measured" and c.source, name
        assert c.spread is not None and c.spread >= 1.0, name  # p90/p10 of its timings
        # two calibrations agree, or the disagreement is flagged: on a busy machine one of
        # them saw its repeats spread (p90/p10 > 2), which the budget output reports as
        # UNRELIABLE; agreement is not a property a loaded machine can promise
        noisy = max(c.spread or 1.0, b.coefficients[name].spread or 1.0) > 2.0
        assert noisy or 1 / 8 < c.value / other < 8, (name, c.value, other)
    assert a.provenance == "calibrated"
    assert a.machine["threads"] == "1" and a.machine["hostname"]
