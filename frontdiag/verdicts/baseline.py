"""The recording's own robust baseline of a metric, per row: a lower quartile of its neighbours.

Ratio-test rejection, the photometric residual and H/E depend on the scene's texture, the
camera's resolution, rate and lens as much as on the failure: a healthy street at 10 Hz rejects
60-75 % of ORB matches where a textured room at 30 Hz rejects 30 %. So each is read against the
recording's own level as well as against its absolute line.

The baseline of row i is the lower quartile of the metric over the rows of the same topic within
``window_s / 2`` seconds on either side of it (the row itself left out), taking only rows that
the absolute reading does not already flag (``exclude``). All three metrics rise in a failure,
so the scene's healthy level is the level it returns to: a lower quartile stays there while up
to three quarters of the window is disturbed (an episode, a noisier neighbouring area), where a
median would follow a long episode and become the level the episode is compared with. Its
spread is read from the same lower half, (median - lower quartile) / 0.6745, which is the
standard deviation for Gaussian noise.

The window is centred, not trailing: frontdiag reads a finished recording, and a centred window
needs no warm-up: the first seconds of a recording borrow their level from the frames that
follow. Where more than ``gap_intervals`` median frame intervals pass without a row (a cut
between areas, a paused recording, dropped messages), the scene after it may be another: the
window stops at the gap, so each stretch between gaps has a level of its own, and the first
frames after a gap borrow theirs from the frames after them. A row that starts afresh for
another reason (``breaks``: the camera's image size changed, and with it every scene-dependent
level) cuts the window in the same way. Where fewer than ``min_rows``
rows, or less than ``min_share`` of the window's readable rows, are left to form it, the
baseline is NaN and only the absolute line reads the row: a recording that is one long episode
(an aisle from its first frame to its last) has no healthy level of its own to compare with.
``widening_baseline`` first doubles the window for such rows until a level forms (a street that
sits at the absolute line for seconds finds the level of the drive around it).
"""

from __future__ import annotations

import numpy as np

QUARTILE_TO_SIGMA = 0.6745  # median - lower quartile of a Gaussian, in standard deviations


def rolling_baseline(t_s: np.ndarray, x: np.ndarray, window_s: float, min_rows: int,
                     min_share: float, exclude: np.ndarray | None = None,
                     gap_intervals: float = 5.0, rows: np.ndarray | None = None,
                     breaks: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(lower quartile, robust sigma) per row over the other non-excluded rows within
    window_s / 2.

    Rows must be in time order; NaN values and excluded rows never enter a baseline. With
    ``rows`` (indices), only those rows are computed; the others stay NaN. ``breaks`` (bool
    per row) marks rows that start a new stretch, as a gap before them does.
    """
    n = len(x)
    med = np.full(n, np.nan)
    sig = np.full(n, np.nan)
    if n == 0:
        return med, sig
    readable = ~np.isnan(x)
    usable = readable & (np.ones(n, bool) if exclude is None else ~exclude)
    if not np.isfinite(t_s).all():  # no stamps: rows are the clock
        t_s = np.arange(n, dtype=float)
    half = window_s / 2.0
    lo = np.searchsorted(t_s, t_s - half, side="left")
    hi = np.searchsorted(t_s, t_s + half, side="right")
    gap = np.zeros(n, bool) if breaks is None else np.asarray(breaks, bool).copy()
    if n > 2:  # stretches between gaps: the window does not cross one
        dt = np.diff(t_s)
        gap[1:] |= dt > gap_intervals * float(np.median(dt))
    if gap[1:].any():
        gap[0] = False
        seg = np.cumsum(gap)
        first = np.searchsorted(seg, seg, side="left")
        last = np.searchsorted(seg, seg, side="right")
        lo, hi = np.maximum(lo, first), np.minimum(hi, last)
    c_read = np.concatenate([[0], np.cumsum(readable)])
    for i in (range(n) if rows is None else rows.tolist()):
        a, b = int(lo[i]), int(hi[i])
        sel = usable[a:b].copy()
        sel[i - a] = False
        vals = x[a:b][sel]
        n_read = int(c_read[b] - c_read[a]) - int(readable[i])
        if len(vals) < min_rows or len(vals) < min_share * n_read:
            continue
        q25, q50 = np.percentile(vals, [25.0, 50.0])
        med[i] = q25
        sig[i] = (q50 - q25) / QUARTILE_TO_SIGMA
    return med, sig


def widening_baseline(t_s: np.ndarray, x: np.ndarray, window_s: float, min_rows: int,
                      min_share: float, exclude: np.ndarray | None = None,
                      gap_intervals: float = 5.0, max_window_s: float = np.inf,
                      breaks: np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``rolling_baseline``, and where its window leaves a row without a level, the nearest
    level of the recording's own: the window doubles until one forms, until it spans the whole
    recording (never across a gap or a break) or until it reaches ``max_window_s``.

    Returns (lower quartile, robust sigma, window used in seconds); all NaN on the rows where
    no level formed at any width.
    """
    base, sig = rolling_baseline(t_s, x, window_s, min_rows, min_share, exclude, gap_intervals,
                                 breaks=breaks)
    used = np.where(np.isnan(base), np.nan, float(window_s))
    n = len(x)
    if n < 2:
        return base, sig, used
    clock = t_s if np.isfinite(t_s).all() else np.arange(n, dtype=float)
    # a window 2 x the recording's span reaches every row from any row
    whole = min(2.0 * float(clock[-1] - clock[0]), float(max_window_s))
    w = float(window_s)
    while w < whole and np.isnan(base).any():
        w = min(2.0 * w, whole)
        todo = np.flatnonzero(np.isnan(base))
        b, sg = rolling_baseline(t_s, x, w, min_rows, min_share, exclude, gap_intervals,
                                 rows=todo, breaks=breaks)
        got = todo[~np.isnan(b[todo])]
        base[got], sig[got], used[got] = b[got], sg[got], w
    return base, sig, used
