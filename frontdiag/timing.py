"""One helper to time pipeline stages (tests inject the clock), and a stream's frame rate."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

Clock = Callable[[], float]


class StageTimer:
    """Accumulates milliseconds per named stage for one frame.

    >>> t = StageTimer(clock=iter([0.0, 0.002]).__next__)
    >>> with t("detect"):
    ...     pass
    >>> t.ms["detect"]
    2.0
    """

    def __init__(self, clock: Clock = time.perf_counter) -> None:
        self._clock = clock
        self.ms: dict[str, float] = {}

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        start = self._clock()
        try:
            yield
        finally:
            self.ms[stage] = self.ms.get(stage, 0.0) + (self._clock() - start) * 1e3

    def total(self) -> float:
        return sum(self.ms.values())


class GapDetector:
    """Tells a gap in a stream of analysed stamps: a pause of the recording or a jump to another
    place, across which a frontend's motion prior and map no longer apply.

    A gap is an interval longer than ``factor`` times the median of the recent intervals and
    longer than ``min_gap_s`` (so dropped frames and ``--stride`` are not gaps); the first
    ``min_history`` intervals only teach the stream's rate. Stamps that go backwards are not gaps
    (they are reported as non-monotonic elsewhere).

    >>> g = GapDetector()
    >>> [g.observe(int(t * 1e9)) for t in (0.0, 0.1, 0.2, 0.3, 2.3, 2.4)]
    [False, False, False, False, True, False]
    """

    def __init__(self, min_gap_s: float = 0.5, factor: float = 5.0, window: int = 20,
                 min_history: int = 3) -> None:
        self.min_gap_s = min_gap_s
        self.min_history = min_history
        self.factor = factor
        self._dts: list[float] = []
        self._window = window
        self._last: int | None = None
        self.count = 0

    def observe(self, t_ns: int) -> bool:
        last, self._last = self._last, t_ns
        if last is None or t_ns <= last:
            return False
        dt = (t_ns - last) * 1e-9
        if len(self._dts) < self.min_history:
            self._dts.append(dt)
            return False
        typical = sorted(self._dts)[len(self._dts) // 2]
        gap = dt > max(self.min_gap_s, self.factor * typical)
        if gap:
            self.count += 1
        else:
            self._dts = [*self._dts, dt][-self._window:]
        return gap


def median_rate_hz(t_ns: Any) -> float:
    """Frames per second of a stream from its stamps (ns, any order): 1 / the median positive
    step between them; NaN without two distinct stamps."""
    import numpy as np

    t = np.asarray(t_ns, dtype=np.float64)
    step = np.diff(np.sort(t[~np.isnan(t)]))
    step = step[step > 0]
    return 1e9 / float(np.median(step)) if step.size else float("nan")
