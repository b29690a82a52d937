"""FD-LOP-003: every loop re-tested against the map optimised from the loops that passed.

Rounds. The first map holds the odometry and the loops whose chain test had power (chain σ at
most ``fold_m``, so a lie of a few ``fold_m`` would have been refuted). Each round optimises
(``solve.py``; from the map before it, and also from the chordal start in the first round and
in rounds that dropped loops), tests every loop against that map, and the next map holds the
loops that passed *with power* (the map's relative σ between their poses at most ``power_m``):
the map stiffens round by round and a group of mutually consistent false loops, which no local
test can refute, meets a map built without it. A true loop refused next to a false one
(swamping) comes back once the false one is out. The rounds stop when the set no longer
changes, or ``max_rounds`` after the first map whose solve converged (after ``max_rounds`` if
none has by then). Loops that contradict one another but not the rest enter and leave the map
together, round after round; when a round's next map is one an earlier round already tested,
the loops not in every map since then leave it for good and are judged against the maps of the
others (kept where they pass there with power and are too small to fold the map). So does a
loop that leaves the map for the ``max_leaves``-th time, where the maps do not repeat exactly.

Loops that pass but never with power (the map too loose between their poses: a stretch that
only they join) are then tested cluster by cluster against the map holding the other such
clusters (``_corroborate``, every cluster from one factorisation: ``leave_cluster_out``); the
clusters that pass there with power join the map and the rounds run again.

Runs (``_screen_runs``): loops whose ends are each within ``run_gap`` poses of another's, as
place recognition closes a revisit over consecutive frames, are tested run by run against the
map without them (all from one factorisation of the last map); a refuted run leaves the map,
and comes back only as a whole.

The test. At the solution the linearised system is ``H δx = −Aᵀ r``. Drawing whitened
measurement noise ``n ~ N(0, I)`` for every edge of the map gives ``δx = −H⁻¹Aᵀn ~ N(0, H⁻¹)``
exactly, so K draws (one factorisation, K back-substitutions) give, for every loop at once,

* a loop in the map: its residual ``U⁻¹n_l + J_l δx`` with covariance ``Σ_L − J_l H⁻¹ J_lᵀ``
  (the redundancy of data snooping, Baarda 1968): a stiff loop with almost no redundancy has a
  tiny residual *and* a tiny residual covariance, so the fold does not hide it;
* a loop not in the map: ``U⁻¹n'_l + J_l δx`` with covariance ``Σ_L + J_l H⁻¹ J_lᵀ``.

The draws are made once per audit and shared by all its tests (:func:`edge_draws`). With the
sample covariance Ŝ of K draws (mean known to be zero), ``T² = eᵀŜ⁻¹e`` gives
``T²(K − k + 1)/(K k) ~ F(k, K − k + 1)`` (Hotelling). The files' covariances are often off by a
scale (published graphs store √Ω, or invented weights); the variance factor ``σ0²``, the median
T² of the loops in the map over the median of χ²_k, rescales them (a robust a-posteriori
variance factor, robust to contamination below one half).

Two scales (FD-LOP-003's ``map_scale``). σ0² is read on the loops in the map, whose residuals
are set by loops beside each other and the short stretches between them; the map between far
poses is the long odometry between them. Where the odometry's error grows with length faster
than its stated covariance, the chains read a larger scale than σ0² (:func:`chain_scales`: the
median χ² of the map's loops no longer than the tested one against their odometry chains),
and one factor would make the long odometry far too stiff. So where that scale s is larger,
each loop is read with the odometry's draws scaled by √(s/σ0²): against the covariance of a
map whose odometry is that much noisier, relative to its loops, than stated.
"""

from __future__ import annotations

import hashlib
import itertools
import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.special import fdtrc
from scipy.stats import chi2 as chi2_dist
from scipy.stats import f as f_dist

from frontdiag.loops import lie, pcm
from frontdiag.loops.init import chordal_init
from frontdiag.loops.solve import (
    Factor,
    Linearised,
    Structure,
    _chol_upper,
    linearise,
    normal_equations,
    scatter_add,
    solve,
)

if TYPE_CHECKING:
    from frontdiag.loops.audit import LoopAudit

log = logging.getLogger(__name__)

F = NDArray[np.float64]
N_DRAWS = 64
MIN_VARIANCE_LOOPS = 10  # loops in the map below which the variance factor is not estimated
# A restart's map replaces a converged one only with a cost lower by more than this share: two
# converged solves of one graph that reached the same minimum from different starts differ by
# up to ~1e-4 of the cost (intel 105.254 / 105.265, CSAIL 3e-7), a different basin by far more
# (sphere2500 712 / 9 081, docs/loops.md).
RESTART_GAIN = 0.01
# The line of the two pre-tests, loose against p_alarm (1e-6): a run goes to the exact
# leave-run-out test when its joint test from the map test's draws (the weaker test: 64 draws
# for up to 32 rows) reads p under it, and one true run in a hundred costs a few
# back-substitutions; a group is re-solved when its linearised leave-group-out test reads a
# median p under it, which spares the groups far from refuted and nothing near the line.
PRE_P = 0.01


def map_edges(result: LoopAudit, in_map: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Edge mask of the map holding the odometry and the loops ``in_map`` (a mask over the
    table's loops)."""
    edges = result.odometry.copy()
    edges[result.table["edge"].to_numpy()[in_map]] = True
    return edges


@dataclass
class MapSystem:
    """The map of ``in_map`` linearised at poses P: every edge's linearisation (``lin_all``),
    the map's edges (``sel``) and theirs (``lin``), and the factorised normal matrix."""

    lin_all: Linearised
    sel: NDArray[np.intp]
    lin: Linearised
    fac: Factor


DRAWS_SEED = 0
"""Seed of the map test's draws: fixed, so that an audit gives the same table every run."""


@dataclass
class Draws:
    """The map test's draws for one audit: whitened noise for every edge (``edge``, edges x k x
    N_DRAWS) and each loop's own residual noise from it (``own``, U_l⁻¹ n_l, loops x k x
    N_DRAWS; U_l the Cholesky factor of the loop's information, as every test whitens with)."""

    edge: F
    own: F


def edge_draws(result: LoopAudit) -> Draws:
    """Whitened measurement noise ``n ~ N(0, I)`` for every edge, N_DRAWS draws a row, drawn
    once per audit and read by every map test of it (common random numbers): a loop's verdict
    changes between rounds only because the map did, not because its sampled covariance was
    drawn again. With fresh draws each round, loops near a line went in and out on the draws
    alone (intel's rounds ran to the cap on every benchmark configuration: 273 rounds over 30
    runs, 173 with one set; docs/loops.md). The loops' own term, the same in every test, is
    computed with them. Freed with the tested maps when the rounds end."""
    if result.draws is None:
        g = result.graph
        edge = np.random.default_rng(DRAWS_SEED).standard_normal((g.n_edges, g.k, N_DRAWS))
        loops = result.table["edge"].to_numpy()
        own = np.linalg.inv(_chol_upper(g.info[loops])) @ edge[loops]
        result.draws = Draws(edge, own)
    return result.draws


def map_system(result: LoopAudit, P: F, in_map: NDArray[np.bool_],
               structure: Structure | None = None) -> MapSystem:
    """Linearise every edge at P and factorise the normal matrix of the map's edges (the work
    :func:`map_test` and :func:`leave_cluster_out` share). ``structure``: what ``solve(keep=)``
    kept from a solve of this map, whose pattern and ordering are then reused (the same
    factor: only the values are computed again); ignored for another edge set."""
    g = result.graph
    n, k = g.n_vertices, g.k
    edges = map_edges(result, in_map)
    sel = np.flatnonzero(edges)
    U_all = _chol_upper(g.info)
    lin_all = linearise(P, g.src, g.dst, g.Z, U_all, n)
    # the map's edges are a subset of every edge: take their linearisation from lin_all
    lin = Linearised(r=lin_all.r.reshape(-1, k)[sel].ravel(), U=U_all[sel],
                     Je_i=lin_all.Je_i[sel], Je_j=lin_all.Je_j[sel], e=lin_all.e[sel])
    if structure is not None and np.array_equal(structure.edges, edges):
        H, _ = normal_equations(lin, g.src[sel], g.dst[sel], n, 0.0, structure.pattern)
        structure.factor.update(H)  # the solve is over: its factor is ours
        return MapSystem(lin_all, sel, lin, structure.factor)
    H, _ = normal_equations(lin, g.src[sel], g.dst[sel], n, 0.0)
    return MapSystem(lin_all, sel, lin, Factor(H, k))


def chain_scales(result: LoopAudit, in_map: NDArray[np.bool_]) -> F:
    """Per loop: the scale of the odometry over stretches no longer than the loop's own, read
    on the map's loops: the median χ² of those of them whose span (poses between their ends)
    is at most the loop's, against their odometry chains (the chain test's, before any
    optimisation), over χ²_k's median, floored as σ0² is; NaN where fewer than
    MIN_VARIANCE_LOOPS of the map's loops are that short, or where FD-LOP-003's
    ``map_scale`` is off.

    σ0² reads the loops in the map by their residuals in it, and those residuals are set by
    the loops beside each other and the short stretches between them (the loops of one revisit
    agree to centimetres). A loop is tested against the map's covariance between its poses as
    well, and where they are far apart that is the long odometry between them, whose scale σ0²
    does not read: where the odometry's error grows faster with length than its stated
    covariance, σ0² is far smaller than the chains' (KITTI 05, 2D: 0.079 against 2.3) and
    would refuse the true loops that close the largest drift. Read only on chains no longer
    than the loop's, a loop is never given more room than stretches of its length have shown
    (intel's chains read 0.24 over its shortest third of loops and 2.3 over its longest: one
    scale from all of them let false loops 30 poses long through). The loops in the map are
    the verified ones, so their chains are not read through false loops; a median, so up to
    half of them may be false."""
    t = result.table
    n = len(t)
    out = np.full(n, np.nan)
    r3 = result.rules.by_statistic("map")
    if not ("map_scale" in r3.params and bool(r3.param("map_scale"))):
        return out
    chi = t["chi2"].to_numpy(dtype=float)
    span = np.abs(t["span"].to_numpy())
    use = in_map & np.isfinite(chi)
    if use.sum() < MIN_VARIANCE_LOOPS:
        return out
    order = np.argsort(span[use], kind="stable")
    s_span, s_chi = span[use][order], chi[use][order]
    # the median of the map's loops up to each span: a running median over the chains sorted
    # by span, then each loop takes the one of the map's loops no longer than it
    cnt = np.searchsorted(s_span, span, side="right")
    ref = float(chi2_dist.ppf(0.5, result.graph.k))
    prefix = _running_median(s_chi)
    ok = cnt >= MIN_VARIANCE_LOOPS
    out[ok] = np.maximum(prefix[cnt[ok] - 1] / ref, 1e-12)
    return out


def _running_median(x: F) -> F:
    """``np.median(x[:c + 1])`` for every c, by two heaps (O(n log n); a median per prefix
    would be O(n²) at city10000's 10 688 loops)."""
    import heapq

    low: list[float] = []  # the smaller half, negated (a max-heap)
    high: list[float] = []  # the larger half
    out = np.empty(x.size)
    for c, v in enumerate(x.tolist()):
        if low and v > -low[0]:
            heapq.heappush(high, v)
        else:
            heapq.heappush(low, -v)
        if len(low) > len(high) + 1:
            heapq.heappush(high, -heapq.heappop(low))
        elif len(high) > len(low):
            heapq.heappush(low, -heapq.heappop(high))
        out[c] = -low[0] if len(low) > len(high) else 0.5 * (-low[0] + high[0])
    return out


def map_test(result: LoopAudit, P: F, in_map: NDArray[np.bool_],
             system: MapSystem | None = None) -> dict[str, F]:
    """Residual of every loop against poses P, and its T² / p-value (see the module doc), from
    the audit's draws (:func:`edge_draws`); ``system`` is :func:`map_system` of the same P and
    map, if already built."""
    g = result.graph
    loops = result.table["edge"].to_numpy()
    n, k = g.n_vertices, g.k
    sys_ = system or map_system(result, P, in_map)
    lin_all, sel, lin, fac = sys_.lin_all, sys_.sel, sys_.lin, sys_.fac
    e_all = lin_all.e
    drawn = edge_draws(result)
    noise = drawn.edge
    # δx = −H⁻¹Aᵀn for the map's edges' draws n
    WiT = np.swapaxes(lin.U @ lin.Je_i, -1, -2)
    WjT = np.swapaxes(lin.U @ lin.Je_j, -1, -2)
    ns = noise[sel]

    def response(draws_: F) -> F:
        b = scatter_add(g.src[sel], WiT @ draws_, n) + scatter_add(g.dst[sel], WjT @ draws_, n)
        return -fac.solve(b.reshape(n * k, N_DRAWS)).reshape(n, k, N_DRAWS)

    dx = response(ns)
    a, bb = g.src[loops], g.dst[loops]
    Ji, Jj = lin_all.Je_i[loops], lin_all.Je_j[loops]
    d_rel = Jj @ dx[bb] + Ji @ dx[a]
    own = drawn.own
    draws = own + d_rel
    S = np.einsum("mis,mjs->mij", draws, draws) / N_DRAWS
    e = e_all[loops]
    T2 = np.einsum("mi,mij,mj->m", e, np.linalg.inv(S), e)
    ref = float(chi2_dist.ppf(0.5, k))
    mine = T2[in_map]
    sigma0_sq = float(np.median(mine) / ref) if mine.size >= MIN_VARIANCE_LOOPS else 1.0
    sigma0_sq = max(sigma0_sq, 1e-12)
    d = g.dim
    map_var_file = np.einsum("mis,mis->m", d_rel[:, :d], d_rel[:, :d]) / N_DRAWS
    s_chain = chain_scales(result, in_map) if mine.size >= MIN_VARIANCE_LOOPS \
        else np.full(loops.size, np.nan)
    rho = np.where(np.isfinite(s_chain), np.maximum(s_chain / sigma0_sq, 1.0), 1.0)
    if (rho > 1.0).any():
        # the odometry's noise on the chains' scale, the loops' on σ0²: δx is linear in the
        # noise, so the map's response with the odometry's draws scaled by √ρ is the unit
        # response plus (√ρ − 1) times its response to the odometry's draws alone; every loop,
        # in the map or out, is read against the covariance the map has when its odometry is
        # ρ times as noisy as the file states relative to the loops
        dx_o = response(ns * result.odometry[sel][:, None, None])
        up = np.flatnonzero(rho > 1.0)
        d_rel = d_rel.copy()
        d_rel[up] += (np.sqrt(rho[up]) - 1.0)[:, None, None] * (
            Jj[up] @ dx_o[bb[up]] + Ji[up] @ dx_o[a[up]])
        draws = own + d_rel
        S = np.einsum("mis,mjs->mij", draws, draws) / N_DRAWS
        T2 = np.einsum("mi,mij,mj->m", e, np.linalg.inv(S), e)
    T2s = T2 / sigma0_sq
    Fstat = T2s * (N_DRAWS - k + 1) / (N_DRAWS * k)
    p = f_dist.sf(Fstat, k, N_DRAWS - k + 1)
    R = lie.inv(g.Z[loops]) @ lie.inv(P[a]) @ P[bb]
    map_var = np.einsum("mis,mis->m", d_rel[:, :d], d_rel[:, :d]) / N_DRAWS
    # what believing the loop moves the map by, G e with G = C_d S⁻¹ (C_d the map's own
    # covariance between the loop's poses): outside the map S = Σ_L + C_d, the share of the
    # residual the map would absorb; inside it S = Σ_L − C_d, and G e = e_out − e_in is what
    # the loop has already moved it by. The variance factor cancels.
    Cd = np.einsum("mis,mjs->mij", d_rel, d_rel) / N_DRAWS
    fold = np.einsum("mij,mj->mi", Cd @ np.linalg.inv(S), e)[:, :d]
    return {"map_sigma_m": np.sqrt(map_var * sigma0_sq), "T2": T2s, "p": p,
            "sigma0_sq": np.full(loops.size, sigma0_sq),
            "chain_scale": s_chain, "map_scale": sigma0_sq * rho,
            "map_sigma_file_m": np.sqrt(map_var_file), "e": e, "draws": draws,
            "fold_m": np.linalg.norm(fold, axis=1),
            "residual_m": np.linalg.norm(R[:, :g.dim, g.dim], axis=1),
            "residual_deg": np.degrees(lie.rotation_angle(R))}


TESTED_KEPT = 2
"""How many tested maps an audit keeps for :func:`tested_map`."""


def tested_map(result: LoopAudit, P: F, in_map: NDArray[np.bool_],
               structure: Structure | None = None) -> tuple[MapSystem, dict[str, F]]:
    """:func:`map_system` and :func:`map_test` of the map of ``in_map`` at ``P``, or those of
    the same map already tested in this audit: the run screen tests the map the last round
    tested, and the round after a corroboration the map the corroboration tested; a second
    test would give the same result (M3500 with 10 % local false loops: 2 of 9 map tests; the
    audit 1.13x faster, median of 30 M3500 runs)."""
    key = (hashlib.blake2b(np.ascontiguousarray(P).tobytes(), digest_size=16).digest(),
           in_map.tobytes())
    for k, system, res in result.tested_maps:
        if k == key:
            return system, res
    system = map_system(result, P, in_map, structure)
    res = map_test(result, P, in_map, system=system)
    result.tested_maps[:] = [*result.tested_maps, (key, system, res)][-TESTED_KEPT:]
    return system, res


def _raw_sigma(res: dict[str, F]) -> F:
    """The map's σ between each loop's poses in the file's units (before the variance factor),
    comparable with the chain's σ."""
    return res["map_sigma_file_m"]


def _stiffer(res: dict[str, F], chain_sigma: F, share: float) -> NDArray[np.bool_]:
    """Whether the map is clearly more certain between a loop's poses than its odometry chain:
    σ at most ``share`` x the chain's (FD-LOP-003's ``overrule_chain``, whose reason derives
    it)."""
    with np.errstate(invalid="ignore"):
        return _raw_sigma(res) <= share * chain_sigma


Solved = tuple[NDArray[np.bool_], F, dict[str, float]]
"""A map already solved: its loops (a mask over the table), its poses and the solve's stats."""


def _corroborate(result: LoopAudit, P: F, in_map: NDArray[np.bool_], res: dict[str, F],
                 p_alarm: float, power_m: float, barred: NDArray[np.bool_]
                 ) -> tuple[NDArray[np.bool_], Solved | None]:
    """Loops that passed without power, admitted because other clusters confirm them, and the
    map of the verified loops plus every candidate, solved from ``P`` (None if not solved).

    The candidates passed the last round but the map was too loose between their poses
    (σ > ``power_m``). They are clustered by the pair test's groups (loops between the same
    stretches, consistent with each other; a loop without a consistent neighbour is a cluster
    of its own). Each cluster is tested, with power, against the map of the verified loops
    plus every *other* candidate cluster: a place-recognition alias seen over several frames
    agrees with itself, but not by chance with independent loops between other places (the
    inter-cluster consistency of Latif, Cadena & Neira 2013, RRR). A cluster that passes there
    with power joins the map; the rounds then re-test it with the rest.

    Every cluster's test comes from one factorisation (:func:`leave_cluster_out`): the map
    holding every candidate is solved once, and each cluster's residuals and covariances
    against that map without it are the deleted residuals of data snooping for a group of
    observations (Baarda 1968), exact for the map linearised there. The variance factor is
    that of the map holding every candidate (:func:`map_test`).
    """
    t = result.table
    cand = ~in_map & (res["p"] >= p_alarm) & ~(res["map_sigma_m"] <= power_m) & ~barred \
        & (t["verdict"] != "fail").to_numpy()
    idx = np.flatnonzero(cand)
    out = np.zeros(len(t), bool)
    if idx.size < 2:
        return out, None
    group = t["group"].to_numpy()[idx]
    # a loop without a consistent neighbour (group -1) is a cluster of its own
    label = np.where(group >= 0, group, -(idx + 2))
    clusters = np.unique(label)
    if clusters.size < 2:
        return out, None
    g = result.graph
    held = in_map | cand
    P_all, st_all = solve(g, map_edges(result, held), P, tol=1e-6)
    members = [idx[label == c] for c in clusters.tolist()]
    for mine, (p, _T2, sigma) in zip(
            members, tested_without(result, P_all, held, members),
            strict=True):
        out[mine[(p >= p_alarm) & (sigma <= power_m)]] = True
    return out, (held, P_all, st_all)


def leave_cluster_out(result: LoopAudit, P: F, in_map: NDArray[np.bool_],
                      clusters: list[NDArray[np.int64]], system: MapSystem | None = None
                      ) -> list[tuple[F, F]]:
    """For each cluster (table rows of loops in the map of ``in_map``, solved at ``P``), every
    one of its loops' T² and translation variance against the map without the cluster, before
    the variance factor; one factorisation for all clusters.

    With A the whitened Jacobian of the map's edges and H = AᵀA at the solution, take the
    cluster's rows A_c and whitened residuals r_c, and M = A_c H⁻¹ A_cᵀ (the cluster's block of
    the hat matrix). Without the cluster the normal matrix is H − A_cᵀA_c, and by the
    Sherman-Morrison-Woodbury identity A_c (H − A_cᵀA_c)⁻¹ A_cᵀ = M (I − M)⁻¹, so the
    cluster's residuals against the map solved without it are r_del = (I − M)⁻¹ r_c, with
    covariance I + M (I − M)⁻¹ = (I − M)⁻¹ (the deleted residuals of data snooping for a group,
    Baarda 1968). Per loop l: T² = r_del,lᵀ [(I − M)⁻¹]_ll⁻¹ r_del,l, χ²_k if the loops are true
    and the covariances right; the map's own covariance between its poses is
    U_l⁻¹ [M (I − M)⁻¹]_ll U_l⁻ᵀ, whose translation trace is returned. Exact for the map
    linearised at P. M comes from the factor's forward half on the rows the cluster's poses
    reach in its elimination tree (:meth:`Factor.quadratic`): on M3500 about 600 of 10 500
    rows, where a back-substitution per residual row of the cluster took 0.8 ms each.
    """
    g = result.graph
    k, d = g.k, g.dim
    loops = result.table["edge"].to_numpy()
    sys_ = system or map_system(result, P, in_map)
    sel, lin, fac = sys_.sel, sys_.lin, sys_.fac
    where = np.full(g.n_edges, -1)
    where[sel] = np.arange(sel.size)
    out = []
    for rows in clusters:
        m = where[loops[rows]]  # the loops' places among the map's edges
        if (m < 0).any():
            raise ValueError("leave_cluster_out: a cluster's loop is not in the map")
        Wi, Wj = lin.U[m] @ lin.Je_i[m], lin.U[m] @ lin.Je_j[m]  # (c, k, k) whitened blocks
        c = m.size
        # A_cᵀ, one column per whitened residual row, held as its nonzero rows (the unknowns
        # of the poses the cluster's loops join)
        verts = np.concatenate([g.src[sel[m]], g.dst[sel[m]]])
        poses, slot = np.unique(verts, return_inverse=True)
        At = np.zeros((poses.size * k, c * k))
        cols = np.arange(c * k).reshape(c, k)
        for blk, sl in ((Wi, slot[:c]), (Wj, slot[c:])):
            rr = (sl[:, None, None] * k + np.arange(k)[None, None, :])  # (c, 1, k) rows
            At[np.broadcast_to(rr, (c, k, k)).ravel(),
               np.broadcast_to(cols[:, :, None], (c, k, k)).ravel()] += blk.ravel()
        rows = (poses[:, None] * k + np.arange(k)).ravel()
        Mx = fac.quadratic(rows, At)
        Q = np.linalg.inv(np.eye(c * k) - Mx)  # (I − M)⁻¹
        r_c = lin.r.reshape(-1, k)[m].ravel()
        r_del = (Q @ r_c).reshape(c, k)
        Q_ll = Q.reshape(c, k, c, k)[np.arange(c), :, np.arange(c), :]  # (c, k, k) blocks
        T2 = np.einsum("mi,mij,mj->m", r_del, np.linalg.inv(Q_ll), r_del)
        Uinv = np.linalg.inv(lin.U[m])
        C = Uinv @ (Q_ll - np.eye(k)) @ np.swapaxes(Uinv, -1, -2)  # M (I − M)⁻¹ = Q − I
        out.append((T2, np.einsum("mii->m", C[:, :d, :d])))
    return out


def tested_without(result: LoopAudit, P: F, in_map: NDArray[np.bool_],
                   clusters: list[NDArray[np.intp]], own_factor: bool = False
                   ) -> list[tuple[F, F, F]]:
    """Per cluster (table rows of loops in the map of ``in_map`` at ``P``): every one of its
    loops' p, T² and map σ (m) against the map without the cluster (:func:`leave_cluster_out`),
    after the variance factor of the map (:func:`map_test`) or, with
    ``own_factor``, of the map's loops outside the cluster (a cluster in the map inflates the
    factor of the map that holds it)."""
    g = result.graph
    system, m = tested_map(result, P, in_map)
    s0_map = float(m["sigma0_sq"][0])
    raw = m["T2"] * s0_map
    median_chi2 = float(chi2_dist.ppf(0.5, g.k))
    out = []
    for rows, (T2, var) in zip(clusters, leave_cluster_out(result, P, in_map, clusters, system),
                               strict=True):
        s0 = s0_map
        if own_factor:
            rest = in_map.copy()
            rest[rows] = False
            s0 = max(float(np.median(raw[rest])) / median_chi2, 1e-12) \
                if rest.sum() >= MIN_VARIANCE_LOOPS else 1.0
        out.append((chi2_dist.sf(T2 / s0, g.k), T2 / s0, np.sqrt(var * s0)))
    return out


def _leave_out(result: LoopAudit, P: F, in_map: NDArray[np.bool_], mine: NDArray[np.bool_]
               ) -> tuple[float, float]:
    """Median p and T² of the loops ``mine`` against the map of ``in_map`` without them,
    solved from ``P``."""
    rest = in_map & ~mine
    edges = map_edges(result, rest)
    Pg, _ = solve(result.graph, edges, P, tol=1e-6)
    res = map_test(result, Pg, rest)
    return float(np.median(res["p"][mine])), float(np.median(res["T2"][mine]))


def _group_suspects(result: LoopAudit, P: F, in_map: NDArray[np.bool_], group: NDArray[np.int64],
                    ids: list[int]) -> list[int]:
    """The groups among ``ids`` (all in the map of ``in_map`` at ``P``) that the group screen
    re-solves the map without: those whose linearised leave-group-out test (the deleted
    residuals of :func:`leave_cluster_out`, every group from one factorisation) reads a median
    p under PRE_P. A group in the map inflates the variance factor it is read against, so each
    group is read against the factor of the map's other loops (their median T² in the map
    test at P). The re-solve and the sampled test decide; this only spares them for the groups
    the linearised test finds far from refuted (intel with 30 % grouped false loops: 52 re-solves,
    6.1 of the audit's 7.9 s)."""
    if not ids:
        return []
    members = [np.flatnonzero(in_map & (group == gid)) for gid in ids]
    tests = tested_without(result, P, in_map, members, own_factor=True)
    return [gid for gid, (p, _T2, _s) in zip(ids, tests, strict=True) if np.median(p) < PRE_P]


def screened_groups(group: NDArray[np.int64], in_map: NDArray[np.bool_]) -> list[int]:
    """The pair-test groups of the map that the screen tests: every group but one holding
    half the map's loops or more (the variance factor, and with it every test, assumes the
    loops in the map are mostly true, so such a group is not tested against the rest)."""
    ids, counts = np.unique(group[in_map], return_counts=True)
    return [int(g) for g, c in zip(ids, counts, strict=True) if g >= 0 and 2 * c < in_map.sum()]


def _refuted_together(result: LoopAudit, P: F, in_map: NDArray[np.bool_], gids: list[int],
                      p_alarm: float) -> tuple[F, dict[int, tuple[float, float]]]:
    """The map of ``in_map`` without all the pair-test groups ``gids``, solved from ``P``, and
    the groups among them that it refutes (the median of their loops' p under ``p_alarm``),
    with their median p and T²."""
    group = result.table["group"].to_numpy()
    trial = in_map & ~np.isin(group, gids)
    P_t, _ = solve(result.graph, map_edges(result, trial), P, tol=1e-6)
    res = map_test(result, P_t, trial)
    found = {}
    for gid in gids:
        mine = in_map & (group == gid)
        p = float(np.median(res["p"][mine]))
        if p < p_alarm:
            found[gid] = (p, float(np.median(res["T2"][mine])))
    return P_t, found


def _screen_beside_dominant(result: LoopAudit, P: F, in_map: NDArray[np.bool_], p_alarm: float,
                           gids: list[int]
                           ) -> tuple[NDArray[np.bool_], F, dict[int, tuple[float, float]], int]:
    """The group screen's first pass where one pair-test group holds half the first map or
    more (it is not screened: :func:`screened_groups`): every other group leaves the map
    together, the map of the rest is solved once, and each group is tested against it; those
    whose loops' median p is under ``p_alarm`` stay out.

    The other groups are then often many small ones that the pair test formed by chance
    among false loops, where the file's covariances are loose. Together they bend the map and
    inflate its variance factor until neither the linearised test nor a re-solve without one
    of them refutes it (sphere2500 with 50 % random false loops: 336 false loops in 138
    groups beside one group of 2 511 loops, σ0² 23.6, and 3 groups suspected; against the map
    of the large group alone σ0² read 2.9 and all 138 were refuted). A true group among them
    is judged against a map that holds no group but the large one, so it is not refuted by a
    false one's bend.

    Returns the loops kept, the poses of their map (``P`` where nothing left), the groups
    refuted with their median p and T², and the solves spent (0 without a dominant group)."""
    group = result.table["group"].to_numpy()
    ids, counts = np.unique(group[in_map], return_counts=True)
    if not gids or not (2 * counts[ids >= 0] >= in_map.sum()).any():
        return in_map.copy(), P, {}, 0
    g = result.graph
    P_t, gone = _refuted_together(result, P, in_map, gids, p_alarm)
    out = in_map & ~np.isin(group, list(gone))
    if len(gone) == len(gids):
        return out, P_t, gone, 1
    if not gone:
        return out, P, gone, 1
    P_o, _ = solve(g, map_edges(result, out), P_t, tol=1e-6)
    return out, P_o, gone, 2


def _screen_groups(result: LoopAudit, P: F, in_map: NDArray[np.bool_], p_alarm: float,
                   gids: list[int]) -> tuple[NDArray[np.bool_], dict[int, tuple[float, float]]]:
    """The first map's loops, less the pair-test groups that the map of the others refutes.

    Used when the first map is seeded with the pair test's groups (the chains too uncertain to
    test loops with power): a group of mutually consistent false loops (an alias seen over
    several frames) passes the pair test like a true group, and in the map it bends the
    least-squares solution and inflates the variance factor, so that the rounds cannot refute
    it. Each group is tested against the map solved without it, from the first map: the
    leave-one-out residual of data snooping for a group of observations (Baarda 1968), with
    the pair test's groups as the clusters of RRR's inter-cluster check (Latif, Cadena & Neira
    2013). A group is refuted when the median of its loops' p is under ``p_alarm``. A false
    group bends the map that the others are tested against, so a true group can read refuted
    beside it: the refuted groups leave one at a time, the most refuted first (lowest median
    p, then highest median T²), and the others are tested again against the map without it.
    A false group can also pass while another bends the map its way: once no refuted group is
    left, every group still in the map is tested again, until none is refuted. Each pass
    re-solves the map only without the groups its linearised test suspects
    (:func:`_group_suspects`). Where one group holds half the map or more, every other group
    is first tested against the map of the rest (:func:`_screen_beside_dominant`).
    Returns the loops kept and, per group taken out, its median p and T² when it left.
    """
    t = result.table
    group = t["group"].to_numpy()
    out, P, gone, _ = _screen_beside_dominant(result, P, in_map, p_alarm, gids)
    gids = [gid for gid in gids if gid not in gone]

    def refuted(ids: list[int], P: F) -> dict[int, tuple[float, float]]:
        """The groups among ``ids`` that the map of ``out`` without them refutes."""
        found = {}
        for gid in _group_suspects(result, P, out, group, ids):
            p, T2 = _leave_out(result, P, out, out & (group == gid))
            if p < p_alarm:
                found[gid] = (p, -T2)
        return found

    cand = refuted(gids, P)
    while cand:
        worst = min(cand, key=lambda c: (cand[c], c))
        p_w, neg_T2 = cand.pop(worst)
        gone[worst] = (p_w, -neg_T2)
        out &= group != worst
        P, _ = solve(result.graph, map_edges(result, out), P, tol=1e-6)
        cand = refuted(list(cand), P)
        if not cand:
            # the groups that passed beside the ones gone: a false group can pass while
            # another bends the map its way, and is refuted once that one has left
            cand = refuted([g_ for g_ in gids if g_ not in gone], P)
    return out, gone


def loop_runs(result: LoopAudit, rows: NDArray[np.intp], gap: int, max_len: int | None = None
              ) -> list[NDArray[np.intp]]:
    """The runs among the loops ``rows`` (table rows): sets of two or more loops linked by
    pairs whose two ends are each at most ``gap`` poses apart (i within gap of i', j within gap
    of j'), as place recognition closes a revisit over several consecutive frames. Loops with
    no such neighbour are left out (the map test is already their leave-one-out test).

    A run longer than ``max_len`` loops (a long revisit: every loop of sphere2500 links to the
    next, 2450 in one run) is cut into windows of ``max_len`` consecutive loops (in order of
    their first pose), each starting half a window after the one before, so that any stretch
    of up to half a window lies whole in one of them."""
    if rows.size < 2:
        return []
    g = result.graph
    edges = result.table["edge"].to_numpy()[rows]
    a, b = g.src[edges], g.dst[edges]
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    pairs = pcm.candidate_pairs(lo, hi, gap)
    if pairs.shape[0] == 0:
        return []
    link = coo_matrix((np.ones(pairs.shape[0]), (pairs[:, 0], pairs[:, 1])),
                      shape=(rows.size, rows.size))
    _, label = connected_components(link, directed=False)
    size = np.bincount(label)
    out = []
    for c in np.flatnonzero(size >= 2).tolist():
        mine = np.flatnonzero(label == c)
        if max_len is None or mine.size <= max_len:
            out.append(rows[mine])
            continue
        mine = mine[np.lexsort((hi[mine], lo[mine]))]
        step = max(max_len // 2, 1)
        starts = [*range(0, mine.size - max_len, step), mine.size - max_len]
        out.extend(rows[np.sort(mine[s_:s_ + max_len])] for s_ in starts)
    return out


def _joint_p(res: dict[str, F], rows: NDArray[np.intp]) -> float:
    """p of the joint test of the loops ``rows`` against the map of ``res`` (:func:`map_test`),
    from its draws: Hotelling's T² of the stacked residuals under their joint sample covariance
    (the draws share δx, so they carry the loops' correlations through the map), after the
    variance factor; 0 where the stack has too many rows for the draws to estimate it."""
    e = res["e"][rows].ravel()
    draws = res["draws"][rows]
    n_draws = draws.shape[-1]
    dim = e.size
    if 2 * dim > n_draws:
        return 0.0
    D = draws.reshape(dim, n_draws)
    try:
        T2 = float(e @ np.linalg.solve(D @ D.T / n_draws, e)) / float(res["sigma0_sq"][0])
    except np.linalg.LinAlgError:
        return 0.0
    if not T2 > 0:  # where f.sf reads 1 (T2 <= 0) and fdtrc nothing
        return 1.0 if T2 <= 0 else float("nan")
    # f.sf's own kernel, without its per-call argument handling (0.1 ms, ~400 calls on M3500)
    return float(fdtrc(dim, n_draws - dim + 1, T2 * (n_draws - dim + 1) / (n_draws * dim)))


def _screen_runs(result: LoopAudit, P: F, in_map: NDArray[np.bool_], p_alarm: float,
                 runs: list[NDArray[np.intp]], res: dict[str, F]
                 ) -> tuple[NDArray[np.bool_], F, dict[int, tuple[float, float]]]:
    """The map's loops less the runs that the map without them refutes, the poses of that
    map, and per run taken out (its index in ``runs``) its median p and T² when it left;
    ``res`` is the map test of the map ``in_map`` at ``P`` (its draws pick the runs tested).

    A pair-test group is every loop joined by consistent pairs, so where the chains are
    loose (σ of half a metre over a few dozen poses) a run of false loops whose claims are
    within a metre of the truth joins the group of the true loops around it, and the group
    screen cannot take it out alone. In the map, the run's loops support each other, so each
    passes the leave-one-out map test. Each run is tested against the map without it, all from
    one factorisation (:func:`leave_cluster_out`; RRR's intra-cluster test of Latif, Cadena &
    Neira 2013 against the map rather than the chain): a run is refuted when the median of its
    loops' p is under ``p_alarm``. As in the group screen, the most refuted run leaves first,
    and the other refuted ones are tested again against the map without it (a false run bends
    the map the true runs beside it are tested against).
    """
    g = result.graph
    out = in_map.copy()
    gone: dict[int, tuple[float, float]] = {}

    def refuted(ids: list[int], P: F) -> dict[int, tuple[float, float]]:
        # a window of a long run can share loops with one already gone: the rest is tested
        left = {i: runs[i][out[runs[i]]] for i in ids}
        ids = [i for i in ids if left[i].size >= 2]
        found: dict[int, tuple[float, float]] = {}
        if not ids:
            return found
        tests = tested_without(result, P, out, [left[i] for i in ids])
        for i, (p, T2, _s) in zip(ids, tests, strict=True):
            if np.median(p) < p_alarm:
                found[i] = (float(np.median(p)), -float(np.median(T2)))
        return found

    # The exact test costs one back-substitution per residual row of the runs tested (3 900 on
    # M3500, about 1 s). For a run in the map, the joint test of its loops together reads the
    # same statistic in the map as without it, r_delᵀ(I − M)r_del = r_cᵀ(I − M)⁻¹r_c (Baarda's
    # test for a group of observations); the last round's draws estimate it, so only the runs
    # whose joint test there reads p < PRE_P go to the exact, per-loop test.
    suspect = [i for i, rows in enumerate(runs) if _joint_p(res, rows) < PRE_P]
    cand = refuted(suspect, P) if suspect else {}
    while cand:
        worst = min(cand, key=lambda c: (cand[c], c))
        p_w, neg_T2 = cand.pop(worst)
        gone[worst] = (p_w, -neg_T2)
        out[runs[worst]] = False
        P, _ = solve(g, map_edges(result, out), P, tol=1e-6)
        if cand:
            cand = refuted(list(cand), P)
    return out, P, gone


def verify_against_map(result: LoopAudit) -> None:
    """Run the rounds and fold their outcome into the table's verdicts (module doc)."""
    t = result.table
    g = result.graph
    rules = result.rules
    r3 = rules.by_statistic("map")
    r4 = rules.by_statistic("untestable")
    fold_m = float(r4.param("fold_m"))
    p_alarm = float(r3.param("p_alarm"))
    power_m = float(r3.param("power_m"))
    overrule = float(r3.param("overrule_chain"))
    corroborate = bool(r3.param("corroborate")) if "corroborate" in r3.params else False
    run_gap = int(r3.param("run_gap")) if "run_gap" in r3.params else 0
    failed = (t["verdict"] == "fail").to_numpy()
    chain_sigma = t["chain_sigma_m"].to_numpy()
    # a loop its chain refused comes back only against a map that knows more between its poses
    # than the chain did: the sampled map test is weaker than the chain's chi2 test (heavier
    # tails), so against a map no stiffer than the chain it would overrule a stronger refusal
    chain_refused = failed & (t["rule"] == rules.by_statistic("chi2").id).to_numpy()
    screen = bool(r3.param("screen_groups")) if "screen_groups" in r3.params else False
    screen_budget = float(r3.param("screen_budget")) if "screen_budget" in r3.params \
        else float("inf")
    in_map = ~failed & (chain_sigma <= fold_m)
    seeded_by_groups = bool(in_map.sum() < MIN_VARIANCE_LOOPS)
    if seeded_by_groups:
        # too few chain-confirmed loops to estimate the variance factor (the first map would
        # be the odometry and a loop or two, on the file's covariances): seed with the loops
        # the pair test grouped instead
        in_map = ~failed & (t["group_size"].to_numpy() >= 2)
    P = result.chain.P.copy()
    max_rounds = int(r3.param("max_rounds"))
    was_in = in_map.copy()  # in the map in some round
    rounds = 0

    last: dict[str, float] = {}  # the stats of the last map's solve
    screened: dict[int, tuple[float, float]] = {}  # groups the screen took out of the first map
    taken = np.zeros(len(t), bool)  # and their loops that were in it
    barred_runs: list[NDArray[np.intp]] = []  # runs the run screen took out, judged whole
    run_out = np.zeros(len(t), bool)  # the loops of those still out
    contested = np.zeros(len(t), bool)  # loops of a cycle of rounds: out of the map for good
    leaves = np.zeros(len(t), np.int64)  # times each loop left the map from one round to the next
    max_leaves = int(r3.param("max_leaves")) if "max_leaves" in r3.params else 0

    def screen_over_budget(P: F, in_map: NDArray[np.bool_], gids: list[int]
                           ) -> tuple[NDArray[np.bool_], dict[int, tuple[float, float]]] | None:
        """None where the screen's solves (up to one per group, each over every pose) are
        within ``screen_budget``. Else only the pass beside a group holding half the map runs
        (:func:`_screen_beside_dominant`, one or two solves), and the notes say so."""
        work = len(gids) * g.n_vertices * g.k**2
        if work <= screen_budget:
            return None
        kept, _, gone, solves = _screen_beside_dominant(result, P, in_map, p_alarm, gids)
        were = "was" if len(gone) == 1 else "were"
        what = (f"{len(gone)} of them {were} refuted against the map of the one group holding "
                "half the map, tested together; the others were not screened" if solves else
                "no group holds half the map, so none was screened")
        result.notes.append(
            f"the first map's {len(gids)} pair-test groups were over FD-LOP-003's screen_budget "
            f"for screening one at a time (each up to one solve of the {g.n_vertices}-pose "
            f"graph: {work:.3g} against {screen_budget:.3g}): {what}. A group of mutually "
            "consistent false loops in the first map can then be kept. Raise screen_budget in a "
            "rules file (--rules) to screen them, at the cost of up to that many solves")
        return kept, gone

    # every map solved in this audit, by its loops: a round whose map an earlier round
    # already solved (a map that recurs after a cycle: CSAIL's rounds 2 and 4) takes that
    # solution instead of solving the same problem again from the poses of the map before it
    # and from the chordal start. The earlier solve started from the chordal start too, or
    # from a map whose loops were all in this one: never from poses bent by loops outside it,
    # which is what the restart guards against. Its map test, if still among the tested
    # maps, comes with it. Poses only: a factorisation per map would hold tens of MB on 3D
    # graphs. The corroboration's map of every candidate enters it too (solved from the map
    # of the verified loops, all of them in it)
    solved_maps: dict[bytes, tuple[F, dict[str, float]]] = {}

    def solve_round(r: int, edges: NDArray[np.bool_], P: F, dropped: bool,
                    factored: list[Structure]) -> tuple[F, dict[str, float]]:
        """The map of round r's ``edges``, from the map before it (``P``); ``dropped``: this
        round's map left out loops the one before it held."""
        if r == 1:
            # the first map from the chordal start of its edges, and from the odometry
            # chain only where that solve did not converge (the lower cost is kept). The
            # chain start was 6.0 m from the optimum on intel after 50 iterations; over the
            # 27 benchmark configurations of M3500, intel and CSAIL (seed 1) the chordal
            # start reached the same minimum as the chain's or one 10-200x lower, and in
            # fewer iterations (docs/loops.md)
            P_warm, st_warm = solve(g, edges, chordal_init(g, edges, P), tol=1e-6,
                                    keep=factored)
            if not st_warm.get("converged", 0.0):
                P_o, st_o = solve(g, edges, P, tol=1e-6, keep=factored)
                if st_o["cost"] < st_warm["cost"]:
                    P_warm, st_warm = P_o, st_o
            return P_warm, st_warm
        P_warm, st_warm = solve(g, edges, P, tol=1e-6, keep=factored)
        if dropped:
            # also from the chordal start of this round's edges: the loops this round
            # dropped had bent the map before it, and LM from there can stop at a minimum
            # of their basin (sphere2500 with random false loops: 9 081 from the map that
            # held 27 false loops, 712 from the chordal start) or run out of iterations
            # still inside it (intel with 50 % grouped false loops, seeds 2 and 3: the
            # screened-out groups passed again against the bent map and 48 and 24 false
            # loops were kept). Two minima are told apart by cost beyond the solver's own
            # precision (RESTART_GAIN); a round that only adds verified loops starts from
            # the map before it.
            P_c, st_c = solve(g, edges, chordal_init(g, edges, P), tol=1e-6, keep=factored)
            if st_c["cost"] < st_warm["cost"] * (1 - RESTART_GAIN):
                P_warm, st_warm = P_c, st_c
        return P_warm, st_warm

    def run_rounds(in_map: NDArray[np.bool_], P: F, first: int
                   ) -> tuple[NDArray[np.bool_], F, dict[str, F], int]:
        res: dict[str, F] = {}
        r = first
        prev: NDArray[np.bool_] | None = None  # the loops of the map before this round's
        # max_rounds counts from the first map whose solve converged: a round tested against
        # a map still descending at the iteration cap can drop true loops that the map, once
        # converged, would take back (sphere2500 with grouped false loops: seven capped rounds,
        # 205 632 down to 15 370, then 92 true loops passing with power against the converged
        # map were left out when the rounds stopped). If no map converges within max_rounds
        # (intel's did not, before FD-LOP-005 capped its overconfident odometry), the rounds
        # stop there as before
        end = first + max_rounds
        converged_once = False
        states: list[bytes] = []  # the loops of each round's map, in order
        for r in itertools.count(first):
            states.append(in_map.tobytes())
            edges = map_edges(result, in_map)
            memo = solved_maps.get(states[-1])
            factored: list[Structure] = []
            if memo is not None:
                P, st = memo
            else:
                P, st = solve_round(r, edges, P, prev is not None and bool((prev & ~in_map).any()),
                                    factored)
                solved_maps[states[-1]] = (P, st)
            if st.get("converged", 0.0) and not converged_once:
                converged_once = True
                end = max(end, r + max_rounds)
            gids = screened_groups(t["group"].to_numpy(), in_map) \
                if r == 1 and seeded_by_groups and screen else []
            if gids:
                # on the first map, where every group the pair test formed is in (screened on
                # later maps, after true loops beside the false groups were swamped, intel with
                # 50 % grouped false loops kept 10 of 128 false loops instead of none)
                kept, gone = screen_over_budget(P, in_map, gids) \
                    or _screen_groups(result, P, in_map, p_alarm, gids)
                screened.update(gone)
                taken[:] = in_map & ~kept
                if taken.any():  # the next round solves the map without them
                    prev, in_map = in_map, kept
                    continue
            last.clear()
            last.update(st)
            # either solve's factor has this map's pattern: the last one kept is reused
            _, res = tested_map(result, P, in_map, factored[0] if factored else None)
            # a run the run screen took out is judged as a whole: it comes back (its loops then
            # as any other) once the median p of its loops, each tested against this map, which
            # holds none of them, passes; until then none of its loops joins, since its loops
            # nearest the truth pass alone and each one admitted bends the map to the next
            run_out[:] = False
            for rows in barred_runs:
                if not np.median(res["p"][rows]) >= p_alarm:
                    run_out[rows] = True
            # admit a loop only once its test had power: map σ small enough to refute a lie
            # of a few fold_m (5.5 σ at p = 1e-6); a passing loop already in the map stays
            nxt = (res["p"] >= p_alarm) & (in_map | (res["map_sigma_m"] <= power_m)) \
                & ~(chain_refused & ~_stiffer(res, chain_sigma, overrule)) & ~run_out \
                & ~contested
            if np.array_equal(nxt, in_map) or r >= end:
                break
            if nxt.tobytes() in states:
                # a cycle: the next map is one an earlier round already tested, so the rounds
                # would repeat it until max_rounds and stop wherever the cap falls. Loops that
                # contradict one another but not the rest (CSAIL's 387→526 and 387→527: both
                # in, both refuted; both out, both pass) enter and leave together. The loops
                # not in every map of the cycle leave it for good and are judged against the
                # maps of the others
                cyc = [np.frombuffer(b, dtype=bool) for b in
                       states[states.index(nxt.tobytes()):]]
                contested[:] |= np.logical_or.reduce(cyc) & ~np.logical_and.reduce(cyc)
                nxt &= ~contested
            leaves[:] += in_map & ~nxt
            if max_leaves and (leaves >= max_leaves).any():
                # the maps need not repeat exactly for a loop to go in and out (intel's do not):
                # one swamped by a false loop leaves once and comes back once that is out; one
                # leaving again is borderline and leaves for good (FD-LOP-003's max_leaves)
                contested[:] |= leaves >= max_leaves
                nxt &= ~contested
            prev, in_map = in_map, nxt
            was_in[:] |= in_map
        return in_map, P, res, r

    in_map, P, res, rounds = run_rounds(in_map, P, 1)
    corroborated = np.zeros(len(t), bool)
    if corroborate:
        extra, solved = _corroborate(result, P, in_map, res, p_alarm, power_m,
                                     chain_refused & ~_stiffer(res, chain_sigma, overrule))
        if extra.any():
            corroborated = extra
            if solved is not None:  # the map of the verified loops and every candidate
                solved_maps[solved[0].tobytes()] = (solved[1], solved[2])
            in_map, P, res, more = run_rounds(in_map | extra, P, rounds + 1)
            rounds = more
    runs_gone: list[tuple[NDArray[np.intp], float, float]] = []
    if run_gap > 0:
        # windows the draws of the map test can read jointly (N_DRAWS / 2 rows): 10 loops
        # in 2D, 5 in 3D
        runs = loop_runs(result, np.flatnonzero(in_map), run_gap, N_DRAWS // (2 * g.k))
        kept, P_runs, gone = _screen_runs(result, P, in_map, p_alarm, runs, res)
        if gone:
            runs_gone = [(runs[i], p_r, T2_r) for i, (p_r, T2_r) in gone.items()]
            barred_runs.extend(runs[i] for i in gone)
            in_map, P, res, rounds = run_rounds(kept, P_runs, rounds + 1)
    result.map_poses = P
    result.tested_maps.clear()  # their factorisations and draws are not needed past here
    result.draws = None
    if last and not last.get("converged", 1.0):
        result.notes.append(
            f"the last map's solve stopped at its {int(last['iterations'])}-iteration cap before "
            f"converging (cost {last['cost']:.6g}, still falling by "
            f"{last['last_rel_decrease']:.1e} of itself per iteration): the loops were tested "
            "against an unconverged map, so a loop near the test's line may read differently "
            "against the optimum. Very stiff or mutually inconsistent information, or false loops "
            "in the map, slow the optimiser this way")
    t["map_residual_m"] = res["residual_m"]
    t["map_residual_deg"] = res["residual_deg"]
    t["map_chi2"] = res["T2"]
    t["map_p"] = res["p"]
    t["variance_factor"] = res["sigma0_sq"]
    t["map_scale"] = res["map_scale"]
    t["map_sigma_m"] = res["map_sigma_m"]
    t["map_fold_m"] = res["fold_m"]
    t["in_map"] = in_map
    result.timings["map_rounds"] = float(rounds)
    alone = res["p"] < p_alarm
    refuted = alone | (run_out & ~in_map)
    verdict = t["verdict"].to_numpy().astype(object)
    rule = t["rule"].to_numpy().astype(object)
    reason = t["reason"].to_numpy().astype(object)
    s0 = float(res["sigma0_sq"][0]) if res["sigma0_sq"].size else 1.0
    stands = chain_refused & ~_stiffer(res, chain_sigma, overrule)
    raw_sigma = _raw_sigma(res)
    t_i, t_j = t["i"].to_numpy(), t["j"].to_numpy()
    cycle_loops = list(zip(t_i[contested].tolist(), t_j[contested].tolist(), strict=True))
    for i in range(len(t)):
        m = (f"against the map of {int(in_map.sum())} verified loops: residual "
             f"{res['residual_m'][i]:.2f} m / {res['residual_deg'][i]:.1f}°, "
             f"χ²={res['T2'][i]:.3g} (σ0²={s0:.3g}"
             + (f"; the odometry on its chains' scale, {res['map_scale'][i]:.3g}"
                if res["map_scale"][i] > s0 else "") + ")")
        if stands[i] and not in_map[i]:
            reason[i] = (f"{reason[i]}; the map between its poses (σ {raw_sigma[i]:.2f} m) is "
                         f"no stiffer than its chain (σ {chain_sigma[i]:.2f} m), so the chain's "
                         f"refusal stands; {m}")
        elif refuted[i] and verdict[i] != "fail" and res["fold_m"][i] <= fold_m \
                and res["residual_m"][i] <= fold_m:
            # inconsistent with the map, but too small to fold it: kept, and said so. The
            # residual is bounded too: a stiff map yields little to one loop (a small G e),
            # but a group of such loops would move it by up to their residual
            off = "off the map" if alone[i] else "with its run, off the map"
            reason[i] = (f"kept: {off} beyond its stated covariance, but believing it "
                         f"moves the map by {res['fold_m'][i]:.2f} m and it is "
                         f"{res['residual_m'][i]:.2f} m from it (both <= fold_m {fold_m:g} m of "
                         f"{r4.id}), too little to fold it; {m}")
            if verdict[i] != "ok":
                reason[i] = f"was {rule[i]}; {reason[i]}"
            verdict[i], rule[i] = "ok", ""
        elif refuted[i]:
            if verdict[i] != "fail":
                verdict[i], rule[i] = r3.severity, r3.id
                reason[i] = ("contradicts the map: " if alone[i]
                             else "contradicts the map with its run: ") + m
            else:
                reason[i] = f"{reason[i]}; also {m}"
        elif not in_map[i]:
            # passed, but not admitted: never with power, the rounds stopped first, or a cycle
            # of rounds took it out
            was = f"was {rule[i]} ({reason[i]}); " if verdict[i] != "ok" else ""
            sig = res["map_sigma_m"][i]
            others = [f"{a}→{b}" for a, b in cycle_loops if (a, b) != (t_i[i], t_j[i])]
            if leaves[i] >= max_leaves > 0:
                cycle = (f"it passes against the last map (σ {sig:.2f} m), but it left the map "
                         f"{leaves[i]} times in the rounds, its test turning with the loops "
                         "around it, and stays out of it")
            else:
                cycle = (f"it passes against the last map (σ {sig:.2f} m), but it entered and "
                         "left the map with loops it contradicts in a cycle of rounds, and stays "
                         f"out of it (the cycle's other loops: {', '.join(others[:5]) or 'none'}"
                         f"{', …' if len(others) > 5 else ''})")
            if contested[i] and sig <= power_m and res["fold_m"][i] <= fold_m \
                    and res["residual_m"][i] <= fold_m:
                # as a loop refuted by the map but too small to fold it is kept (above)
                verdict[i], rule[i] = "ok", ""
                reason[i] = (f"{was}kept: {cycle}; believing it moves the map by "
                             f"{res['fold_m'][i]:.2f} m and it is {res['residual_m'][i]:.2f} m "
                             f"from it (both <= fold_m {fold_m:g} m of {r4.id}), too little to "
                             f"fold it; {m}")
                continue
            reason[i] = was
            verdict[i], rule[i] = r4.severity, r4.id
            if contested[i] and sig <= power_m:
                reason[i] += (f"not verified: {cycle}; believing it would move the map by "
                              f"{res['fold_m'][i]:.2f} m and it is {res['residual_m'][i]:.2f} m "
                              f"from it (not both <= fold_m {fold_m:g} m); {m}")
            elif not sig <= power_m:
                reason[i] += (f"not verified: the map between its poses is uncertain to "
                              f"{sig:.2f} m (> {power_m:g} m), too loose to refute a lie; {m}")
            elif was_in[i]:
                reason[i] += (f"not verified: borderline, it was in the map of an earlier "
                              f"round and left it, and passes against the last map (σ "
                              f"{sig:.2f} m); the rounds stopped after {rounds} with it "
                              f"outside; {m}")
            else:
                reason[i] += (f"not verified: it passes against the last map with power "
                              f"(σ {sig:.2f} m <= {power_m:g} m), but the rounds stopped after "
                              f"{rounds} (max_rounds {max_rounds}) before it joined the map; {m}")
        elif verdict[i] != "ok":
            reason[i] = f"was {rule[i]} ({reason[i]}); agrees with the map: {m}"
            verdict[i], rule[i] = "ok", ""
        elif corroborated[i]:
            reason[i] = ("verified by other loops: the map was too loose between its poses "
                         "until it held other clusters of loops, against which it passed with "
                         f"power; {m}")
    group = t["group"].to_numpy()
    for gid, (p_g, T2_g) in screened.items():
        mine = np.flatnonzero(taken & (group == gid))
        took = (f"its pair-test group ({mine.size} loops) was taken out of the first map: "
                f"against the map without it, median χ²={T2_g:.3g}, p={p_g:.2g}")
        for i in mine.tolist():
            reason[i] = f"{reason[i]}; {took}" if reason[i] else took
    for rows, p_r, T2_r in runs_gone:
        e_ = t["edge"].to_numpy()[rows]
        a_, b_ = np.minimum(g.src[e_], g.dst[e_]), np.maximum(g.src[e_], g.dst[e_])
        took = (f"its run of {rows.size} loops ({a_.min()}-{a_.max()} → {b_.min()}-{b_.max()}) "
                f"was taken out of the map: against the map without it, median "
                f"χ²={T2_r:.3g}, p={p_r:.2g}")
        if not run_out[rows].any():
            took += "; it came back once the map had changed"
        for i in rows.tolist():
            if "its run of" in reason[i]:  # windows of one long run overlap: the first says it
                continue
            reason[i] = f"{reason[i]}; {took}" if reason[i] else took
    t["verdict"] = verdict.astype(str)
    t["rule"] = rule.astype(str)
    t["reason"] = reason.astype(str)
