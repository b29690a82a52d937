"""Pairwise consistency of loop closures and the largest consistent set (PCM).

Two loops l1: a1→b1 and l2: a2→b2 are consistent when the cycle they form with odometry closes:

    E = Log(Z1 · T(b1→b2) · Z2⁻¹ · T(a2→a1)),   χ² = Eᵀ Σ_E⁻¹ E ≤ χ²_k(1 − p_pair),

with Σ_E the four pieces' covariances carried to the cycle's end by adjoints (Mangelson,
Dominic, Eustice & Vasudevan 2018, eq. 5-6).

Candidate pairs. The cycle's covariance grows with the two odometry chains |a1 − a2| and
|b1 − b2|. Far pairs carry long, uncertain chains, so their test passes whatever the loops say:
it has no power and only makes the consistency graph dense. Only pairs whose endpoints are within
``window`` poses of each other (Chebyshev distance in (a, b) index space) are tested: a k-d tree
finds them in O(m log m + pairs) instead of m² / 2. An untested pair is what PCM's own test would
have passed for lack of power, so it counts as consistent.

Largest consistent set. With untested pairs consistent, a set is pairwise consistent exactly
when it holds no tested-inconsistent pair, so PCM's maximum clique of the consistency graph is
the maximum independent set of the sparse conflict graph. Each conflict component is solved
exactly (branch and bound) up to ``exact_max`` loops and greedily (least conflicts first) above.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from scipy.stats import chi2 as chi2_dist

from frontdiag.loops import lie
from frontdiag.loops.chain import Chain
from frontdiag.loops.graph import PoseGraph

F = NDArray[np.float64]
I64 = NDArray[np.int64]


def candidate_pairs(a: I64, b: I64, window: int) -> I64:
    """(p, 2) index pairs into the loop list with |a1-a2| <= window and |b1-b2| <= window."""
    if a.shape[0] < 2:
        return np.zeros((0, 2), np.int64)
    tree = cKDTree(np.c_[a, b].astype(float))
    pairs = tree.query_pairs(r=float(window), p=np.inf, output_type="ndarray")
    return np.asarray(pairs, dtype=np.int64).reshape(-1, 2)


def pair_chi2(graph: PoseGraph, chain: Chain, loops: I64, pairs: I64) -> F:
    """χ² of the cycle loop1 - odometry - loop2⁻¹ - odometry for each pair (NaN across segments)."""
    if pairs.shape[0] == 0:
        return np.zeros(0)
    e1, e2 = loops[pairs[:, 0]], loops[pairs[:, 1]]
    a1, b1 = graph.src[e1], graph.dst[e1]
    a2, b2 = graph.src[e2], graph.dst[e2]
    Z1, Z2 = graph.Z[e1], graph.Z[e2]
    S1 = np.asarray(np.linalg.inv(graph.info[e1]), dtype=np.float64)
    S2 = np.asarray(np.linalg.inv(graph.info[e2]), dtype=np.float64)
    B, SB = chain.between(b1, b2)
    D, SD = chain.between(a2, a1)
    C = lie.inv(Z2)
    AdZ2 = lie.adjoint(Z2)
    SC = AdZ2 @ S2 @ np.swapaxes(AdZ2, -1, -2)
    CD = C @ D
    BCD = B @ CD
    E = lie.log(Z1 @ BCD)

    def carry(X: F, S: F) -> F:
        A = lie.adjoint(lie.inv(X))
        return A @ S @ np.swapaxes(A, -1, -2)

    cov = carry(BCD, S1) + carry(CD, SB) + carry(D, SC) + SD
    chi2 = np.einsum("pi,pij,pj->p", E, np.linalg.inv(cov), E)
    ok = chain.same_segment(b1, b2) & chain.same_segment(a1, a2)
    return np.where(ok, chi2, np.nan)


def _mis_exact(nodes: list[int], adj: dict[int, set[int]]) -> set[int]:
    best: set[int] = set()

    def rec(cand: set[int], chosen: set[int]) -> None:
        nonlocal best
        if len(chosen) + len(cand) <= len(best):
            return
        if not cand:
            best = set(chosen)
            return
        v = max(cand, key=lambda x: len(adj[x] & cand))
        if not adj[v] & cand:  # no conflicts left: take all
            rec(set(), chosen | cand)
            return
        rec(cand - {v} - adj[v], chosen | {v})
        rec(cand - {v}, chosen)

    rec(set(nodes), set())
    return best


def _mis_greedy(nodes: list[int], adj: dict[int, set[int]]) -> set[int]:
    left = set(nodes)
    keep: set[int] = set()
    while left:
        v = min(left, key=lambda x: (len(adj[x] & left), x))
        keep.add(v)
        left -= adj[v] | {v}
    return keep


def max_consistent_set(n: int, conflicts: I64, exact_max: int = 40) -> NDArray[np.bool_]:
    """Keep-mask of the largest set of n loops with no conflicting pair (see module doc)."""
    keep = np.ones(n, bool)
    if conflicts.shape[0] == 0:
        return keep
    g = coo_matrix((np.ones(conflicts.shape[0]), (conflicts[:, 0], conflicts[:, 1])),
                   shape=(n, n))
    _, label = connected_components(g, directed=False)
    involved = np.unique(conflicts.ravel())
    adj: dict[int, set[int]] = {int(v): set() for v in involved}
    for p, q in conflicts:
        adj[int(p)].add(int(q))
        adj[int(q)].add(int(p))
    for lab in np.unique(label[involved]):
        nodes = [int(v) for v in involved[label[involved] == lab]]
        chosen = _mis_exact(nodes, adj) if len(nodes) <= exact_max else _mis_greedy(nodes, adj)
        for v in nodes:
            keep[v] = v in chosen
    return keep


def consistency_groups(n: int, consistent: I64) -> I64:
    """Group number of each loop: connected components of the consistent pairs (-1 = alone)."""
    if consistent.shape[0] == 0:
        return np.full(n, -1, np.int64)
    g = coo_matrix((np.ones(consistent.shape[0]), (consistent[:, 0], consistent[:, 1])),
                   shape=(n, n))
    _, label = connected_components(g, directed=False)
    sizes = np.bincount(label)
    out = label.astype(np.int64)
    out[sizes[label] < 2] = -1
    return out


def threshold(k: int, p: float) -> float:
    """χ² value above which a k-dof statistic has tail probability below p."""
    return float(chi2_dist.isf(p, k))
