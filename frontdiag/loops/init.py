"""Chordal initialisation of a pose graph: rotations first, then translations, both linear.

Levenberg–Marquardt from the odometry chain can stop far from the optimum when the chain has
drifted: on the intel graph (1228 edges) it is at a cost of 44 114 after its 50 iterations
(491 after 200, still descending) against 216 from this start, a map 6.0 m (ATE) away from
the optimum, and every loop tested against that map reads as wrong. The chordal relaxation
(Martinec & Pajdla 2007; Carlone, Tron, Daniilidis & Dellaert 2015) avoids the non-convexity
of the rotations:

1. rotations: minimise Σ w ‖R_j − R_i R_ij‖²_F over unconstrained d×d matrices (linear least
   squares, the rows decouple: one factorisation, d solves), then project each onto SO(d) by
   SVD;
2. translations: with the rotations fixed, t_j − t_i = R_i t_ij is linear in t.

Weights are scalars per edge: the mean diagonal of the edge's rotation (resp. translation)
information. Each connected component of the selected edges is anchored at its first vertex's
pose in ``fallback`` (the odometry chain), so the gauge matches the chain's.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import connected_components

from frontdiag.loops.graph import PoseGraph
from frontdiag.loops.solve import Factor, block_matrix

F = NDArray[np.float64]
_ANCHOR = 1e8  # the anchors' prior, relative to the stiffest edge


def _normal_matrix(n: int, d: int, src: NDArray[np.int64], dst: NDArray[np.int64], w: F,
                   off: F, anchors: NDArray[np.int64], prior: float) -> sp.csc_matrix:
    """Σ_e w_e [−M_e, I]ᵀ[−M_e, I] over (i, j) blocks, for residuals x_j − M_e x_i with M_e
    orthogonal (so the (i, i) block is w·I), plus a stiff prior on the anchors."""
    eye = np.eye(d)
    diag = np.zeros((n, d, d))
    np.add.at(diag, src, w[:, None, None] * eye)
    np.add.at(diag, dst, w[:, None, None] * eye)
    diag[anchors] += prior * eye
    return block_matrix(diag, src, dst, -w[:, None, None] * np.swapaxes(off, -1, -2))


def chordal_init(graph: PoseGraph, edges: NDArray[np.bool_], fallback: F) -> F:
    """Initial poses for the selected edges (see the module doc); ``fallback`` (n, d+1, d+1)
    anchors each connected component."""
    sel = np.flatnonzero(edges)
    n, d, k = graph.n_vertices, graph.dim, graph.k
    if sel.size == 0:
        return fallback.copy()
    src, dst, Z = graph.src[sel], graph.dst[sel], graph.Z[sel]
    info = graph.info[sel]
    w_rot = np.einsum("mii->m", info[:, d:, d:]) / (k - d)
    w_tr = np.einsum("mii->m", info[:, :d, :d]) / d
    adj = sp.coo_matrix((np.ones(sel.size), (src, dst)), shape=(n, n))
    _, comp = connected_components(adj, directed=False)
    anchors = np.unique(comp, return_index=True)[1].astype(np.int64)
    R_ij, t_ij = Z[:, :d, :d], Z[:, :d, d]
    # rotations, row by row: the r-th rows x of R satisfy x_j = R_ijᵀ x_i
    prior = _ANCHOR * float(w_rot.max())
    H = _normal_matrix(n, d, src, dst, w_rot, np.swapaxes(R_ij, -1, -2), anchors, prior)
    fac = Factor(H, graph.k)
    X = np.empty((n, d, d))
    for r in range(d):
        b = np.zeros((n, d))
        b[anchors] = prior * fallback[anchors, r, :d]
        X[:, r, :] = fac.solve(b.ravel()).reshape(n, d)
    U, _, Vt = np.linalg.svd(X)
    fix = np.ones((n, d))
    fix[:, -1] = np.sign(np.linalg.det(U @ Vt))
    R = (U * fix[:, None, :]) @ Vt
    # translations: t_j − t_i = R_i t_ij
    prior = _ANCHOR * float(w_tr.max())
    Ht = _normal_matrix(n, d, src, dst, w_tr, np.broadcast_to(np.eye(d), (sel.size, d, d)),
                        anchors, prior)
    step = np.einsum("mab,mb->ma", R[src], t_ij) * w_tr[:, None]
    g = np.zeros((n, d))
    np.add.at(g, dst, step)
    np.add.at(g, src, -step)
    g[anchors] += prior * fallback[anchors, :d, d]
    t = Factor(Ht, graph.k).solve(g.ravel()).reshape(n, d)
    P = np.zeros((n, d + 1, d + 1))
    P[:, :d, :d] = R
    P[:, :d, d] = t
    P[:, d, d] = 1.0
    return P
