"""Per-loop statistics before optimisation: residual against the odometry chain, χ², stiffness.

For a loop a→b with measurement Z and information Ω_L, the chain gives T_ab with covariance
Σ_c. The residual ``e = Log(T_ab⁻¹ Z)`` has covariance ``S = Σ_c + Σ_L`` if both are right, so
``χ² = eᵀ S⁻¹ e`` with k = 3 (2D) or 6 (3D) degrees of freedom.

Stiffness (springs in series add compliance): along the residual's direction u the chain has
compliance ``u ᵀ Σ_c u`` and stiffness ``k_chain = 1 / (uᵀ Σ_c u)``; the loop has stiffness
``k_loop = uᵀ Ω_L u``. Linearised, an optimiser closes the loop by moving the map by
``G e`` with ``G = Σ_c S⁻¹`` and leaves ``(I − G) e`` on the loop; along u that is the fold
fraction ``f = k_loop / (k_loop + k_chain)``. ``displacement_m`` is the translation of ``G e``:
how far the map would move if the loop were believed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import NDArray
from scipy.stats import chi2 as chi2_dist

from frontdiag.loops import lie
from frontdiag.loops.chain import Chain
from frontdiag.loops.graph import PoseGraph

F = NDArray[np.float64]


@dataclass(frozen=True)
class LoopStats:
    """Arrays over the loops (edges that are not odometry), in edge order."""

    edge: NDArray[np.int64]
    table: pd.DataFrame
    e: F
    """(m, k) residual tangent vectors at b."""
    S: F
    """(m, k, k) residual covariance Σ_c + Σ_L."""
    chain_cov: F
    link_stiffness: float
    """Median translational stiffness of one odometry link (m⁻²), the normalising unit."""


def link_stiffness(chain: Chain, dim: int) -> float:
    """Median over links of the translational stiffness of one link, 1 / mean variance."""
    cov = chain.link_cov[chain.has_link]
    if cov.shape[0] == 0:
        return float("nan")
    var = np.trace(cov[:, :dim, :dim], axis1=1, axis2=2) / dim
    return float(np.median(1.0 / var))


def loop_stats(graph: PoseGraph, chain: Chain, loops: NDArray[np.int64]) -> LoopStats:
    """Residual, χ², p-value, compliance, fold fraction and displacement of each loop edge."""
    d, k = graph.dim, graph.k
    a, b = graph.src[loops], graph.dst[loops]
    ok = chain.same_segment(a, b)
    T, Sc = chain.between(a, b)
    Z = graph.Z[loops]
    info = graph.info[loops]
    SL = np.linalg.inv(info)
    R = lie.inv(T) @ Z
    e = lie.log(R)
    S = Sc + SL
    Sinv = np.linalg.inv(S)
    chi2 = np.einsum("mi,mij,mj->m", e, Sinv, e)
    G = Sc @ Sinv
    move = np.einsum("mij,mj->mi", G, e)
    left = e - move
    t = e[:, :d]
    tn = np.linalg.norm(t, axis=1)
    u = np.zeros_like(e)
    u[:, :d] = np.where(tn[:, None] > 0, t / np.where(tn > 0, tn, 1.0)[:, None], 0.0)
    no_t = tn == 0
    u[no_t, d] = 1.0 if d == 2 else 0.0
    if d == 3:
        u[no_t, k - 1] = 1.0
    compliance = np.einsum("mi,mij,mj->m", u, Sc, u)
    k_loop = np.einsum("mi,mij,mj->m", u, info, u)
    k_chain = 1.0 / np.maximum(compliance, 1e-300)
    f = k_loop / (k_loop + k_chain)
    unit = link_stiffness(chain, d)
    p = chi2_dist.sf(chi2, k)
    nan = np.where(ok, 1.0, np.nan)
    table = pd.DataFrame({
        "edge": loops,
        "line": graph.line[loops],
        "i": graph.ids[a],
        "j": graph.ids[b],
        "span": (b - a).astype(np.int64),
        "residual_m": np.linalg.norm(R[:, :d, d], axis=1) * nan,
        "residual_deg": np.degrees(lie.rotation_angle(R)) * nan,
        "chi2": chi2 * nan,
        "dof": k,
        "p_value": p * nan,
        "chain_sigma_m": np.sqrt(np.trace(Sc[:, :d, :d], axis1=1, axis2=2)) * nan,
        "chain_compliance_links": compliance * unit * nan,
        "loop_stiffness_links": k_loop / unit,
        "f": f * nan,
        "displacement_m": np.linalg.norm(move[:, :d], axis=1) * nan,
        "post_residual_m": np.linalg.norm(left[:, :d], axis=1) * nan,
        "chain_ok": ok,
    })
    return LoopStats(edge=loops, table=table, e=e, S=S, chain_cov=Sc, link_stiffness=unit)
