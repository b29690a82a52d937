"""Photometric checks at tracked features (docs/derivations.md §5).

For the features matched between the previous and the current frame (at most 256, evenly
spaced), an 8x8 patch is taken around the keypoint in each image. The residual I2 - I1 over those pixels shows an exposure
step (a 20% gain on a 120-level pixel gives 24 levels where a tracked pixel normally sits at
3-5), and the affine brightness model I2 = a*I1 + b fitted over the same patches names it.

The gain and bias are fitted over the patch pixels by geometric-mean (reduced major axis)
regression, a = sign(cov) * std(I2) / std(I1), b = mean(I2) - a * mean(I1), which is the least
squares fit that treats I1 and I2 symmetrically. Ordinary least squares of I2 on I1 is biased
here: keypoints are localised to about a pixel, so I1 is a noisy regressor and OLS shrinks a
towards 0 — on a synthetic textured pair with unchanged exposure it returns a = 0.89 where the
symmetric fit returns 1.00 (and 1.19 / 0.80 for applied gains of 1.2 / 0.8). Patches holding a
clipped pixel (0 or 255) are left out of the fit, since a saturated pixel does not follow
a*I + b, and one re-fit without the patches beyond 3 robust sigmas keeps a few wrong matches
from dragging it.

The brightness ratio is the median over the unclipped patches of mean(patch in I2) /
mean(patch in I1): how much brighter the same surfaces are, the quantity an exposure or gain
change multiplies. Unlike the pixel residual it needs the patches only to cover the same
surface, not to align to the pixel, so it holds between frames far apart (photographs a second
apart, a wide turn) where misalignment alone lifts the residual to 15-45 grey levels; unlike
the frame mean it is not moved by the view showing a brighter or darker part of the scene. It is
left out (NaN) under MIN_RATIO_PATCHES patches. Its standard error, ``brightness_ratio_se``, is
that of the median of the log ratios: sqrt(pi/2) x 1.4826 MAD / sqrt(n), the large-sample
standard error of a median of normally scattered values with the MAD as a robust sigma. The
patch ratios of one frame pair scatter little under a gain change of a matte scene (MAD 0.01-0.06
in the simulator) and much where the surfaces themselves change brightness with the view (0.12-
0.23 on a glossy print seen 20-30 degrees apart), which is what the error carries to the rule.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

PATCH = 8
MAX_PATCHES = 256  # 16k pixels: plenty for a median and a two-parameter fit
MIN_RATIO_PATCHES = 16  # a median of fewer patch ratios is at the mercy of two wrong matches
DARK_PATCH = 4.0  # a patch mean under 4 grey levels is sensor black: its ratio is noise


@dataclass(frozen=True)
class Photometric:
    residual_med: float = float("nan")
    gain: float = float("nan")
    bias: float = float("nan")
    residual_affine_med: float = float("nan")
    n_patches: int = 0
    brightness_ratio: float = float("nan")
    brightness_ratio_se: float = float("nan")  # standard error of log(brightness_ratio)


def _corners(shape: tuple[int, ...], xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Top-left corners of the PATCHxPATCH patches around xy, and which of them fit."""
    h, w = shape[:2]
    x0 = np.rint(xy[:, 0]).astype(np.intp) - PATCH // 2
    y0 = np.rint(xy[:, 1]).astype(np.intp) - PATCH // 2
    return x0, y0, (x0 >= 0) & (y0 >= 0) & (x0 + PATCH <= w) & (y0 + PATCH <= h)


def _patches(img: np.ndarray, x0: np.ndarray, y0: np.ndarray) -> np.ndarray:
    win = np.lib.stride_tricks.sliding_window_view(img, (PATCH, PATCH))
    return win[y0, x0].reshape(-1, PATCH * PATCH).astype(np.float32)


def _fit_affine(i1: np.ndarray, i2: np.ndarray) -> tuple[float, float]:
    """Geometric-mean regression of i2 on i1 (symmetric in the two images)."""
    s1, s2 = float(np.std(i1)), float(np.std(i2))
    if s1 < 1e-6:
        return float("nan"), float("nan")
    c = float(np.mean((i1 - i1.mean()) * (i2 - i2.mean())))
    a = math.copysign(s2 / s1, c)
    return a, float(i2.mean() - a * i1.mean())


def photometric(prev: np.ndarray, cur: np.ndarray, xy_prev: np.ndarray, xy_cur: np.ndarray,
                max_patches: int = MAX_PATCHES) -> Photometric:
    """Median |I2 - I1| over patches at tracked features, and the affine gain/bias."""
    if len(xy_prev) == 0 or prev.ndim != 2 or cur.ndim != 2:
        return Photometric()
    x1, y1, ok1 = _corners(prev.shape, xy_prev)
    x2, y2, ok2 = _corners(cur.shape, xy_cur)
    idx = np.flatnonzero(ok1 & ok2)
    if len(idx) == 0:
        return Photometric()
    if len(idx) > max_patches:  # evenly spaced subset: the medians do not need more
        idx = idx[np.linspace(0, len(idx) - 1, max_patches).astype(np.intp)]
    p1 = _patches(prev, x1[idx], y1[idx])
    p2 = _patches(cur, x2[idx], y2[idx])
    res = float(np.median(np.abs(p2 - p1)))
    unclipped = ~(((p1 <= 0) | (p1 >= 255) | (p2 <= 0) | (p2 >= 255)).any(axis=1))
    q1, q2 = p1[unclipped], p2[unclipped]
    ratio, ratio_se = _brightness_ratio(q1, q2)
    if len(q1) < 3:
        return Photometric(res, n_patches=len(p1), brightness_ratio=ratio,
                           brightness_ratio_se=ratio_se)
    a, b = _fit_affine(q1, q2)
    if not math.isfinite(a):
        return Photometric(res, n_patches=len(p1), brightness_ratio=ratio,
                           brightness_ratio_se=ratio_se)
    r = (q2 - (a * q1 + b)).mean(axis=1)  # per-patch mean residual
    mad = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    keep = np.abs(r - np.median(r)) <= 3.0 * max(mad, 0.5)
    if 3 <= keep.sum() < len(keep):
        a2, b2 = _fit_affine(q1[keep], q2[keep])
        if math.isfinite(a2):
            a, b = a2, b2
    res_aff = float(np.median(np.abs(p2 - (a * p1 + b))))
    return Photometric(res, a, b, res_aff, len(p1), ratio, ratio_se)


def _brightness_ratio(q1: np.ndarray, q2: np.ndarray) -> tuple[float, float]:
    """Median over patch pairs of mean(I2 patch) / mean(I1 patch), and the standard error of its
    log (module docstring); NaN under MIN_RATIO_PATCHES pairs whose means are above sensor
    black."""
    m1, m2 = q1.mean(axis=1), q2.mean(axis=1)
    lit = (m1 >= DARK_PATCH) & (m2 >= DARK_PATCH)
    n = int(lit.sum())
    if n < MIN_RATIO_PATCHES:
        return float("nan"), float("nan")
    r = m2[lit] / m1[lit]
    log_r = np.log(r)
    mad = 1.4826 * float(np.median(np.abs(log_r - np.median(log_r))))
    return float(np.median(r)), math.sqrt(math.pi / 2) * mad / math.sqrt(n)
