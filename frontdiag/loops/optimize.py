"""`--optimize`: solve with and without the flagged loops and show what the optimiser hides.

Both solutions start from the odometry chain. For each flagged loop the table reports its
residual before optimisation (against the chain), after optimisation with every loop in (what an
optimiser without the audit reports: small, because the map moved instead) and against the map
without the flagged loops. The map change is the ATE between the two solutions (rigidly aligned,
RMS of position differences).

The solver is GTSAM's Levenberg–Marquardt when the ``loops-opt`` extra is installed, else the
built-in sparse solver (``solve.py``); the result names the one used.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from frontdiag.loops import lie
from frontdiag.loops.graph import PoseGraph
from frontdiag.loops.init import chordal_init
from frontdiag.loops.solve import solve

if TYPE_CHECKING:
    from frontdiag.loops.audit import LoopAudit

log = logging.getLogger(__name__)

F = NDArray[np.float64]


def align_rigid(X: F, Y: F) -> F:
    """Rotate and translate positions X (n, d) onto Y by least squares (Umeyama, no scale)."""
    mx, my = X.mean(axis=0), Y.mean(axis=0)
    C = (Y - my).T @ (X - mx)
    U, _, Vt = np.linalg.svd(C)
    D = np.eye(X.shape[1])
    D[-1, -1] = np.sign(np.linalg.det(U @ Vt))
    R = U @ D @ Vt
    return (X - mx) @ R.T + my


def ate(P: F, Q: F) -> float:
    """RMS position difference after rigid alignment of poses P onto Q (both (n, d+1, d+1))."""
    d = P.shape[-1] - 1
    X, Y = P[:, :d, d], Q[:, :d, d]
    return float(np.sqrt(np.mean(np.sum((align_rigid(X, Y) - Y) ** 2, axis=1))))


def gtsam_problem(graph: PoseGraph, edges: NDArray[np.bool_], init: F) -> tuple[Any, Any]:
    """(NonlinearFactorGraph, Values) for the selected edges: factor 0 is the gauge prior on
    vertex 0, factor 1 + n the n-th selected edge (needs the loops-opt extra)."""
    import gtsam

    g = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    d = graph.dim
    perm = np.array([3, 4, 5, 0, 1, 2])  # GTSAM's Pose3 tangent is (rotation, translation)

    def pose(M: F) -> Any:
        if d == 2:
            return gtsam.Pose2(M[0, 2], M[1, 2], float(np.arctan2(M[1, 0], M[0, 0])))
        return gtsam.Pose3(M)

    for i in range(graph.n_vertices):
        values.insert(i, pose(init[i]))
    prior = gtsam.noiseModel.Isotropic.Sigma(graph.k, 1e-6)
    g.add(gtsam.PriorFactorPose2(0, values.atPose2(0), prior) if d == 2 else
          gtsam.PriorFactorPose3(0, values.atPose3(0), prior))
    between = gtsam.BetweenFactorPose2 if d == 2 else gtsam.BetweenFactorPose3
    for e in np.flatnonzero(edges):
        info = graph.info[e] if d == 2 else graph.info[e][np.ix_(perm, perm)]
        g.add(between(int(graph.src[e]), int(graph.dst[e]), pose(graph.Z[e]),
                      gtsam.noiseModel.Gaussian.Information(info)))
    return g, values


def poses_from_gtsam(values: Any, graph: PoseGraph) -> F:
    out = np.empty((graph.n_vertices, graph.dim + 1, graph.dim + 1))
    for i in range(graph.n_vertices):
        out[i] = (values.atPose2(i) if graph.dim == 2 else values.atPose3(i)).matrix()
    return out


def solve_gtsam(graph: PoseGraph, edges: NDArray[np.bool_], init: F) -> F:
    """Levenberg–Marquardt in GTSAM on the selected edges (needs the loops-opt extra)."""
    import gtsam

    g, values = gtsam_problem(graph, edges, init)
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(100)
    return poses_from_gtsam(gtsam.LevenbergMarquardtOptimizer(g, values, params).optimize(),
                            graph)


def solver_name() -> str:
    try:
        import gtsam  # noqa: F401
    except ImportError:
        return "built-in sparse Levenberg–Marquardt (install frontdiag[loops-opt] for GTSAM)"
    return "GTSAM Levenberg–Marquardt"


def optimise(graph: PoseGraph, edges: NDArray[np.bool_], init: F) -> F:
    try:
        import gtsam  # noqa: F401
    except ImportError:
        return solve(graph, edges, init)[0]
    return solve_gtsam(graph, edges, init)


def compare_solutions(result: LoopAudit, poses: dict[str, F] | None = None) -> dict[str, Any]:
    """Solve with every edge and without the flagged loops; the flagged loops' residuals
    before / after and the ATE between the two maps. ``poses``, if given, receives the two
    solutions (``all``, ``clean``)."""
    g = result.graph
    t = result.table
    every = np.ones(g.n_edges, bool)
    kept = result.kept_edges()
    # each solve from the chordal start of its own edges (frontdiag/loops/init.py): from the
    # odometry chain, LM can stop in a local minimum metres from the optimum
    P_all = optimise(g, every, chordal_init(g, every, result.chain.P))
    P_clean = optimise(g, kept, chordal_init(g, kept, result.chain.P))
    if poses is not None:
        poses.update({"all": P_all, "clean": P_clean})
    flagged = t[t["verdict"] == "fail"].sort_values("displacement_m", ascending=False,
                                                    na_position="last")
    e = flagged["edge"].to_numpy()
    rows = []
    if e.size:
        R_all = lie.inv(g.Z[e]) @ lie.inv(P_all[g.src[e]]) @ P_all[g.dst[e]]
        R_cln = lie.inv(g.Z[e]) @ lie.inv(P_clean[g.src[e]]) @ P_clean[g.dst[e]]
        d = g.dim
        after = np.linalg.norm(R_all[:, :d, d], axis=1)
        clean = np.linalg.norm(R_cln[:, :d, d], axis=1)
        for n, (_, r) in enumerate(flagged.iterrows()):
            rows.append({"loop": int(r["loop"]), "i": int(r["i"]), "j": int(r["j"]),
                         "residual_before_m": float(r["residual_m"]),
                         "residual_after_m": float(after[n]),
                         "residual_clean_m": float(clean[n])})
    d = g.dim
    move = np.linalg.norm(P_all[:, :d, d] - align_rigid(P_clean[:, :d, d], P_all[:, :d, d]),
                          axis=1)
    return {"solver": solver_name(), "ate_m": ate(P_clean, P_all),
            "max_displacement_m": float(move.max()) if move.size else 0.0,
            "flagged": rows}
