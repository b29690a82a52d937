"""A small sparse Levenberg–Marquardt pose-graph solver (SE(2) and SE(3)) on scipy.sparse.

Edge error ``e = Log(Z⁻¹ P_i⁻¹ P_j)`` with right perturbations ``P ← P Exp(δ)``; Jacobians
``∂e/∂δ_j = J_r⁻¹(e)`` and ``∂e/∂δ_i = −J_r⁻¹(e) Ad(T_ij⁻¹)`` (``linearise``). Whitened by
the Cholesky factor of each edge's information; the first vertex is held by a stiff prior (the
gauge). Normal equations are factorised by QDLDL (sparse LDLᵀ under an approximate minimum
degree ordering), the pattern once per solve and the values once per iteration; on 3D graphs,
where the 6x6 blocks and the loops' fill-in make dense fronts, by CHOLMOD's supernodal
Cholesky when cvxopt (the ``loops-fast`` extra) is installed (:func:`sparse_backend`).

This is the fallback and the verification solver of the audit; ``--optimize`` uses GTSAM when
the ``loops-opt`` extra is installed.
"""

from __future__ import annotations

import importlib.util
import logging
import os
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg
import scipy.sparse as sp
from numpy.typing import NDArray

from frontdiag.errors import ConfigError, OptionalDependencyError
from frontdiag.loops import lie
from frontdiag.loops.graph import PoseGraph

log = logging.getLogger(__name__)

F = NDArray[np.float64]
GAUGE_INFO = 1e10
LM_LAMBDA0 = 1e-8
"""Levenberg–Marquardt's first damping, relative to the diagonal (see :func:`solve`)."""


@dataclass
class Linearised:
    r: F
    """Whitened residuals (edges·k)."""
    U: F
    """(edges, k, k) upper Cholesky factors of the information, Ω = UᵀU."""
    Je_i: F
    """(edges, k, k) unwhitened Jacobian blocks of the error wrt the source vertex."""
    Je_j: F
    """(edges, k, k) the same wrt the destination vertex."""
    e: F
    """(edges, k) the errors before whitening (``r`` is ``U e``)."""


def _chol_upper(info: F) -> F:
    L = np.linalg.cholesky(info)
    return np.swapaxes(L, -1, -2)


def edge_errors(P: F, src: NDArray[np.int64], dst: NDArray[np.int64], Z: F) -> tuple[F, F]:
    """Errors e (m, k) and the relative poses T_ij (m, d+1, d+1) at poses P."""
    T = lie.inv(P[src]) @ P[dst]
    return lie.log(lie.inv(Z) @ T), T


def linearise(P: F, src: NDArray[np.int64], dst: NDArray[np.int64], Z: F, U: F,
              n: int) -> Linearised:
    """Whitened residuals and the Jacobians of e = Log(Z⁻¹ P_i⁻¹ P_j) under right perturbations
    of the poses: J_r⁻¹(e) wrt P_j and −J_r⁻¹(e) Ad(T_ij⁻¹) wrt P_i. J_r⁻¹(e) taken as I is
    exact only at e = 0: the iterations then stop where that approximate Jᵀr vanishes, which is
    not the least-squares minimum wherever edges keep a residual (CSAIL: cost 40.408 instead of
    40.404), and where loops disagree, far from it. J_r⁻¹ is exact (``lie.right_jacobian_inv``):
    its first-order form I + ad(e)/2 is off by tenths at the radians of a false loop's
    residual."""
    e, T = edge_errors(P, src, dst, Z)
    Jr_inv = lie.right_jacobian_inv(e)
    Ji = -Jr_inv @ lie.adjoint(lie.inv(T))
    del n
    r = np.einsum("mij,mj->mi", U, e).ravel()
    return Linearised(r=r, U=U, Je_i=Ji, Je_j=Jr_inv, e=e)


def scatter_add(idx: NDArray[np.int64], vals: F, n: int) -> F:
    """``out[idx[m]] += vals[m]`` over the first axis (``np.add.at``): by one ``bincount``, or
    for rows of 32 values or more (the map test's 64 draws a row) as the product of the 0/1
    incidence matrix with the rows: on M3500's 5 400 rows of 192, 0.7 ms against 5–7 ms."""
    w = int(np.prod(vals.shape[1:], dtype=np.int64))
    m = idx.shape[0]
    if w >= 32:
        A = sp.csr_matrix((np.ones(m), (idx, np.arange(m))), shape=(n, m))
        return np.asarray(A @ vals.reshape(m, w)).reshape((n, *vals.shape[1:]))
    flat = (idx[:, None] * w + np.arange(w)).ravel()
    out = np.bincount(flat, weights=vals.reshape(-1), minlength=n * w)
    return out.reshape((n, *vals.shape[1:]))


class UpperPattern:
    """The upper triangle (diagonal included) of a symmetric k x k block matrix with blocks on
    the diagonal and at (src[e], dst[e]) / (dst[e], src[e]), as a CSC structure, and where every
    block entry lands in it: each assembly is then one ``bincount`` into a fixed pattern."""

    def __init__(self, src: NDArray[np.int64], dst: NDArray[np.int64], n: int, k: int) -> None:
        ar = np.arange(k)
        rb = np.repeat(ar, k)  # row within the block, row-major
        cb = np.tile(ar, k)

        def entries(bi: NDArray[np.int64], bj: NDArray[np.int64]
                    ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
            return ((bi[:, None] * k + rb).ravel(), (bj[:, None] * k + cb).ravel())

        ver = np.arange(n)
        parts = [entries(ver, ver), entries(src, dst), entries(dst, src)]
        rr = np.concatenate([p[0] for p in parts])
        cc = np.concatenate([p[1] for p in parts])
        N = n * k
        self.keep = np.flatnonzero(rr <= cc)
        keys = cc[self.keep].astype(np.int64) * N + rr[self.keep]
        uniq, self.slot = np.unique(keys, return_inverse=True)
        self.indices = (uniq % N).astype(np.int32)
        self.indptr = np.searchsorted(uniq // N, np.arange(N + 1)).astype(np.int32)
        self.shape = (N, N)

    def matrix(self, diag: F, off: F) -> sp.csc_matrix:
        """Upper triangle of the matrix with ``diag[v]`` and ``off[e]`` blocks (duplicates
        summed); the lower blocks are ``off[e]ᵀ``, so only their upper entries are read."""
        vals = np.concatenate([diag.reshape(-1), off.reshape(-1),
                               np.swapaxes(off, -1, -2).reshape(-1)])
        data = np.bincount(self.slot, weights=vals[self.keep], minlength=len(self.indices))
        return sp.csc_matrix((data, self.indices, self.indptr), shape=self.shape)


def normal_equations(lin: Linearised, src: NDArray[np.int64], dst: NDArray[np.int64], n: int,
                     damping: float = 0.0, pattern: UpperPattern | None = None
                     ) -> tuple[sp.csc_matrix, F]:
    """The upper triangle of H = AᵀA (+ damping·diag + gauge prior), assembled block by block on
    a fixed pattern, so that every iteration of one solve refactorises the same structure; and
    g = Aᵀr. Pass the edge set's ``pattern`` to reuse it across iterations."""
    k = lin.U.shape[-1]
    Wi = lin.U @ lin.Je_i
    Wj = lin.U @ lin.Je_j
    r = lin.r.reshape(-1, k)
    Hii = np.swapaxes(Wi, -1, -2) @ Wi
    Hjj = np.swapaxes(Wj, -1, -2) @ Wj
    Hij = np.swapaxes(Wi, -1, -2) @ Wj
    g = scatter_add(src, np.einsum("mji,mj->mi", Wi, r), n) \
        + scatter_add(dst, np.einsum("mji,mj->mi", Wj, r), n)
    diag = scatter_add(src, Hii, n) + scatter_add(dst, Hjj, n)
    dvals = np.einsum("nii->ni", diag).copy()
    idx = np.arange(k)
    # damping and a relative regulariser per entry (a mean would mix metres and radians)
    diag[:, idx, idx] += (damping + 1e-12) * dvals + 1e-12
    diag[0, idx, idx] += GAUGE_INFO
    if pattern is None:
        pattern = UpperPattern(src, dst, n, k)
    return pattern.matrix(diag, Hij), g.ravel()


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


def _upper(H: sp.spmatrix) -> sp.csc_matrix:
    """The upper triangle of H as CSC with sorted indices (H itself when it is one already)."""
    if isinstance(H, sp.csc_matrix) and H.has_sorted_indices:
        coo_r = H.indices
        cols = np.repeat(np.arange(H.shape[1]), np.diff(H.indptr))
        if np.all(coo_r <= cols):
            return H
    T = sp.triu(H, format="csc")
    T.sort_indices()
    return T


SOLVER_ENV = "FRONTDIAG_LOOPS_SOLVER"
"""Environment variable choosing the sparse factorisation: ``auto`` (the default), ``qdldl`` or
``cholmod`` (for A/B runs and tests)."""

SOLVERS = ("auto", "qdldl", "cholmod")


def cholmod_available() -> bool:
    """Whether cvxopt (the ``loops-fast`` extra), which carries CHOLMOD, can be imported."""
    return importlib.util.find_spec("cvxopt") is not None


def _solver_wanted() -> str:
    """``FRONTDIAG_LOOPS_SOLVER``, checked: one of :data:`SOLVERS`."""
    want = os.environ.get(SOLVER_ENV, "auto").strip().lower() or "auto"
    if want not in SOLVERS:
        raise ConfigError(f"{SOLVER_ENV}={want!r}: choose one of {', '.join(SOLVERS)}")
    return want


def sparse_backend(k: int | None) -> str:
    """The factorisation for the normal matrices of a graph of tangent dimension k (3 in 2D,
    6 in 3D): ``qdldl`` or ``cholmod``.

    ``auto`` takes CHOLMOD's supernodal Cholesky for 3D graphs (k = 6) where cvxopt is
    installed, QDLDL otherwise. QDLDL is a simplicial LDLᵀ: entry by entry, no dense kernels.
    On a 3D graph each pose is a 6x6 block and the loops' fill-in makes dense fronts, which a
    supernodal factorisation does with BLAS: on sphere2500 (15 000 unknowns) a refactorisation
    takes 90 ms with QDLDL and 16 ms with CHOLMOD, and 64 right-hand sides 185 against 74 ms.
    On the 2D benchmark graphs (CSAIL, intel, M3500: 3 000–10 500 unknowns) QDLDL is as fast or
    faster (CSAIL 0.2 against 0.4 ms), so 2D stays with it. ``FRONTDIAG_LOOPS_SOLVER`` forces
    either. Both are direct factorisations of the same matrix: their solutions agree to about
    1e-10 of themselves (docs/loops.md has the audits side by side)."""
    want = _solver_wanted()
    if want == "qdldl":
        return "qdldl"
    if want == "cholmod":
        if not cholmod_available():
            raise OptionalDependencyError(
                f"{SOLVER_ENV}=cholmod needs cvxopt, which is not installed",
                hint="pip install 'frontdiag[loops-fast]', or unset the variable")
        return "cholmod"
    return "cholmod" if k == 6 and cholmod_available() else "qdldl"


def solver_label(k: int, fallbacks: int = 0) -> str:
    """What :func:`sparse_backend` picks for a graph of tangent dimension k, for the audit's
    summary; ``fallbacks``: how many matrices CHOLMOD refused and QDLDL factorised instead
    (:func:`ldlt_fallbacks`), said where there were any."""
    label = {"qdldl": "QDLDL (simplicial LDLT)",
             "cholmod": "CHOLMOD (supernodal Cholesky, cvxopt)"}[sparse_backend(k)]
    if fallbacks:
        label += (f"; QDLDL on {fallbacks} matri{'x' if fallbacks == 1 else 'ces'} that "
                  "Cholesky refused as not definite")
    return label


_LDLT_FALLBACKS = [0]
"""Matrices CHOLMOD refused and QDLDL factorised, since the process started (one audit at a
time per process: the audit reads the count before and after)."""


def ldlt_fallbacks() -> int:
    """How many matrices CHOLMOD has refused (and QDLDL factorised) in this process."""
    return _LDLT_FALLBACKS[0]


class _Etree:
    """QDLDL's factors (L strictly lower, CSC; D; the ordering) with the elimination tree of
    L: each column's parent is its first nonzero row below the diagonal."""

    def __init__(self, factors: tuple[Any, Any, Any]) -> None:
        L, d, p = factors
        self.L = sp.csc_matrix(L)
        self.n = self.L.shape[0]
        self.d = np.asarray(d, dtype=float)
        p = np.asarray(p, dtype=np.intp)
        self.pinv = np.empty(self.n, np.intp)
        self.pinv[p] = np.arange(self.n)
        parent = np.full(self.n, -1, np.intp)
        has = np.diff(self.L.indptr) > 0
        first = self.L.indptr[:-1][has]
        # the smallest row of each column, whether or not QDLDL sorted them
        parent[has] = np.minimum.reduceat(self.L.indices, first) if first.size else []
        self._parent: list[int] = parent.tolist()

    def reach(self, start: NDArray[np.intp]) -> NDArray[np.intp]:
        """The rows ``start`` and all their ancestors, ascending."""
        mark = bytearray(self.n)
        par = self._parent
        for i in start.tolist():
            while i != -1 and not mark[i]:
                mark[i] = 1
                i = par[i]
        return np.flatnonzero(np.frombuffer(bytes(mark), np.uint8))


REACH_DENSE_MAX = 2000
"""The largest elimination-tree reach :meth:`Factor.quadratic` solves on a dense triangle
(32 MB); a wider one takes the full back-substitutions."""


class _Qdldl:
    def __init__(self, T: sp.csc_matrix) -> None:
        import qdldl

        # upper=True: T is the upper triangle already, which spares QDLDL its own triu copy
        self._f = qdldl.Solver(T, upper=True)
        self._tree: _Etree | None = None
        self._factors: tuple[Any, Any, Any] | None = None

    def update(self, T: sp.csc_matrix) -> None:
        self._f.update(T, upper=True)
        self._tree = None
        self._factors = None

    def factors(self) -> tuple[Any, Any, Any]:
        """QDLDL's factors (L, D, the ordering), copied out of the solver once per
        factorisation: the fill count and the elimination tree read the same copy."""
        if self._factors is None:
            self._factors = self._f.factors()
        return self._factors

    def quadratic(self, rows: NDArray[np.intp], B: F) -> F | None:
        """Bᵀ H⁻¹ B for a B whose only nonzero rows are ``rows`` (values ``B``), from the
        factors' forward half on the rows it reaches; None where that reach is too wide.

        QDLDL factorises Pᵀ H P = (I + L) D (I + L)ᵀ, so Bᵀ H⁻¹ B = Yᵀ D⁻¹ Y with
        Y = (I + L)⁻¹ Pᵀ B. A column of L has its nonzeros only at ancestors of its own index
        in the elimination tree, so Y is nonzero only on the rows of Pᵀ B and their ancestors
        (the reach; Gilbert & Peierls 1988), and L restricted to the reach is all the forward
        substitution reads. A pose graph's reach is a few hundred of its thousands of rows
        (M3500's groups: about 600 of 10 500), so a dense triangle of that size replaces a
        forward and a backward pass over the whole factor per column."""
        if self._tree is None:
            self._tree = _Etree(self.factors())
            self._factors = None  # the tree holds what it needs
        t = self._tree
        R = t.reach(t.pinv[rows])
        if R.size > REACH_DENSE_MAX:
            return None
        pos = np.full(t.n, -1)
        pos[R] = np.arange(R.size)
        # the reach is closed under ancestors: its columns have every nonzero inside it
        start, end = t.L.indptr[R], t.L.indptr[R + 1]
        cnt = end - start
        src = np.repeat(start - np.cumsum(cnt) + cnt, cnt) + np.arange(int(cnt.sum()))
        tri = np.zeros((R.size, R.size))
        tri[pos[t.L.indices[src]], np.repeat(np.arange(R.size), cnt)] = t.L.data[src]
        Bp = np.zeros((R.size, B.shape[1]))
        Bp[pos[t.pinv[rows]]] = B
        Y = scipy.linalg.solve_triangular(tri, Bp, lower=True, unit_diagonal=True,
                                          check_finite=False)
        return np.asarray(Y.T @ (Y / t.d[R][:, None]))

    def solve(self, b: F) -> F:
        if b.ndim == 1:
            return np.asarray(self._f.solve(b))
        # QDLDL solves one right-hand side at a time: transpose once, so each column is a
        # contiguous row, and fill one array (a strided copy per column and a stack of the
        # results took a fifth of the time of the solves themselves on M3500's 64 draws)
        rows = np.ascontiguousarray(b.T)
        out = np.empty_like(rows)
        for i in range(rows.shape[0]):
            out[i] = self._f.solve(rows[i])
        return out.T


class _Cholmod:
    """CHOLMOD through cvxopt: the symbolic analysis (AMD ordering, supernodes) once, the
    numeric factorisation per values; every right-hand side of a block in one call. The
    matrix is built once per pattern; a refactorisation only replaces its values, which are
    stored in the same column order as the CSC triangle's (building the matrix anew took 11 ms
    on parking-garage, as long as the factorisation)."""

    def __init__(self, T: sp.csc_matrix) -> None:
        from cvxopt import cholmod

        cholmod.options["supernodal"] = 2  # always supernodal (its auto rule picks by flops)
        self._n = T.shape[0]
        self._A = self._spmatrix(T)
        # the values go in place only where cvxopt kept every entry in the triangle's order
        self._in_place = np.array_equal(np.asarray(self._A.I).ravel(), T.indices)
        self._F = cholmod.symbolic(self._A, uplo="U")
        cholmod.numeric(self._A, self._F)  # ArithmeticError where not definite

    def update(self, T: sp.csc_matrix) -> None:
        from cvxopt import cholmod, matrix

        if self._in_place:
            self._A.V = matrix(np.ascontiguousarray(T.data, dtype=float))
        else:
            self._A = self._spmatrix(T)
        cholmod.numeric(self._A, self._F)  # ArithmeticError where not definite

    @staticmethod
    def _spmatrix(T: sp.csc_matrix) -> Any:
        """cvxopt's sparse matrix of the CSC triangle, from its triplets."""
        from cvxopt import spmatrix

        cols = np.repeat(np.arange(T.shape[1]), np.diff(T.indptr))
        return spmatrix(np.ascontiguousarray(T.data, dtype=float), T.indices.astype(np.int64),
                        cols.astype(np.int64), T.shape)

    def solve(self, b: F) -> F:
        from cvxopt import cholmod, matrix

        x = matrix(np.asarray(b, dtype=float).reshape(self._n, -1))
        cholmod.solve(self._F, x)
        out = np.asarray(x)
        return out.ravel() if b.ndim == 1 else out


FILL_SWITCH = 1_000_000
"""Nonzeros of QDLDL's factor above which a 2D graph's system goes to CHOLMOD (where cvxopt is
installed and no backend is forced). Loops that join distant poses fill the factor in; past
about a million nonzeros CHOLMOD's supernodes pay for their set-up many times over: M3500 with
every one of 977 random false loops in the map, 1.9 M nonzeros, 1.9 s a refactorisation with
QDLDL against 0.31 s with CHOLMOD; city10000 with 10 % grouped ones, 4.7 M, 5.9 against 0.74 s.
Below it QDLDL is as fast or faster (city10000 as published, 1.0 M: 59 against 67 ms;
docs/loops.md, "Sparse factorisation")."""

_BIG_FILL: dict[int, bool] = {}
"""Sizes of system (unknowns) whose QDLDL factor passed FILL_SWITCH since :func:`forget_fill`:
a later system of the same size starts with CHOLMOD (an audit factorises many systems of one
graph)."""


def forget_fill() -> None:
    """Forget which system sizes filled in: each audit starts its own memo, so a later graph
    of the same size (another file in the same process) is not sent to CHOLMOD for it."""
    _BIG_FILL.clear()


def _may_switch(k: int | None) -> bool:
    """Whether a QDLDL factorisation may move to CHOLMOD: 2D graphs under ``auto`` with cvxopt
    installed (3D graphs are CHOLMOD's from the start)."""
    return k == 3 and _solver_wanted() == "auto" and cholmod_available()


class Factor:
    """A factorisation of a symmetric positive definite matrix (QDLDL or CHOLMOD, see
    :func:`sparse_backend`); ``update`` refactorises new values on the same pattern without
    ordering it again. ``k``: the graph's tangent dimension, which picks the backend (the
    chordal start's matrices have blocks of 2 or 3 and follow their graph's choice)."""

    def __init__(self, H: sp.csc_matrix, k: int | None = None) -> None:
        T = _upper(H)
        self.k = k
        self.backend = sparse_backend(k)
        self._pattern = (T.indptr.copy(), T.indices.copy())
        self._impl: _Qdldl | _Cholmod = self._factorise(T)

    def _factorise(self, T: sp.csc_matrix) -> _Qdldl | _Cholmod:
        if self.backend == "qdldl" and _BIG_FILL.get(T.shape[0]) and _may_switch(self.k):
            self.backend = "cholmod"  # this size of system filled in before: start supernodal
        if self.backend == "cholmod":
            try:
                return _Cholmod(T)
            except ArithmeticError:
                return self._to_ldlt(T)
        q = _Qdldl(T)
        if _may_switch(self.k):
            fill = int(q.factors()[0].nnz)
            if fill > FILL_SWITCH:
                log.info("QDLDL's factor holds %d nonzeros: CHOLMOD factorises this system", fill)
                _BIG_FILL[T.shape[0]] = True
                try:
                    c = _Cholmod(T)
                except ArithmeticError:
                    return q
                self.backend = "cholmod"
                return c
        return q

    def _to_ldlt(self, T: sp.csc_matrix) -> _Qdldl:
        """Cholesky needs a definite matrix; LDLᵀ carries on through a pivot that is zero to
        rounding (a part of the graph the gauge does not reach), as it did before CHOLMOD."""
        log.info("CHOLMOD refused a matrix that is not definite; QDLDL factorises it")
        _LDLT_FALLBACKS[0] += 1
        self.backend = "qdldl"
        return _Qdldl(T)

    def update(self, H: sp.csc_matrix) -> None:
        T = _upper(H)
        if (T.indptr.shape == self._pattern[0].shape and T.indices.shape ==
                self._pattern[1].shape and np.array_equal(T.indptr, self._pattern[0])
                and np.array_equal(T.indices, self._pattern[1])):
            try:
                self._impl.update(T)
            except ArithmeticError:
                self._impl = self._to_ldlt(T)
        else:
            self.__init__(H, self.k)  # type: ignore[misc]

    def solve(self, b: F) -> F:
        return self._impl.solve(b)

    def quadratic(self, rows: NDArray[np.intp], B: F) -> F:
        """Bᵀ H⁻¹ B (m x m) for an (N x m) B whose only nonzero rows are ``rows`` (unique),
        given as their values ``B`` (len(rows) x m): the hat-matrix block of a few
        observations. QDLDL's factor solves only the rows these reach
        (:meth:`_Qdldl.quadratic`); otherwise, or where they reach too far, one
        back-substitution per column."""
        if isinstance(self._impl, _Qdldl):
            out = self._impl.quadratic(rows, B)
            if out is not None:
                return out
        n = self._pattern[0].size - 1
        full = np.zeros((n, B.shape[1]))
        full[rows] = B
        return np.asarray(B.T @ self.solve(full)[rows])


@dataclass
class Structure:
    """What a solve leaves for a test of the same map: its edges, their fixed pattern and the
    last factorisation (whose ordering a refactorisation of new values keeps)."""

    edges: NDArray[np.bool_]
    pattern: UpperPattern
    factor: Factor


def solve(graph: PoseGraph, edges: NDArray[np.bool_], init: F, *, max_iters: int = 50,
          tol: float = 1e-7, keep: list[Structure] | None = None
          ) -> tuple[F, dict[str, float]]:
    """Levenberg–Marquardt on the selected edges from ``init``; returns poses and stats
    (``iterations``, ``cost_initial``, ``cost``; ``converged`` 0 where the iterations ran out
    before the relative decrease of the cost fell under ``tol``, with the last accepted step's
    decrease in ``last_rel_decrease``).

    The damping is Marquardt's (``lam`` times the diagonal), updated by Nielsen's rule from the
    gain ratio ρ of the actual to the model's decrease (Madsen, Nielsen & Tingleff 2004,
    "Methods for non-linear least squares problems", §3.2): an accepted step multiplies it by
    max(1/3, 1 − (2ρ − 1)³), so it falls where the quadratic model holds and stays where it
    barely does; a step that raises the cost is refused and multiplies it by ν, which doubles
    with each refusal in a row. A pose chain's long bends have eigenvalues near (π/n)² of the
    diagonal (n poses; 8e-7 for M3500's 3500), and a damping above that holds them back, so the
    cost falls linearly: from 1e-4, divided by 3 per step, M3500's solves took 10–22 iterations.
    It starts at 1e-8, under that line for graphs up to some 30 000 poses; where the quadratic
    model overshoots, a few refusals raise it (ν doubles). A fixed factor of 10 down and up
    instead made intel's solves with false loops in the map alternate between a refused and an
    accepted step up to the iteration cap.

    ``keep``, a list, receives the solve's :class:`Structure`, so that a test of the same map
    refactorises it (``Factor.update``) instead of ordering it again."""
    sel = np.flatnonzero(edges)
    src, dst, Z = graph.src[sel], graph.dst[sel], graph.Z[sel]
    U = _chol_upper(graph.info[sel])
    n, k, d = graph.n_vertices, graph.k, graph.dim
    P = init.copy()
    lam, nu = LM_LAMBDA0, 2.0
    pattern = UpperPattern(src, dst, n, k)
    lin = linearise(P, src, dst, Z, U, n)
    cost = float(lin.r @ lin.r)
    first = cost
    it = 0
    fac: Factor | None = None
    converged, rel = False, float("nan")
    for it in range(1, max_iters + 1):  # noqa: B007
        H, g = normal_equations(lin, src, dst, n, lam, pattern)
        if fac is None:
            fac = Factor(H, k)
        else:
            fac.update(H)
        step = -fac.solve(g)
        # the model's decrease −(2gᵀh + hᵀAᵀAh), with (AᵀA + lam·D) h = −g: −gᵀh + lam·hᵀDh
        # (H's diagonal holds (1 + lam)·D, up to the regulariser and the gauge)
        hDh = float(step @ (H.diagonal() * step)) * lam / (1.0 + lam)
        predicted = -float(g @ step) + hDh
        P_new = P @ lie.exp(step.reshape(n, k), d)
        lin_new = linearise(P_new, src, dst, Z, U, n)
        new_cost = float(lin_new.r @ lin_new.r)
        if new_cost < cost:
            rel = (cost - new_cost) / max(cost, 1e-300)
            rho = (cost - new_cost) / max(predicted, 1e-300)
            P, lin, cost = P_new, lin_new, new_cost
            lam = max(lam * max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), 1e-12)
            nu = 2.0
            if rel < tol:
                converged = True
                break
        else:
            lam *= nu
            nu *= 2.0
            if lam > 1e8:  # no step lowers the cost: a minimum, to numerical precision
                converged = True
                break
    if keep is not None and fac is not None:
        keep[:] = [Structure(edges.copy(), pattern, fac)]
    return P, {"iterations": float(it), "cost_initial": first, "cost": cost,
               "converged": float(converged), "last_rel_decrease": rel}
