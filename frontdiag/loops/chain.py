"""The odometry chain between any two poses, with its propagated covariance, in O(1) per query.

Compose the odometry links from the first pose: ``P_k = L_0 · … · L_{k-1}``. The chain from
pose a to pose b is ``T_ab = P_a⁻¹ P_b``. With each link perturbed on the right,
``L_k Exp(ξ_k)``, the chain's error at b is ``ξ = Σ_{a≤k<b} Ad(T_{k+1,b}⁻¹) ξ_k`` and, since
``Ad(T_{k+1,b}⁻¹) = Ad(P_b)⁻¹ Ad(P_{k+1})``, its covariance is

    Σ_ab = Ad(P_b)⁻¹ (C_b − C_a) Ad(P_b)⁻ᵀ,    C_m = Σ_{k<m} Ad(P_{k+1}) Σ_k Ad(P_{k+1})ᵀ,

a prefix sum: one pass over the links, then any number of chains by two lookups (first-order
propagation, Barfoot & Furgale 2014). A missing link starts a new segment; chains across
segments do not exist.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from frontdiag.loops import lie
from frontdiag.loops.graph import PoseGraph

F = NDArray[np.float64]
I64 = NDArray[np.int64]


@dataclass(frozen=True)
class Chain:
    P: F
    """(n, d+1, d+1) odometry poses composed from the first vertex."""
    C: F
    """(n, k, k) prefix sums of the link covariances carried to the world frame."""
    segment: I64
    """(n,) segment number of each vertex (a new one after every missing link)."""
    link_cov: F
    """(n-1, k, k) covariance of each link (zero where the link is missing)."""
    has_link: NDArray[np.bool_]

    def between(self, a: I64, b: I64) -> tuple[F, F]:
        """Chain transforms (m, d+1, d+1) and covariances (m, k, k) from a to b (any order)."""
        a = np.asarray(a)
        b = np.asarray(b)
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        T = lie.inv(self.P[lo]) @ self.P[hi]
        A = np.linalg.inv(lie.adjoint(self.P[hi]))
        S = A @ (self.C[hi] - self.C[lo]) @ np.swapaxes(A, -1, -2)
        S = 0.5 * (S + np.swapaxes(S, -1, -2))
        back = a > b
        if back.any():
            Ad = lie.adjoint(T[back])
            S[back] = Ad @ S[back] @ np.swapaxes(Ad, -1, -2)
            T[back] = lie.inv(T[back])
        return T, S

    def same_segment(self, a: I64, b: I64) -> NDArray[np.bool_]:
        return np.asarray(self.segment[a] == self.segment[b])


def build_chain(graph: PoseGraph, odometry: NDArray[np.bool_]) -> Chain:
    """Compose the odometry links (edges in ``odometry`` joining vertex rows k and k+1)."""
    n = graph.n_vertices
    m = graph.dim + 1
    k = graph.k
    steps = np.tile(np.eye(m), (max(n - 1, 0), 1, 1))
    cov = np.zeros((max(n - 1, 0), k, k))
    has = np.zeros(max(n - 1, 0), bool)
    link = np.flatnonzero(odometry & (graph.dst == graph.src + 1))
    # first edge per link wins (odometry_mask already keeps one per pair)
    rows, first = np.unique(graph.src[link], return_index=True)
    link = link[first]
    steps[rows] = graph.Z[link]
    cov[rows] = np.linalg.inv(graph.info[link])
    has[rows] = True
    P = lie.prefix_products(steps)
    Ad = lie.adjoint(P[1:])
    terms = Ad @ cov @ np.swapaxes(Ad, -1, -2)
    C = np.zeros((n, k, k))
    C[1:] = np.cumsum(terms, axis=0)
    segment = np.concatenate([[0], np.cumsum(~has)]).astype(np.int64)
    return Chain(P=P, C=C, segment=segment, link_cov=cov, has_link=has)
