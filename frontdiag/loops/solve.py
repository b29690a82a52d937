"""A small sparse Levenberg–Marquardt pose-graph solver (SE(2) and SE(3)) on scipy.sparse.

Edge error ``e = Log(Z⁻¹ P_i⁻¹ P_j)`` with right perturbations ``P ← P Exp(δ)``; Jacobians
``∂e/∂δ_j = I`` and ``∂e/∂δ_i = −Ad(T_ij⁻¹)`` (the first-order ``J_r⁻¹(e) ≈ I``, exact at
zero error). Whitened by the Cholesky factor of each edge's information; the first vertex is
held by a stiff prior (the gauge). Normal equations are factorised with SuperLU under a
approximate minimum degree ordering (QDLDL), once per solve.

This is the fallback and the verification solver of the audit; ``--optimize`` uses GTSAM when
the ``loops-opt`` extra is installed.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from frontdiag.loops import lie
from frontdiag.loops.graph import PoseGraph

log = logging.getLogger(__name__)

F = NDArray[np.float64]
GAUGE_INFO = 1e10


@dataclass
class Linearised:
    r: F
    """Whitened residuals (edges·k)."""
    U: F
    """(edges, k, k) upper Cholesky factors of the information, Ω = UᵀU."""
    Je_i: F
    """(edges, k, k) unwhitened Jacobian blocks wrt the source vertex (wrt dst it is I)."""


def _chol_upper(info: F) -> F:
    L = np.linalg.cholesky(info)
    return np.swapaxes(L, -1, -2)


def edge_errors(P: F, src: NDArray[np.int64], dst: NDArray[np.int64], Z: F) -> tuple[F, F]:
    """Errors e (m, k) and the relative poses T_ij (m, d+1, d+1) at poses P."""
    T = lie.inv(P[src]) @ P[dst]
    return lie.log(lie.inv(Z) @ T), T


def linearise(P: F, src: NDArray[np.int64], dst: NDArray[np.int64], Z: F, U: F,
              n: int) -> Linearised:
    e, T = edge_errors(P, src, dst, Z)
    Ji = -lie.adjoint(lie.inv(T))
    del n
    r = np.einsum("mij,mj->mi", U, e).ravel()
    return Linearised(r=r, U=U, Je_i=Ji)


def normal_equations(lin: Linearised, src: NDArray[np.int64], dst: NDArray[np.int64], n: int,
                     damping: float = 0.0) -> tuple[sp.csc_matrix, F]:
    """H = AᵀA (+ damping·diag + gauge prior) assembled block by block on a fixed pattern, so
    that every iteration of one solve refactorises the same structure; and g = Aᵀr."""
    k = lin.U.shape[-1]
    Wi = lin.U @ lin.Je_i
    Wj = lin.U
    r = lin.r.reshape(-1, k)
    Hii = np.swapaxes(Wi, -1, -2) @ Wi
    Hjj = np.swapaxes(Wj, -1, -2) @ Wj
    Hij = np.swapaxes(Wi, -1, -2) @ Wj
    g = np.zeros((n, k))
    np.add.at(g, src, np.einsum("mji,mj->mi", Wi, r))
    np.add.at(g, dst, np.einsum("mji,mj->mi", Wj, r))
    diag = np.zeros((n, k, k))
    np.add.at(diag, src, Hii)
    np.add.at(diag, dst, Hjj)
    dvals = np.einsum("nii->ni", diag).copy()
    idx = np.arange(k)
    # damping and a relative regulariser per entry (a mean would mix metres and radians)
    diag[:, idx, idx] += (damping + 1e-12) * dvals + 1e-12
    diag[0, idx, idx] += GAUGE_INFO
    return block_matrix(diag, src, dst, Hij), g.ravel()


def block_matrix(diag: F, src: NDArray[np.int64], dst: NDArray[np.int64],
                 off: F) -> sp.csc_matrix:
    """The symmetric sparse matrix with k x k blocks ``diag[v]`` on the diagonal and ``off[e]``
    at (src[e], dst[e]) (its transpose at (dst[e], src[e])); duplicates are summed."""
    n, k = diag.shape[0], diag.shape[-1]
    ar = np.arange(k)
    rows_b = ar[:, None] * np.ones(k, dtype=np.int64)[None, :]
    cols_b = rows_b.T

    def blocks(bi: NDArray[np.int64], bj: NDArray[np.int64],
               vals: F) -> tuple[NDArray[np.int64], NDArray[np.int64], F]:
        rr = (bi[:, None, None] * k + rows_b[None]).ravel()
        cc = (bj[:, None, None] * k + cols_b[None]).ravel()
        return rr, cc, vals.ravel()

    ver = np.arange(n)
    parts = [blocks(ver, ver, diag), blocks(src, dst, off),
             blocks(dst, src, np.swapaxes(off, -1, -2))]
    rr = np.concatenate([p[0] for p in parts])
    cc = np.concatenate([p[1] for p in parts])
    vv = np.concatenate([p[2] for p in parts])
    return sp.coo_matrix((vv, (rr, cc)), shape=(n * k, n * k)).tocsc()


class Factor:
    """LDLᵀ of a symmetric positive definite matrix (QDLDL with AMD ordering); ``update``
    refactorises new values on the same pattern without re-ordering."""

    def __init__(self, H: sp.csc_matrix) -> None:
        import qdldl

        T = sp.triu(H, format="csc")
        T.sort_indices()
        self._pattern = (T.indptr.copy(), T.indices.copy())
        self._f = qdldl.Solver(T)

    def update(self, H: sp.csc_matrix) -> None:
        T = sp.triu(H, format="csc")
        T.sort_indices()
        if (T.indptr.shape == self._pattern[0].shape and T.indices.shape ==
                self._pattern[1].shape and np.array_equal(T.indptr, self._pattern[0])
                and np.array_equal(T.indices, self._pattern[1])):
            self._f.update(T)
        else:
            self.__init__(H)  # type: ignore[misc]

    def solve(self, b: F) -> F:
        if b.ndim == 1:
            return np.asarray(self._f.solve(b))
        return np.stack([np.asarray(self._f.solve(np.ascontiguousarray(c))) for c in b.T], axis=1)


def solve(graph: PoseGraph, edges: NDArray[np.bool_], init: F, *, max_iters: int = 50,
          tol: float = 1e-7) -> tuple[F, dict[str, float]]:
    """Levenberg–Marquardt on the selected edges from ``init``; returns poses and stats."""
    sel = np.flatnonzero(edges)
    src, dst, Z = graph.src[sel], graph.dst[sel], graph.Z[sel]
    U = _chol_upper(graph.info[sel])
    n, k, d = graph.n_vertices, graph.k, graph.dim
    P = init.copy()
    lam = 1e-4
    lin = linearise(P, src, dst, Z, U, n)
    cost = float(lin.r @ lin.r)
    first = cost
    it = 0
    fac: Factor | None = None
    for it in range(1, max_iters + 1):  # noqa: B007
        H, g = normal_equations(lin, src, dst, n, lam)
        if fac is None:
            fac = Factor(H)
        else:
            fac.update(H)
        step = -fac.solve(g)
        P_new = P @ lie.exp(step.reshape(n, k), d)
        lin_new = linearise(P_new, src, dst, Z, U, n)
        new_cost = float(lin_new.r @ lin_new.r)
        if new_cost < cost:
            rel = (cost - new_cost) / max(cost, 1e-300)
            P, lin, cost = P_new, lin_new, new_cost
            lam = max(lam / 3.0, 1e-9)
            if rel < tol:
                break
        else:
            lam *= 10.0
            if lam > 1e8:
                break
    return P, {"iterations": float(it), "cost_initial": first, "cost": cost}
