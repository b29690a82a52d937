"""Seeded false loop closures for benchmarks and tests (the generator is part of the result).

Three kinds, after Sünderhauf & Protzel (2012), whose outlier sets became the standard test of
robust pose-graph back-ends:

* ``random``: two vertices drawn uniformly (at least ``min_span`` apart);
* ``local``: the second vertex within ``local_window`` poses of the first;
* ``grouped``: groups of ``group_size`` loops (i+t → j+t), mutually consistent through the
  odometry, as a perceptual alias seen over several consecutive frames produces.

Every false loop claims what place recognition claims on an alias: the two poses are at nearly
the same place, translation uniform in a disc (ball in 3D) of ``claim_radius_m``, heading drawn
uniformly. Its information is the median information of the graph's loops, so it looks exactly
as trustworthy as a true one, and its measurement carries noise drawn from that information.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from frontdiag.loops import lie
from frontdiag.loops.chain import build_chain
from frontdiag.loops.graph import PoseGraph

KINDS = ("random", "local", "grouped")


def _claims(rng: np.random.Generator, n: int, dim: int, radius: float) -> NDArray[np.float64]:
    yaw = rng.uniform(-np.pi, np.pi, n)
    if dim == 2:
        r = radius * np.sqrt(rng.uniform(0, 1, n))
        ang = rng.uniform(-np.pi, np.pi, n)
        return lie.se2(r * np.cos(ang), r * np.sin(ang), yaw)
    v = rng.normal(size=(n, 3))
    v *= (radius * rng.uniform(0, 1, n) ** (1 / 3) / np.linalg.norm(v, axis=1))[:, None]
    rot = Rotation.from_euler("z", yaw[:, None]) * Rotation.from_rotvec(rng.normal(0, 0.05, (n, 3)))
    return lie.se3(v, rot.as_quat())


def inject_false_loops(graph: PoseGraph, fraction: float, kind: str, seed: int, *,
                       min_span: int = 10, local_window: int = 50, group_size: int = 10,
                       claim_radius_m: float = 1.0) -> tuple[PoseGraph, NDArray[np.bool_]]:
    """Return the graph with ``fraction`` × (its loop count) false loops appended, and a mask
    over the new graph's edges marking the false ones."""
    if kind not in KINDS:
        raise ValueError(f"kind {kind!r}: choose one of {KINDS}")
    rng = np.random.default_rng(seed)
    odo = graph.odometry_mask()
    true_loops = np.flatnonzero(~odo)
    n_false = round(fraction * true_loops.size)
    n = graph.n_vertices
    if n_false == 0 or n < 2 * min_span + group_size:
        return graph, np.zeros(graph.n_edges, bool)
    src: list[int] = []
    dst: list[int] = []
    if kind == "grouped":
        n_groups = int(np.ceil(n_false / group_size))
        for _ in range(n_groups):
            while True:
                a = int(rng.integers(0, n - group_size))
                b = int(rng.integers(0, n - group_size))
                if abs(a - b) >= min_span + group_size:
                    break
            a, b = min(a, b), max(a, b)
            for t in range(group_size):
                src.append(a + t)
                dst.append(b + t)
        src, dst = src[:n_false], dst[:n_false]
    else:
        while len(src) < n_false:
            a = int(rng.integers(0, n))
            if kind == "random":
                b = int(rng.integers(0, n))
            else:
                b = a + int(rng.integers(-local_window, local_window + 1))
            if 0 <= b < n and abs(a - b) >= (min_span if kind == "random" else 2):
                src.append(min(a, b))
                dst.append(max(a, b))
    s = np.asarray(src, dtype=np.int64)
    d = np.asarray(dst, dtype=np.int64)
    Z = _claims(rng, s.size, graph.dim, claim_radius_m)
    if kind == "grouped":
        P = build_chain(graph, odo).P
        first = np.arange(s.size) - np.arange(s.size) % group_size
        a0, b0 = s[first], d[first]
        # Z_t = (P_a0⁻¹ P_a)⁻¹ · Z_0 · (P_b0⁻¹ P_b): consistent with the odometry
        Z = lie.inv(lie.inv(P[a0]) @ P[s]) @ Z[first] @ (lie.inv(P[b0]) @ P[d])
    info = np.median(graph.info[true_loops], axis=0) if true_loops.size else np.median(
        graph.info, axis=0)
    info = 0.5 * (info + info.T)
    # every claim carries the noise its information promises
    L = np.linalg.cholesky(np.linalg.inv(info))
    Z = Z @ lie.exp(rng.standard_normal((s.size, info.shape[0])) @ L.T, graph.dim)
    new = replace(
        graph,
        src=np.concatenate([graph.src, s]),
        dst=np.concatenate([graph.dst, d]),
        Z=np.concatenate([graph.Z, Z]),
        info=np.concatenate([graph.info, np.tile(info, (s.size, 1, 1))]),
        line=np.concatenate([graph.line, np.zeros(s.size, np.int64)]),
        flipped=np.concatenate([graph.flipped, np.zeros(s.size, bool)]),
        notes=list(graph.notes),
    )
    mask = np.concatenate([np.zeros(graph.n_edges, bool), np.ones(s.size, bool)])
    return new, mask
