"""Unguided Hamming matching: Lowe ratio test and mutual consistency from ONE distance matrix.

The whole query-by-train Hamming matrix is computed once, exactly, by FAISS's popcount kernel
(``faiss.hammings``: XOR + hardware popcount on the packed 256-bit descriptors, about 0.2 ms for
1000 x 1000 on one core). Both slices of the matrix the reference figures asks for come out of it: the
row's two best (ratio test) and the column's best (mutual consistency).
``cv2.BFMatcher(crossCheck=True)`` cannot be combined with ``knnMatch(k=2)``, and running the kNN
in both directions would cost more than ORB itself (docs/derivations.md §3);
``benchmarks/bench_camera.py`` measures the alternatives side by side.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

N_BITS = 256
N_BYTES = N_BITS // 8
# ORB-SLAM's "good match" Hamming distance for ORB (TH_LOW, Mur-Artal et al. 2015): a candidate
# this close is a plausible partner, so a query refused by the ratio test with its second
# candidate this close had two plausible partners (ambiguity), not none (an unmatched feature)
GOOD_MATCH_BITS = 50

_faiss: Any = None


def faiss_module() -> Any:
    """The faiss module, imported on first use (``parallel.one_blas_thread`` loads it before
    limiting BLAS, as faiss carries its own OpenBLAS)."""
    global _faiss
    if _faiss is None:
        import faiss  # imported on first use: `frontdiag --help` need not load it

        _faiss = faiss
    return _faiss


def hamming_matrix(q_des: np.ndarray, t_des: np.ndarray) -> np.ndarray:
    """Exact Hamming distances (int32, ``(len(q), len(t))``) between packed ORB descriptors."""
    q = np.ascontiguousarray(q_des, dtype=np.uint8)
    t = np.ascontiguousarray(t_des, dtype=np.uint8)
    if q.ndim != 2 or t.ndim != 2 or q.shape[1] != t.shape[1]:
        raise ValueError(f"descriptor shapes differ: {q.shape} vs {t.shape}")
    out = np.empty((len(q), len(t)), np.int32)
    if len(q) == 0 or len(t) == 0:
        return out
    faiss = faiss_module()
    faiss.hammings(faiss.swig_ptr(q), faiss.swig_ptr(t), len(q), len(t), q.shape[1],
                   faiss.swig_ptr(out))
    return out


@dataclass(frozen=True)
class Matches:
    """Accepted pairs (query index, train index) and the statistics of the test."""

    query: np.ndarray  # (M,) intp
    train: np.ndarray  # (M,) intp
    n_putative: int  # query features that had two candidates (the ratio test applies)
    n_ratio_rejected: int  # of those, how many failed d1 < ratio * d2
    n_ratio_ambiguous: int = 0  # of the rejected, how many had d2 <= GOOD_MATCH_BITS
    d_accepted_med: float = float("nan")  # median best distance (bits) of the ratio-passed queries

    @property
    def ratio_reject_rate(self) -> float:
        return self.n_ratio_rejected / self.n_putative if self.n_putative else float("nan")

    @property
    def ratio_ambiguous_rate(self) -> float:
        """Share of query features refused with two plausible partners (both candidates within
        GOOD_MATCH_BITS): repetition's share of the rejection; refusals of features that no
        candidate resembles (viewpoint change, blur, new view) do not count."""
        return self.n_ratio_ambiguous / self.n_putative if self.n_putative else float("nan")

    @staticmethod
    def none() -> Matches:
        empty = np.zeros(0, np.intp)
        return Matches(empty, empty, 0, 0)


def match(q_des: np.ndarray, t_des: np.ndarray, ratio: float = 0.8,
          mutual: bool = True) -> Matches:
    """Nearest neighbour of every query among all train descriptors, with both tests.

    ``ratio_reject_rate`` counts every query whose best match fails d1 < ratio*d2, regardless
    of the mutual check: it is the global repetitive-structure statistic.
    Ties resolve to the lowest index, in rows and in columns, so the result is deterministic.
    """
    nq, nt = len(q_des), len(t_des)
    if nq == 0 or nt < 2:
        return Matches.none()
    d = hamming_matrix(q_des, t_des)
    rows = np.arange(nq)
    j1 = d.argmin(axis=1)
    d1 = d[rows, j1]
    col_best = d.min(axis=0) if mutual else None
    d[rows, j1] = N_BITS + 1
    d2 = d.min(axis=1)
    passed = d1 < ratio * d2
    keep = passed
    if col_best is not None:
        keep = passed & (d1 <= col_best[j1])
    q = np.flatnonzero(keep)
    t = j1[q]
    if col_best is not None and len(q):
        # a tie for a column's best leaves several queries pointing at it: keep the first
        _, first = np.unique(t, return_index=True)
        if len(first) < len(q):
            first.sort()
            q, t = q[first], t[first]
    ambiguous = ~passed & (d2 <= GOOD_MATCH_BITS)
    d_acc = float(np.median(d1[passed])) if passed.any() else float("nan")
    return Matches(q, t, nq, int(nq - np.count_nonzero(passed)),
                   int(np.count_nonzero(ambiguous)), d_acc)


def copy_line_bits(d_accepted_med: float, ratio: float) -> float:
    """The distance within which a copy in the same frame makes the ratio test refuse a typical
    match: the frame's median accepted distance over the ratio, that distance capped at the
    good-match distance (beyond it no candidate is a plausible partner, and a frame whose
    accepted matches are that poor would count chance neighbours as copies). Where the ratio
    test accepted nothing (a pattern so regular that every feature has a twin) there is no
    typical distance: a copy within the good-match distance itself is a plausible partner."""
    if not np.isfinite(d_accepted_med):
        return float(GOOD_MATCH_BITS)
    return min(d_accepted_med, GOOD_MATCH_BITS) / ratio


def in_frame_twin_rate(des: np.ndarray, xy: np.ndarray, octave: np.ndarray, max_bits: float,
                       scale_factor: float = 1.2, patch_px: float = 31.0) -> float:
    """Share of one frame's keypoints that have a copy elsewhere in the same frame: another
    keypoint whose descriptor lies within ``max_bits`` of theirs, further away than half an ORB
    patch at the coarser of the two pyramid levels (closer ones describe overlapping pixels: the
    same corner found again, not a copy).

    With ``max_bits`` the frame's typical accepted match distance over the ratio (d / ratio),
    such a keypoint's true match in the next frame is refused by the ratio test whenever its copy
    is seen there too: it is the scene repeating itself, read in one image, so neither the frame
    rate nor the motion between the frames enters it except through that typical distance.
    NaN with fewer than two keypoints or no distance line."""
    n = len(des)
    if n < 2 or not np.isfinite(max_bits):
        return float("nan")
    d = hamming_matrix(des, des)
    np.fill_diagonal(d, N_BITS + 1)
    p = np.asarray(xy, np.float64)
    radius = 0.5 * patch_px * scale_factor ** np.asarray(octave, np.float64)
    # each row's nearest descriptor; where it is the same corner (within half a patch), set it
    # aside and take the next, only for rows still within max_bits: a few passes over few rows,
    # instead of every pair of keypoints within the largest radius
    copy = np.zeros(n, bool)
    rows = np.arange(n)
    j = d.argmin(axis=1)
    while len(rows):
        close = d[rows, j] <= max_bits
        rows, j = rows[close], j[close]
        gap = p[rows] - p[j]
        same = np.einsum("ij,ij->i", gap, gap) < np.maximum(radius[rows], radius[j]) ** 2
        copy[rows[~same]] = True
        rows, j = rows[same], j[same]
        if len(rows):
            d[rows, j] = N_BITS + 1
            j = d[rows].argmin(axis=1)
    return float(np.count_nonzero(copy)) / n
