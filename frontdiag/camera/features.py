"""ORB features with grid bucketing and the adaptive per-cell FAST threshold, plus spatial entropy.

ORB-SLAM's extractor, built from OpenCV pieces so that the pyramid is computed once:

1. an 8-level pyramid at scale 1.2, each level resized from the one above it;
2. per level, FAST at ``fast_threshold`` (20); every bucketing cell that yields nothing is re-run
   at ``fast_threshold_min`` (7) — weak features in the right place beat strong ones in the wrong
   place (docs/derivations.md §2);
3. the level's share of the feature budget is proportional to its area (0.6944**level), and is
   spread over the cells round-robin: every cell gives its best corner, then its second best, ...
   until the budget is spent (a per-cell cap that adapts to how many cells have corners);
4. orientation by intensity centroid on the unblurred level, descriptors by OpenCV's ORB on the
   same level image (it blurs and samples the rotated BRIEF pattern).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from operator import attrgetter

import cv2
import numpy as np

ENTROPY_GRID = (8, 6)  # (cols, rows), fixed by the metric's definition
PATCH_SIZE = 31
HALF_PATCH = PATCH_SIZE // 2
EDGE = 19  # ORB-SLAM's EDGE_THRESHOLD: the rotated 31x31 patch plus blur stays inside the level
# Fewest points whose entropy over the 48 cells is read. n points dropped uniformly at random read
# H/Hmax 0.56 on average at n = 10 and 0.71 at n = 20 (1st percentile 0.63), 0.78 at n = 30
# (1st percentile 0.71, 2000 seeded draws each): below 30, a perfectly spread set of points
# reads as clustered (< 0.6) by sampling alone, whatever the scene.
MIN_ENTROPY_POINTS = 30


def spatial_entropy(xy: np.ndarray, width: int, height: int,
                    grid: tuple[int, int] = ENTROPY_GRID) -> tuple[float, int]:
    """Normalised Shannon entropy of keypoint positions over a ``cols x rows`` grid.

    Returns ``(H / log2(cols*rows), occupied_cells)``; NaN when there are no keypoints.
    Uniform -> 1.0; everything in one cell -> 0.0.
    """
    if len(xy) == 0 or width <= 0 or height <= 0:
        return float("nan"), 0
    counts = grid_counts(xy, width, height, grid)
    return entropy_from_counts(counts), int(np.count_nonzero(counts))


def grid_counts(xy: np.ndarray, width: int, height: int,
                grid: tuple[int, int] = ENTROPY_GRID) -> np.ndarray:
    """Keypoints per cell of a ``cols x rows`` grid, as a ``(rows, cols)`` int array."""
    cols, rows = grid
    if len(xy) == 0 or width <= 0 or height <= 0:
        return np.zeros((rows, cols), np.int64)
    cx = np.clip((xy[:, 0] * (cols / width)).astype(np.intp), 0, cols - 1)
    cy = np.clip((xy[:, 1] * (rows / height)).astype(np.intp), 0, rows - 1)
    return np.bincount(cy * cols + cx, minlength=cols * rows).reshape(rows, cols)


def shared_entropy(xy: np.ndarray, shared: np.ndarray, width: int, height: int,
                   grid: tuple[int, int] = ENTROPY_GRID) -> float:
    """``spatial_entropy`` over the cells both views saw (``shared``, ``(rows, cols)`` bool):
    H / log2(cells). Points in an unshared cell (at the edge of the overlap) add their cell."""
    counts = grid_counts(xy, width, height, grid)
    return entropy_from_counts(counts[shared | (counts > 0)])


def entropy_from_counts(counts: np.ndarray) -> float:
    """H / Hmax for a histogram of cell counts (Hmax = log2 of the number of cells)."""
    counts = np.asarray(counts, dtype=np.float64).ravel()
    total = counts.sum()
    if total <= 0 or counts.size < 2:
        return float("nan")
    p = counts[counts > 0] / total
    return float(-(p * np.log2(p)).sum() / math.log2(counts.size))


# Keypoints at pyramid level >= COARSE_LEVEL (scale 1.2**3 = 1.73: each pixel averages ~3 of the
# original's per axis) with a FAST score at the strong threshold are texture at scale. Sensor
# noise and paper grain make corners at the finest levels only: on a still webcam over blank
# paper the detector fills its 1000-keypoint budget while 1 % of its corners repeat in the next
# frame, and 1 of them is strong at level >= 3; textured scenes (real and simulated, 320x240 to
# 1280x720) have 100-300 of the 297 these levels are given (docs/camera.md).
COARSE_LEVEL = 3


# Two corners at scale closer than the ORB patch of the first coarse level (31 px x 1.2**3 = 54 px
# of the original image) belong to one textured structure: the same corner found again at the
# next levels, or two corners of one object. A corner at scale with no other within that distance
# is a stray (a grain cluster or a speck that passed the threshold at one level only).
CONFIRM_PX = PATCH_SIZE * 1.2**COARSE_LEVEL


def coarse_texture(feats: Features, width: int, height: int, strong: float
                   ) -> tuple[int, float]:
    """``(count, hull share)`` of the keypoints at level >= COARSE_LEVEL with a FAST score of at
    least ``strong``: how many, and the share of the image covered by the convex hull of those
    with another of them within CONFIRM_PX (NaN under 3 such points)."""
    sel = (feats.octave >= COARSE_LEVEL) & (feats.response >= strong)
    n = int(np.count_nonzero(sel))
    if n < 3 or width <= 0 or height <= 0:
        return n, float("nan")
    from scipy.spatial import cKDTree  # imported on first use: `frontdiag --help` need not

    xy = feats.xy[sel].astype(np.float64)
    nearest, _ = cKDTree(xy).query(xy, k=2)  # column 0 is the point itself
    kept = xy[nearest[:, 1] <= CONFIRM_PX]
    if len(kept) < 3:
        return n, float("nan")
    hull = cv2.convexHull(np.ascontiguousarray(kept, dtype=np.float32))
    return n, float(cv2.contourArea(hull)) / float(width * height)


def lit_share(gray: np.ndarray, threshold: int) -> float:
    """Share of the pixels brighter than ``threshold`` grey levels (the FAST threshold).

    A FAST corner at threshold t needs ring pixels more than t grey levels from the centre, so
    where no pixel exceeds t none can fire at t; in a view with almost no such pixels the
    detector's corners sit on the few lit pixels (lamps, windows) and, at the lower retry
    threshold, on sensor noise.
    """
    if gray.size == 0:
        return float("nan")
    _, lit = cv2.threshold(gray, threshold, 255, cv2.THRESH_BINARY)  # 255 where > threshold
    return cv2.countNonZero(lit) / float(gray.size)


def level_budgets(n_features: int, n_levels: int, scale_factor: float) -> list[int]:
    """Features per pyramid level, proportional to level area; the remainder goes to the top.

    1000 features, 8 levels, 1.2 -> 323, 224, 156, 108, 75, 52, 36, 26 (docs/derivations.md §2).
    """
    f = 1.0 / (scale_factor * scale_factor)
    shares = [f**i for i in range(n_levels)]
    total = sum(shares)
    out = [round(n_features * s / total) for s in shares[:-1]]
    out.append(max(n_features - sum(out), 0))
    return out


@dataclass(frozen=True)
class Features:
    """Keypoints of one frame in level-0 pixel coordinates, with ORB descriptors."""

    xy: np.ndarray  # (N, 2) float32
    octave: np.ndarray  # (N,) int16
    response: np.ndarray  # (N,) float32
    angle: np.ndarray  # (N,) float32, degrees
    des: np.ndarray  # (N, 32) uint8
    n_weak: int = 0  # keypoints that came from the low-threshold retry

    def __len__(self) -> int:
        return len(self.xy)

    @staticmethod
    def empty() -> Features:
        return Features(np.zeros((0, 2), np.float32), np.zeros(0, np.int16),
                        np.zeros(0, np.float32), np.zeros(0, np.float32),
                        np.zeros((0, 32), np.uint8))


def _circle_weights() -> tuple[np.ndarray, np.ndarray]:
    """x and y moment weights over ORB's circular 31x31 patch, flattened."""
    r = np.arange(-HALF_PATCH, HALF_PATCH + 1, dtype=np.float32)
    xs, ys = np.meshgrid(r, r)
    inside = (xs * xs + ys * ys) <= HALF_PATCH * HALF_PATCH + HALF_PATCH  # ORB's umax disc
    return (xs * inside).ravel(), (ys * inside).ravel()


_RESPONSE = attrgetter("response")
_WX, _WY = _circle_weights()
_W = np.stack([_WX, _WY], axis=1)  # (961, 2)


def ic_angles(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """ORB orientation by intensity centroid, theta = atan2(m01, m10), in degrees [0, 360)."""
    if len(x) == 0:
        return np.zeros(0, np.float32)
    win = np.lib.stride_tricks.sliding_window_view(img, (PATCH_SIZE, PATCH_SIZE))
    patches = win[y - HALF_PATCH, x - HALF_PATCH].reshape(len(x), -1).astype(np.float32)
    m = patches @ _W
    ang = np.degrees(np.arctan2(m[:, 1], m[:, 0]))
    return np.mod(ang, 360.0).astype(np.float32)


def _select_spread(cell: np.ndarray, response: np.ndarray, budget: int) -> np.ndarray:
    """Indices of up to ``budget`` keypoints, round-robin over cells by descending response.

    Every cell gives its best corner, then every cell its second best, and so on; within the
    last round the stronger corners go first. Responses are FAST scores (integers below 256).
    """
    n = len(cell)
    if n <= budget:
        return np.arange(n)
    weak = 255 - np.minimum(response, 255).astype(np.int64)
    order = np.argsort(cell.astype(np.int64) * 256 + weak)
    sc = cell[order]
    rank = np.arange(n) - np.searchsorted(sc, sc)  # position within its cell, best first
    cum = np.cumsum(np.bincount(rank))
    last = int(np.searchsorted(cum, budget))  # the round in which the budget runs out
    full = order[rank < last]
    tier = order[rank == last]
    best = tier[np.argsort(weak[tier], kind="stable")[:budget - len(full)]]
    return np.concatenate([full, best])


def _points(kps: Sequence[cv2.KeyPoint]) -> np.ndarray:
    """(N, 2) float32 positions of keypoints (one C++ call)."""
    return np.asarray(cv2.KeyPoint.convert(kps), np.float32).reshape(-1, 2)


def _runs(mask: np.ndarray) -> list[tuple[int, int, int]]:
    """(row, first col, end col) of every horizontal run of True in a 2-D boolean grid."""
    out = []
    for r, line in enumerate(mask.tolist()):
        c = 0
        while c < len(line):
            if line[c]:
                start = c
                while c < len(line) and line[c]:
                    c += 1
                out.append((r, start, c))
            else:
                c += 1
    return out


class OrbExtractor:
    """Bucketed ORB with the adaptive per-cell FAST threshold; one pyramid per frame."""

    def __init__(self, n_features: int = 1000, n_levels: int = 8, scale_factor: float = 1.2,
                 fast_threshold: int = 20, fast_threshold_min: int = 7,
                 grid_cols: int = 8, grid_rows: int = 6) -> None:
        self.n_levels = n_levels
        self.scale_factor = scale_factor
        self.budgets = level_budgets(n_features, n_levels, scale_factor)
        self.grid = (grid_cols, grid_rows)
        self._fast = cv2.FastFeatureDetector.create(fast_threshold, True)
        self._fast_min = cv2.FastFeatureDetector.create(fast_threshold_min, True)
        self._orb = cv2.ORB.create(nfeatures=n_features, scaleFactor=scale_factor, nlevels=1,
                                   edgeThreshold=EDGE, patchSize=PATCH_SIZE)

    def pyramid(self, gray: np.ndarray) -> list[np.ndarray]:
        h, w = gray.shape
        levels = [gray]
        for lv in range(1, self.n_levels):
            s = self.scale_factor**lv
            size = (round(w / s), round(h / s))
            if min(size) <= 2 * EDGE + 2:
                break
            levels.append(cv2.resize(levels[-1], size, interpolation=cv2.INTER_LINEAR))
        return levels

    def _detect_level(self, img: np.ndarray, budget: int
                      ) -> tuple[list, np.ndarray, np.ndarray, int]:
        """Chosen keypoint objects of one level, their xy and FAST score, and the weak count."""
        h, w = img.shape
        x0, y0, x1, y1 = EDGE, EDGE, w - EDGE, h - EDGE
        cols, rows = self.grid
        cw, ch = (x1 - x0) / cols, (y1 - y0) / rows

        def cells_of(xy: np.ndarray) -> np.ndarray:
            ok = (xy[:, 0] >= x0) & (xy[:, 0] < x1) & (xy[:, 1] >= y0) & (xy[:, 1] < y1)
            cx = np.minimum(((xy[:, 0] - x0) * (1.0 / cw)).astype(np.intp), cols - 1)
            cy = np.minimum(((xy[:, 1] - y0) * (1.0 / ch)).astype(np.intp), rows - 1)
            return np.where(ok, cy * cols + cx, -1)

        kps = list(self._fast.detect(img))
        xy = _points(kps) if kps else np.zeros((0, 2), np.float32)
        cell = cells_of(xy)
        n_strong = len(kps)
        empty = np.bincount(cell[cell >= 0], minlength=cols * rows) == 0
        # Retry the empty cells at the low threshold, on their pixels only: one FAST call per
        # horizontal run of empty cells (with the 3-pixel ring margin FAST needs around it).
        # A corner found in the margin belongs to a neighbouring cell: it is kept only by the
        # run that owns its cell, so no corner is counted twice.
        if empty.any():
            offsets, owners = [], []
            for r, c0, c1 in _runs(empty.reshape(rows, cols)):
                ya, yb = max(int(y0 + r * ch) - 3, 0), int(y0 + (r + 1) * ch) + 4
                xa, xb = max(int(x0 + c0 * cw) - 3, 0), int(x0 + c1 * cw) + 4
                weak = self._fast_min.detect(img[ya:yb, xa:xb])
                if weak:
                    kps += weak
                    offsets.append((len(weak), xa, ya))
                    owners.append((r * cols + c0, r * cols + c1))
            if offsets:
                counts, xa_, ya_ = (np.array(v) for v in zip(*offsets, strict=True))
                wxy = _points(kps[n_strong:])
                wxy[:, 0] += np.repeat(xa_, counts)
                wxy[:, 1] += np.repeat(ya_, counts)
                first, end = (np.repeat(np.array(v), counts) for v in zip(*owners, strict=True))
                wcell = cells_of(wxy)
                wcell[(wcell < first) | (wcell >= end)] = -1
                xy = np.concatenate([xy, wxy])
                cell = np.concatenate([cell, wcell])
        valid = np.flatnonzero(cell >= 0)
        if valid.size == 0:
            return [], np.zeros((0, 2), np.float32), np.zeros(0, np.float32), 0
        response = np.fromiter(map(_RESPONSE, kps), np.float32, len(kps))[valid]
        pick = _select_spread(cell[valid], response, budget)
        chosen = valid[pick]
        out = [kps[i] for i in chosen.tolist()]
        weak_pos = np.flatnonzero(chosen >= n_strong)
        for j in weak_pos.tolist():  # retry keypoints were found in a sub-image
            out[j].pt = (float(xy[chosen[j], 0]), float(xy[chosen[j], 1]))
        return out, xy[chosen], response[pick], len(weak_pos)

    def detect_and_compute(self, gray: np.ndarray) -> Features:
        """Detect, orient and describe; never raises on blank or tiny images."""
        if gray.ndim != 2 or min(gray.shape) <= 2 * EDGE + 2:
            return Features.empty()
        gray = np.ascontiguousarray(gray)
        parts: list[tuple[np.ndarray, ...]] = []
        n_weak = 0
        for lv, img in enumerate(self.pyramid(gray)):
            kps, xy, resp, weak = self._detect_level(img, self.budgets[lv])
            if not kps:
                continue
            ang = ic_angles(img, np.rint(xy[:, 0]).astype(np.intp),
                            np.rint(xy[:, 1]).astype(np.intp))
            for k, a in zip(kps, ang.tolist(), strict=True):
                k.angle = a
            kps_out, des = self._orb.compute(img, kps)
            if des is None or not kps_out:
                continue
            if len(kps_out) != len(kps):  # ORB dropped some near the border: re-read them
                xy = _points(kps_out)
                resp = np.array([k.response for k in kps_out], np.float32)
                ang = np.array([k.angle for k in kps_out], np.float32)
                weak = min(weak, len(kps_out))
            scale = np.float32(self.scale_factor**lv)
            parts.append((xy * scale, np.full(len(xy), lv, np.int16), resp, ang, des))
            n_weak += weak
        if not parts:
            return Features.empty()
        xy_all, oct_all, resp_all, ang_all, des_all = (np.concatenate(c) for c in zip(*parts, strict=True))
        return Features(xy_all.astype(np.float32), oct_all, resp_all, ang_all,
                        np.ascontiguousarray(des_all), n_weak)
