"""FD-LOP-005: edges whose stated information no sensor justifies (overconfident constraints).

An edge's information is its claimed certainty. Odometry from a scan matcher standing still,
or a loop whose covariance came out of a degenerate fit, is sometimes written with a variance
near zero: intel's published graph (dpgo's copy) holds an odometry edge with σ 0.6 µm in x,
2.3·10¹¹ times the information of the graph's median edge on that axis. Such an edge is not
merely stiff:

* no sensor measures motion that well (a LiDAR's range noise is centimetres; averaged over a
  scan, a tenth of a millimetre at best), so the claim is a fault of whatever wrote it;
* Levenberg–Marquardt stalls on it: a step that moves the poses it joins breaks its constraint
  at second order, and 10¹¹ times that outweighs what the step gains elsewhere, so steps are
  rejected until the damping freezes the graph. On intel GTSAM's LM stops at its initial
  estimate (0 iterations from the chordal start) and frontdiag's solver stops at cost 215.85,
  above the minimum; with the 26 edges over the line capped, GTSAM reaches 215.71 in 7
  iterations and frontdiag's solver in 32.

The test is per axis of the tangent (x, y, θ in 2D; x, y, z, rx, ry, rz in 3D): an edge is
overconfident when a diagonal entry of its information exceeds ``max_over_median`` times the
median of that entry over every edge of the graph (translation and rotation have their own
medians, so units never mix). Capping scales the edge's information as ``S Ω S`` with ``S`` the
diagonal that brings each offending entry down to the line, which keeps its correlations and
leaves it positive definite; edges under the line are untouched (bit for bit).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from frontdiag.loops.graph import PoseGraph

F = NDArray[np.float64]
AXES = {2: ("x", "y", "θ"), 3: ("x", "y", "z", "rx", "ry", "rz")}


@dataclass(frozen=True)
class Overconfident:
    """The overconfident edges of a graph, stiffest first."""

    edges: NDArray[np.int64]
    """Edge indices."""
    ratio: F
    """Each one's largest diagonal information over that axis's median."""
    axis: NDArray[np.int64]
    """The axis of that largest ratio."""
    sigma: F
    """σ on that axis (1/√Ω_aa: m for translation, rad for rotation)."""
    median: F
    """(k,) median diagonal information per axis over every edge."""
    max_over_median: float

    def __len__(self) -> int:
        return int(self.edges.size)


def find_overconfident(graph: PoseGraph, max_over_median: float) -> Overconfident:
    """Edges with a diagonal information entry above ``max_over_median`` x that axis's median."""
    diag = np.einsum("mii->mi", graph.info)
    median = np.median(diag, axis=0) if graph.n_edges else np.ones(graph.k)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratios = diag / median
    ratios = np.where(np.isfinite(ratios), ratios, 0.0)
    worst = ratios.max(axis=1) if graph.n_edges else np.zeros(0)
    over = np.flatnonzero(worst > max_over_median)
    over = over[np.argsort(-worst[over], kind="stable")]
    axis = ratios[over].argmax(axis=1) if over.size else np.zeros(0, np.int64)
    sigma = 1.0 / np.sqrt(diag[over, axis]) if over.size else np.zeros(0)
    return Overconfident(over.astype(np.int64), worst[over], axis.astype(np.int64), sigma,
                         median, float(max_over_median))


def cap_information(graph: PoseGraph, oc: Overconfident) -> PoseGraph:
    """A copy of ``graph`` whose overconfident edges have every diagonal information entry at
    most ``max_over_median`` x its axis's median (``S Ω S``, see the module doc)."""
    if not len(oc):
        return graph
    info = graph.info.copy()
    sub = info[oc.edges]
    diag = np.einsum("mii->mi", sub)
    line = oc.max_over_median * oc.median
    s = np.sqrt(np.minimum(1.0, line / diag))
    info[oc.edges] = sub * s[:, :, None] * s[:, None, :]
    return replace(graph, info=info)


def describe(graph: PoseGraph, oc: Overconfident, e: int) -> str:
    """One edge of ``oc`` (its position ``e`` in it) as a reader finds it in the file."""
    edge = int(oc.edges[e])
    a = int(oc.axis[e])
    name = AXES[graph.dim][a]
    unit = "m" if a < graph.dim else "rad"
    return (f"{graph.edge_name(edge)}: σ_{name} {oc.sigma[e]:.2g} {unit}, information "
            f"{oc.ratio[e]:.2g}× the graph's median on {name}")
