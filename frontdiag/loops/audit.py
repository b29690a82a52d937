"""The loop-closure audit: every loop tested before optimisation, one verdict each.

    graph = read_graph("run.g2o")
    result = audit(graph)                 # per-loop table, verdicts, summary
    result.table                          # what loops.parquet holds

Order of the tests (each rule in rules/loops/loops.toml):

1. FD-LOP-001, chain: the loop against the odometry chain between its poses (χ²).
2. FD-LOP-002, pairs: loops that survive 1 are tested in pairs (PCM); the largest consistent
   set is kept.
3. FD-LOP-003, map: the odometry plus the surviving loops are optimised and every loop is
   re-tested against that map with the map's relative covariance (``verify=True``).
4. FD-LOP-004, untestable: a loop that nothing confirms and that would move the map.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from frontdiag.loops import pcm
from frontdiag.loops.chain import Chain, build_chain
from frontdiag.loops.graph import GraphError, PoseGraph
from frontdiag.loops.rules import LoopRules, load_loop_rules
from frontdiag.loops.solve import forget_fill, ldlt_fallbacks, solver_label
from frontdiag.loops.stats import LoopStats, loop_stats
from frontdiag.loops.stiffness import (
    AXES,
    Overconfident,
    cap_information,
    describe,
    find_overconfident,
)

log = logging.getLogger(__name__)

TABLE_COLUMNS = ["loop", "i", "j", "residual_m", "residual_deg", "chi2", "p_value", "f",
                 "displacement_m", "group", "verdict", "rule", "reason"]


@dataclass
class LoopAudit:
    graph: PoseGraph
    rules: LoopRules
    chain: Chain
    stats: LoopStats
    table: pd.DataFrame
    """One row per loop: the columns of loops.parquet."""
    odometry: np.ndarray
    n_pairs: int = 0
    n_conflicts: int = 0
    timings: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    map_poses: np.ndarray | None = None
    calibration: float = 1.0
    """Factor applied to every covariance of the file (1: as read)."""
    overconfident: Overconfident | None = None
    """FD-LOP-005's edges (odometry and loops), None without that rule."""
    capped: bool = False
    """Whether ``graph`` holds their information capped (the file's otherwise)."""
    tested_maps: list[tuple[Any, Any, Any]] = field(default_factory=list, repr=False,
                                                     compare=False)
    """The map test's last maps (``verify.tested_map``), reused within this audit only."""
    draws: Any = field(default=None, repr=False, compare=False)
    """The map test's noise draws (``verify.edge_draws``), shared by this audit's tests only."""
    sparse_solver: str = ""
    """The factorisation the audit used (``solve.solver_label``), with the matrices CHOLMOD
    refused and QDLDL factorised, if any."""

    def kept_edges(self) -> np.ndarray:
        """Edges (odometry and loops) of the graph without the refuted loops."""
        keep = self.odometry.copy()
        keep[self.table["edge"].to_numpy()[self.table["verdict"].to_numpy() == "ok"]] = True
        return keep


def _overconfident_rows(result: LoopAudit, top: int) -> dict[str, Any]:
    """FD-LOP-005's edges for the summary: counts, the line, and the stiffest ``top``."""
    over = result.overconfident
    if over is None:
        return {"checked": False}
    g = result.graph
    names = AXES[g.dim]
    rows = []
    for e, a, s, r in zip(over.edges[:top].tolist(), over.axis[:top].tolist(),
                          over.sigma[:top].tolist(), over.ratio[:top].tolist(), strict=True):
        i, j = g.file_ends(e)
        rows.append({"edge_line": int(g.line[e]), "i": i, "j": j,
                     "odometry": bool(result.odometry[e]), "axis": names[int(a)],
                     "sigma": float(s), "over_median": float(r)})
    return {"checked": True, "max_over_median": over.max_over_median,
            "odometry": int(result.odometry[over.edges].sum()),
            "loops": int((~result.odometry[over.edges]).sum()), "capped": result.capped,
            "stiffest": rows}


def _calibration_note(t: pd.DataFrame, k: int, cycles: Callable[[], float]) -> str | None:
    """What the loops' χ² against their chains say of the file's covariances, where they are
    off by more than 10x; ``cycles()`` gives the factor ``--calibrate`` would apply (the
    pairwise cycles' own reading, NaN when too few can be tested), read only then."""
    chi = t["chi2"].to_numpy(dtype=float)
    chi = chi[np.isfinite(chi)]
    if chi.size < 20:
        return None
    ratio = float(np.median(chi)) / pcm.threshold(k, 0.5)
    if 0.1 <= ratio <= 10:
        return None
    scale = cycles()
    both = (f"the median loop χ² is {ratio:.2g}× what correct covariances give"
            + (f", the pairwise cycles' lower quartile {scale:.2g}×" if np.isfinite(scale) else ""))
    if ratio < 0.1:
        return (f"{both}: the "
                "file's information looks too small, so the chain test is weak. If the file "
                "stores square-root information, read it with --sqrt-info; if every covariance "
                "is off by one factor, --calibrate scales them by the pairwise cycles; but where "
                "the loops are far more precise than the odometry, one factor makes the chains "
                "too stiff and true loops are refused: compare the kept loops with and without "
                "it (docs/loops.md, --calibrate)")
    return (f"{both}: the file's information looks too large (or squared), so true loops may "
            "be refused. If every covariance is off by one factor, --calibrate scales them by the "
            "pairwise cycles; it also takes the tests' power over false loops down with them, so "
            "compare the kept loops with and without it (docs/loops.md, --calibrate)")


def audit(graph: PoseGraph, rules: LoopRules | None = None, *, odom_max_gap: int = 1,
          verify: bool = True, calibrate: bool = False,
          progress: Callable[[str], None] | None = None) -> LoopAudit:
    """Test every loop of ``graph`` (see the module doc) and return the per-loop table.

    Runs with one BLAS thread: the audit's dense algebra is batches of 3x3 or 6x6 blocks and
    vector products (the sparse factorisation is single-threaded anyway), too small for BLAS
    threads to help, and where another process holds a core their synchronisation stalls
    every product: M3500 with 30 % random false loops took 4.7-5.0 s with two BLAS threads
    beside one busy process and 3.2-3.3 s with one (on a quiet machine 7-10 % apart).
    """
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        return _audit(graph, rules, odom_max_gap=odom_max_gap, verify=verify,
                      calibrate=calibrate, progress=progress)


def _audit(graph: PoseGraph, rules: LoopRules | None, *, odom_max_gap: int, verify: bool,
           calibrate: bool, progress: Callable[[str], None] | None) -> LoopAudit:
    rules = rules or load_loop_rules()
    say = progress or (lambda _s: None)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    fallbacks0 = ldlt_fallbacks()
    forget_fill()
    odo = graph.odometry_mask(odom_max_gap)
    if graph.n_edges and not odo.any():
        raise GraphError(graph.path, f"no odometry: none of its {graph.n_edges} edges joins two "
                                     "vertices adjacent in id order, so no chain joins the poses "
                                     "a loop closes",
                         hint="the audit needs the odometry edges: a graph of loops alone "
                              "cannot be tested")
    loops = np.flatnonzero(~odo)
    no_loops = (f"no loop closures: all {graph.n_edges} edges join vertices at most "
                f"{odom_max_gap} apart in id order, so they are odometry and nothing was audited "
                "(--odom-max-gap sets that span)") if graph.n_edges and not loops.size else None
    r2 = rules.by_statistic("pcm")
    r5 = rules.optional("stiffness")
    over = find_overconfident(graph, float(r5.param("max_over_median"))) if r5 else None
    capped = bool(over is not None and len(over) and r5 is not None
                  and (r5.param("cap") if "cap" in r5.params else True))
    file_graph = graph
    if capped and over is not None:
        graph = cap_information(graph, over)
    calibration = 1.0
    if calibrate:
        graph, calibration = calibrate_information(graph, odo, loops, int(r2.param("window")))
    chain = build_chain(graph, odo)
    st = loop_stats(graph, chain, loops)
    timings["chain_s"] = time.perf_counter() - t0
    say(f"chain test of {loops.size} loops")
    k = graph.k
    t = st.table.copy()
    t.insert(0, "loop", np.arange(len(t), dtype=np.int64))
    n = len(t)
    verdict = np.full(n, "ok", dtype=object)
    rule = np.full(n, "", dtype=object)
    reason = np.full(n, "", dtype=object)

    r1 = rules.by_statistic("chi2")
    thr1 = pcm.threshold(k, float(r1.param("p_alarm")))
    chi = t["chi2"].to_numpy(dtype=float)
    bad1 = np.isfinite(chi) & (chi > thr1)
    verdict[bad1], rule[bad1] = r1.severity, r1.id
    for i in (int(x) for x in np.flatnonzero(bad1)):
        reason[i] = (f"contradicts the odometry chain: residual {t.residual_m.iat[i]:.2f} m / "
                     f"{t.residual_deg.iat[i]:.1f}° against chain σ {t.chain_sigma_m.iat[i]:.2f} m"
                     f", χ²={chi[i]:.3g} > {thr1:.3g}")

    # --- pairs (PCM) ------------------------------------------------------------------------
    t1 = time.perf_counter()
    a, b = graph.src[loops], graph.dst[loops]
    pairs = pcm.candidate_pairs(a, b, int(r2.param("window")))
    alive = ~bad1
    pairs = pairs[alive[pairs[:, 0]] & alive[pairs[:, 1]]]
    say(f"pairwise consistency of {pairs.shape[0]} candidate pairs")
    pchi = pcm.pair_chi2(graph, chain, loops, pairs)
    thr2 = pcm.threshold(k, float(r2.param("p_pair")))
    tested = np.isfinite(pchi)
    conflict = pairs[tested & (pchi > thr2)]
    consistent = pairs[tested & (pchi <= thr2)]
    group = pcm.consistency_groups(n, consistent)
    keep = pcm.max_consistent_set(n, conflict)
    timings["pcm_s"] = time.perf_counter() - t1
    size = np.bincount(group[group >= 0], minlength=1) if (group >= 0).any() else np.zeros(1)
    gsize = np.where(group >= 0, size[np.maximum(group, 0)], 1)
    min_group = int(r2.param("min_group"))
    lost = ~keep & alive
    nbr: dict[int, list[int]] = {}
    for p, q in conflict:
        nbr.setdefault(int(p), []).append(int(q))
        nbr.setdefault(int(q), []).append(int(p))
    for i in (int(x) for x in np.flatnonzero(lost)):
        winners = [w for w in nbr.get(int(i), []) if keep[w]]
        wsize = max((int(gsize[w]) for w in winners), default=0)
        if wsize >= min_group:
            verdict[i], rule[i] = r2.severity, r2.id
            reason[i] = (f"inconsistent with {len(winners)} loop(s) of consistent group "
                         f"{int(group[winners[0]])} ({wsize} loops), e.g. loop {winners[0]}")
        else:
            verdict[i], rule[i] = "warn", r2.id
            reason[i] = (f"conflicts with loop {winners[0] if winners else '?'}; neither has "
                         "support from other loops")
    t["group"] = group
    t["group_size"] = gsize.astype(np.int64)
    t["n_conflicts"] = np.bincount(conflict.ravel(), minlength=n) if conflict.size else 0
    t["n_consistent"] = (np.bincount(consistent.ravel(), minlength=n)
                         if consistent.size else 0)

    result = LoopAudit(graph=graph, rules=rules, chain=chain, stats=st, table=t, odometry=odo,
                       n_pairs=int(pairs.shape[0]), n_conflicts=int(conflict.shape[0]),
                       timings=timings)
    result.calibration = calibration
    result.overconfident = over
    result.capped = capped
    if over is not None and len(over):
        result.notes.append(_overconfident_note(file_graph, over, odo, capped))
    if calibration != 1.0:
        result.notes.append(f"covariances scaled by {calibration:.3g} (the median χ² of the "
                            "pairwise cycles over its expected value; without --calibrate the "
                            "file's stand)")
    _finish(result, verdict, rule, reason)
    if verify and n:
        from frontdiag.loops.verify import verify_against_map

        t2 = time.perf_counter()
        say("re-testing the loops against the map of the verified loops")
        verify_against_map(result)
        timings["map_s"] = time.perf_counter() - t2
    _untestable(result)
    _overconfident_loops(result, file_graph)
    # the pair test's cycles are every candidate pair's where the chain test refused no loop
    note = _calibration_note(result.table, k, (lambda: cycle_scale(pchi, k)) if not bad1.any()
                             else lambda: cycle_reading(graph, odo, loops, int(r2.param("window")),
                                                        chain))
    if note:
        result.notes.append(note)
    if no_loops:
        result.notes.append(no_loops)
    timings["total_s"] = time.perf_counter() - t0
    result.sparse_solver = solver_label(graph.k, ldlt_fallbacks() - fallbacks0)
    return result


def calibrate_information(graph: PoseGraph, odo: np.ndarray, loops: np.ndarray,
                          window: int) -> tuple[PoseGraph, float]:
    """Scale every covariance by s = lower-quartile pairwise-cycle χ² / lower quartile of χ²_k.

    Short cycles of two neighbouring loops and two short chains are the graph's own evidence of
    its noise. A cycle through a false loop can only raise its χ², so the lower quartile stays
    right while up to three quarters of the cycles touch false loops. Returns the
    graph (a copy with information / s) and s; s = 1 with fewer than 20 testable pairs.
    """
    from dataclasses import replace

    s = cycle_reading(graph, odo, loops, window)
    if not np.isfinite(s):
        return graph, 1.0
    return replace(graph, info=graph.info / s), s


def cycle_reading(graph: PoseGraph, odo: np.ndarray, loops: np.ndarray, window: int,
                  chain: Chain | None = None) -> float:
    """The covariance scale the pairwise cycles of every candidate pair read: their
    lower-quartile χ² over χ²_k's (see :func:`calibrate_information`); NaN under 20 finite
    cycles or where it is not positive. ``chain``: the odometry chain of ``graph`` where the
    caller holds it already."""
    if chain is None:
        chain = build_chain(graph, odo)
    pairs = pcm.candidate_pairs(graph.src[loops], graph.dst[loops], window)
    return cycle_scale(pcm.pair_chi2(graph, chain, loops, pairs), graph.k)


def cycle_scale(pair_chi2: np.ndarray, k: int) -> float:
    """Lower-quartile χ² of the finite ``pair_chi2`` over χ²_k's; NaN under 20 of them or where
    it is not positive."""
    chi = pair_chi2[np.isfinite(pair_chi2)]
    if chi.size < 20:
        return float("nan")
    s = float(np.quantile(chi, 0.25)) / pcm.threshold(k, 0.75)
    return s if np.isfinite(s) and s > 0 else float("nan")


def _finish(result: LoopAudit, verdict: np.ndarray, rule: np.ndarray,
            reason: np.ndarray) -> None:
    t = result.table
    t["verdict"] = verdict.astype(str)
    t["rule"] = rule.astype(str)
    t["reason"] = reason.astype(str)


def _untestable(result: LoopAudit) -> None:
    """FD-LOP-004: loops still 'ok' that no test could confirm and that would move the map."""
    r4 = result.rules.by_statistic("untestable")
    t = result.table
    fold_m = float(r4.param("fold_m"))
    confirmed = t["chain_confirms"] if "chain_confirms" in t else pd.Series(False, index=t.index)
    lone = ((t["verdict"] == "ok") & ~t["chain_ok"] & (t["group_size"] < 2)
            & ~confirmed.astype(bool))
    disp = t["displacement_m"].fillna(np.inf)
    hit = lone & (disp > fold_m)
    t.loc[hit, "verdict"] = r4.severity
    t.loc[hit, "rule"] = r4.id
    t.loc[hit, "reason"] = "no odometry chain joins its poses and no other loop confirms it"


def _overconfident_note(graph: PoseGraph, over: Overconfident, odo: np.ndarray,
                        capped: bool) -> str:
    n_odo = int(odo[over.edges].sum())
    n_loop = len(over) - n_odo
    head = (f"FD-LOP-005: {n_odo} odometry edge(s) and {n_loop} loop(s) claim information above "
            f"{over.max_over_median:g}x the graph's median on an axis; the stiffest, "
            f"{describe(graph, over, 0)}. No sensor measures that well, and Levenberg–Marquardt "
            "stalls on such an edge (it may not take a single step)")
    if capped:
        return (f"{head}. The audit tested the loops with these entries lowered to that line "
                "(still far stiffer than the graph's typical edge); floor the variances where "
                "the graph is written")
    return f"{head}. They were not capped (FD-LOP-005 cap = false)"


def _overconfident_loops(result: LoopAudit, graph: PoseGraph) -> None:
    """FD-LOP-005 on the loop table: a loop that claims an impossible certainty is said to, and
    one that passed every test becomes a warning (its information would dominate the map)."""
    over = result.overconfident
    if over is None or not len(over):
        return
    r5 = result.rules.by_statistic("stiffness")
    t = result.table
    row_of = {int(e): i for i, e in enumerate(t["edge"].to_numpy())}
    verdict = t["verdict"].to_numpy().astype(object)
    rule = t["rule"].to_numpy().astype(object)
    reason = t["reason"].to_numpy().astype(object)
    for pos, e in enumerate(over.edges.tolist()):
        i = row_of.get(int(e))
        if i is None:  # an odometry edge: in the note only
            continue
        said = f"overconfident information ({describe(graph, over, pos)})"
        if verdict[i] == "ok":
            verdict[i], rule[i], reason[i] = r5.severity, r5.id, said
        else:
            reason[i] = f"{reason[i]}; also {said}" if reason[i] else said
    _finish(result, verdict, rule, reason)


def summary(result: LoopAudit, top: int = 10) -> dict[str, Any]:
    """Counts, the rules that fired, and the refuted loops ranked by the displacement they cause."""
    t = result.table
    counts = t["verdict"].value_counts()
    flagged = t[t["verdict"] != "ok"].sort_values(["displacement_m", "chi2"],
                                                  ascending=False, na_position="last")
    cols = ["loop", "i", "j", "residual_m", "residual_deg", "chi2", "f", "displacement_m",
            "verdict", "rule", "reason"]
    return {
        "graph": result.graph.path,
        "dim": result.graph.dim,
        "vertices": result.graph.n_vertices,
        "edges": result.graph.n_edges,
        "odometry": int(result.odometry.sum()),
        "loops": len(t),
        "verdicts": {k: int(counts.get(k, 0)) for k in ("ok", "warn", "fail")},
        "rules": {r.id: int((t["rule"] == r.id).sum()) for r in result.rules.rule},
        "pairs_tested": result.n_pairs,
        "pair_conflicts": result.n_conflicts,
        "link_stiffness_m2": result.stats.link_stiffness,
        "overconfident_edges": _overconfident_rows(result, top),
        "timings_s": result.timings,
        "sparse_solver": result.sparse_solver or solver_label(result.graph.k),
        "notes": result.graph.notes + result.notes,
        "worst": flagged.head(top)[cols].to_dict(orient="records"),
    }
