"""One helper to time pipeline stages; tests inject the clock."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

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
