"""Unguided Hamming matching: Lowe ratio test and mutual consistency from ONE distance matrix.

The whole query-by-train Hamming matrix comes from a single float GEMM: with descriptor bits
mapped to +/-1, the dot product of two 256-bit descriptors is 256 - 2 * Hamming distance.
On one core that costs less than one brute-force OpenCV kNN pass, and both slices of the matrix
the lesson asks for come out of it: the row's two best (ratio test) and the column's best
(mutual consistency). ``cv2.BFMatcher(crossCheck=True)`` cannot be combined with ``knnMatch(k=2)``,
and running the kNN in both directions would double the cost (lesson, chapter 2).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

N_BITS = 256


_SIGNS = (np.unpackbits(np.arange(256, dtype=np.uint8)[:, None], axis=1)
          .astype(np.float32) * 2.0 - 1.0)  # byte value -> its 8 bits as -1/+1, MSB first


def descriptor_signs(des: np.ndarray) -> np.ndarray:
    """(N, 32) uint8 ORB descriptors -> (N, 256) float32 in {-1, +1}; computed once per frame."""
    return np.take(_SIGNS, des.ravel(), axis=0).reshape(len(des), N_BITS)


def hamming_matrix(q_signs: np.ndarray, t_signs: np.ndarray) -> np.ndarray:
    """Exact Hamming distances (float32) between every query and train descriptor."""
    dot = cv2.gemm(q_signs, t_signs, 1.0, None, 0.0,  # type: ignore[call-overload]
                   flags=cv2.GEMM_2_T)
    return (N_BITS - dot) * 0.5


@dataclass(frozen=True)
class Matches:
    """Accepted pairs (query index, train index) and the statistics of the test."""

    query: np.ndarray  # (M,) intp
    train: np.ndarray  # (M,) intp
    n_putative: int  # query features that had two candidates (the ratio test applies)
    n_ratio_rejected: int  # of those, how many failed d1 < ratio * d2

    @property
    def ratio_reject_rate(self) -> float:
        return self.n_ratio_rejected / self.n_putative if self.n_putative else float("nan")

    @staticmethod
    def none(n_query: int = 0) -> Matches:
        empty = np.zeros(0, np.intp)
        return Matches(empty, empty, 0, 0)


def match(q_signs: np.ndarray, t_signs: np.ndarray, ratio: float = 0.8,
          mutual: bool = True) -> Matches:
    """Nearest neighbour of every query among all train descriptors, with both tests.

    ``ratio_reject_rate`` counts every query whose best match fails d1 < ratio*d2, regardless
    of the mutual check: it is the global repetitive-structure statistic of chapter 2.
    """
    nq, nt = len(q_signs), len(t_signs)
    if nq == 0 or nt < 2:
        return Matches.none(nq)
    dot = cv2.gemm(q_signs, t_signs, 1.0, None, 0.0,  # type: ignore[call-overload]
                   flags=cv2.GEMM_2_T)
    rows = np.arange(nq)
    j1 = dot.argmax(axis=1)
    s1 = dot[rows, j1]
    # column best by value (max along axis 0 is several times faster than argmax there)
    col_best = dot.max(axis=0) if mutual else None
    dot[rows, j1] = -np.inf
    s2 = dot.max(axis=1)
    d1 = (N_BITS - s1) * 0.5
    d2 = (N_BITS - s2) * 0.5
    passed = d1 < ratio * d2
    keep = passed
    if col_best is not None:
        keep = passed & (s1 >= col_best[j1])
    q = np.flatnonzero(keep)
    t = j1[q]
    if col_best is not None and len(q):
        # a tie for a column's best leaves several queries pointing at it: keep the first
        _, first = np.unique(t, return_index=True)
        if len(first) < len(q):
            first.sort()
            q, t = q[first], t[first]
    return Matches(q, t, nq, int(nq - np.count_nonzero(passed)))
