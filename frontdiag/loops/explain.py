"""`frontdiag loops GRAPH --explain ID`: one loop's tests, with the stiffness arithmetic."""

from __future__ import annotations

import numpy as np

from frontdiag.errors import ConfigError
from frontdiag.loops.audit import LoopAudit
from frontdiag.loops.pcm import threshold


def pick_loop(result: LoopAudit, key: str) -> int:
    """Row of the loop named by its number or by ``I-J`` vertex ids (either order)."""
    t = result.table
    key = key.strip()
    if len(t) == 0:
        raise ConfigError(f"--explain {key}: the graph has no loop closures to explain (every "
                          "edge is odometry; see --odom-max-gap)")
    if "-" in key.lstrip("-"):
        left, _, right = key.partition("-")
        try:
            i, j = int(left), int(right)
        except ValueError:
            raise ConfigError(f"--explain {key!r}: give a loop number or I-J vertex ids") from None
        hit = np.flatnonzero(((t["i"] == i) & (t["j"] == j)) | ((t["i"] == j) & (t["j"] == i)))
        if hit.size == 0:
            raise ConfigError(f"--explain {key}: no loop joins vertices {i} and {j}")
        return int(hit[0])
    try:
        n = int(key)
    except ValueError:
        raise ConfigError(f"--explain {key!r}: give a loop number or I-J vertex ids") from None
    if not 0 <= n < len(t):
        raise ConfigError(f"--explain {n}: loops are numbered 0..{len(t) - 1}")
    return n


def _capped(result: LoopAudit, edge: int) -> str:
    """Said after the loop's stiffness when the audit capped its information (FD-LOP-005)."""
    over = result.overconfident
    if not result.capped or over is None or edge not in set(over.edges.tolist()):
        return ""
    return (f" (its information capped at FD-LOP-005's line, {over.max_over_median:g}x the "
            "graph's median on an axis; the file claims more)")


def explain_loop(result: LoopAudit, row: int) -> str:
    """Plain text: the loop, its chain, χ², the series-spring arithmetic and the verdict."""
    t = result.table.iloc[row]
    g = result.graph
    k = g.k
    unit = result.stats.link_stiffness
    lines = [f"loop {int(t['loop'])}: vertices {int(t['i'])} -> {int(t['j'])} "
             f"({g.path} line {int(t['line'])}), span {int(t['span'])} poses"]
    if not bool(t["chain_ok"]):
        lines.append("  no odometry chain joins these poses (a link is missing between them): "
                     "the chain test cannot run")
    else:
        thr = threshold(k, float(result.rules.by_statistic("chi2").param("p_alarm")))
        c_links = float(t["chain_compliance_links"])
        k_chain = 1.0 / c_links if c_links > 0 else float("inf")
        kl = float(t["loop_stiffness_links"])
        f = float(t["f"])
        lines += [
            "before optimisation, against the odometry chain:",
            f"  residual        {t['residual_m']:.3f} m, {t['residual_deg']:.2f}° "
            f"(chain σ {t['chain_sigma_m']:.3f} m)",
            f"  Mahalanobis χ²  {t['chi2']:.4g} with {k} dof, p = {t['p_value']:.3g} "
            f"(alarm above {thr:.4g})",
            "stiffness along the residual (one odometry link = 1, "
            f"{unit:.4g} m⁻²):",
            f"  chain compliance  {c_links:.4g} links in series -> k_chain = 1/{c_links:.4g} "
            f"= {k_chain:.4g}",
            f"  loop stiffness    Ω = {kl:.4g}{_capped(result, int(t['edge']))}",
            f"  fold fraction     f = Ω/(Ω + k_chain) = {kl:.4g}/({kl:.4g} + {k_chain:.4g}) "
            f"= {f:.5f}",
            f"  if wrong, the optimiser moves the map {t['displacement_m']:.3f} m and leaves "
            f"{t['post_residual_m'] * 1000:.2f} mm on the loop",
        ]
    if int(t.get("group", -1)) >= 0:
        lines.append(f"pairs: consistent with {int(t['n_consistent'])} neighbouring loop(s), "
                     f"in conflict with {int(t['n_conflicts'])}; group {int(t['group'])} of "
                     f"{int(t['group_size'])} loops")
    else:
        lines.append(f"pairs: no consistent neighbour; in conflict with {int(t['n_conflicts'])}")
    if "map_chi2" in result.table.columns and np.isfinite(t.get("map_chi2", np.nan)):
        fold = t.get("map_fold_m", np.nan)
        lines.append(f"against the map of the verified loops: residual {t['map_residual_m']:.3f} m, "
                     f"χ² {t['map_chi2']:.4g} (σ0² = {t.get('variance_factor', np.nan):.3g}"
                     + (f"; the odometry on its chains' scale, {t['map_scale']:.3g}"
                        if t.get("map_scale", np.nan) > t.get("variance_factor", np.nan)
                        else "") + ")"
                     + (f"; believing it moves the map by {fold:.3f} m" if np.isfinite(fold)
                        else ""))
    if t["rule"]:
        lines.append(f"verdict: {t['verdict']} {t['rule']}: {t['reason']}")
    else:
        lines.append(f"verdict: {t['verdict']}" + (f" ({t['reason']})" if t["reason"] else ""))
    if t["rule"]:
        r = result.rules.get(str(t["rule"]))
        lines += [f"  fix: {r.text.fix}", f"  wrong fix: {r.text.wrong_fix}"]
    return "\n".join(lines)
