"""The warehouse run as a pose graph (.g2o) with true and perceptual-aliasing false loops.

Keyframes every ``step_m`` along laps of the hall (the ``healthy_loop`` path at its 1.2 m/s). Odometry
links carry noise drawn from their stated information. True loops join keyframes of different
laps within ``revisit_m`` of each other and facing the same way. False loops come from the two
ways the hall fools place recognition: the hall is symmetric under a half turn about its centre
(the rack island and the wall racks look the same from both long sides: ``mirror``), and the
racking repeats every bay (``bay``: the same side, one bay further on). Each alias event is a
group of ``group`` consecutive keyframe pairs claiming the same place, mutually consistent
through the odometry, as a place recogniser that keeps matching the wrong aisle produces.

Labels: ``<graph>.labels.csv`` with ``i,j,label,kind`` (label: true_loop / false_loop).
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from frontdiag.loops import lie

BAY_M = 2.4


def _rel(X: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    return lie.inv(X[i]) @ X[j]


def warehouse_pose_graph(out: Path | str, seconds: float = 150.0, seed: int = 0, step_m: float = 0.5,
                         false_share: float = 0.3, group: int = 4,
                         revisit_m: float = 0.4) -> tuple[Path, Path, dict[str, int]]:
    """Write the graph and its labels; returns both paths and counts."""
    from frontdiag.sim.scenarios import _LOOP

    rng = np.random.default_rng(seed)
    v = 1.2  # the healthy_loop scenario's speed round the hall
    drive = _LOOP.motion(0.0, v)
    ts = np.arange(0.0, seconds, step_m / v)
    poses = np.array([drive(float(t))[:3] for t in ts])
    X = lie.se2(poses[:, 0], poses[:, 1], poses[:, 2])
    n = X.shape[0]
    sig_odo = np.array([0.01, 0.01, np.radians(0.2)])
    sig_loop = np.array([0.02, 0.02, np.radians(0.5)])
    info_odo = np.diag(1 / sig_odo**2)
    info_loop = np.diag(1 / sig_loop**2)

    def noisy(Z: np.ndarray, sig: np.ndarray) -> np.ndarray:
        return Z @ lie.exp(rng.standard_normal((Z.shape[0], 3)) * sig, 2)

    k = np.arange(n - 1)
    Z_odo = noisy(_rel(X, k, k + 1), sig_odo)
    # true loops: other laps, within revisit_m, same heading; one per 3 keyframes
    xy = poses[:, :2]
    true_pairs = []
    min_gap = int(0.5 * _LOOP.length / step_m)
    for j in range(0, n, 3):
        d = np.hypot(*(xy[: max(j - min_gap, 0)] - xy[j]).T)
        if d.size == 0:
            continue
        dyaw = np.abs(np.angle(np.exp(1j * (poses[: d.size, 2] - poses[j, 2]))))
        ok = np.flatnonzero((d < revisit_m) & (dyaw < np.radians(20)))
        if ok.size:
            true_pairs.append((int(ok[np.argmin(d[ok])]), j))
    ti = np.array([p[0] for p in true_pairs], dtype=np.int64)
    tj = np.array([p[1] for p in true_pairs], dtype=np.int64)
    Z_true = noisy(_rel(X, ti, tj), sig_loop)
    # false loops: alias events on the long sides
    cx = 0.5 * (_LOOP.p[:, 0].min() + _LOOP.p[:, 0].max())
    cy = 0.5 * (_LOOP.p[:, 1].min() + _LOOP.p[:, 1].max())
    on_long = np.abs(np.abs(poses[:, 1] - cy) - 3.0) < 0.05
    n_events = max(1, round(false_share * len(true_pairs) / group))
    fi: list[int] = []
    fj: list[int] = []
    kinds: list[str] = []
    cand = np.flatnonzero(on_long[: n - group])
    tries = 0
    while len(kinds) < n_events * group and tries < 10000:
        tries += 1
        a = int(rng.choice(cand))
        kind = "mirror" if rng.uniform() < 0.5 else "bay"
        if kind == "mirror":  # half turn about the hall centre
            tx, ty = 2 * cx - poses[a, 0], 2 * cy - poses[a, 1]
            tyaw = poses[a, 2] + np.pi
        else:  # one bay further along the same side
            h = poses[a, 2]
            tx, ty, tyaw = poses[a, 0] + BAY_M * np.cos(h), poses[a, 1] + BAY_M * np.sin(h), h
        d = np.hypot(xy[:, 0] - tx, xy[:, 1] - ty)
        dyaw = np.abs(np.angle(np.exp(1j * (poses[:, 2] - tyaw))))
        ok = np.flatnonzero((d < revisit_m) & (dyaw < np.radians(20)) & on_long
                            & (np.abs(np.arange(n) - a) > group + 2))
        ok = ok[ok < n - group]
        if ok.size == 0:
            continue
        b = int(rng.choice(ok))
        for t in range(group):
            fi.append(a + t)
            fj.append(b + t)
            kinds.append(kind)
    fa, fb = np.array(fi, dtype=np.int64), np.array(fj, dtype=np.int64)
    # the recogniser claims b is where a is: Z0 ≈ identity, then consistent along both sides
    first = np.arange(fa.size) - np.arange(fa.size) % group
    Z0 = lie.exp(rng.standard_normal((fa.size, 3)) * sig_loop, 2)[first]
    Z_false = noisy(lie.inv(_rel(X, fa[first], fa)) @ Z0 @ _rel(X, fb[first], fb), sig_loop)
    out = Path(out)
    P0 = lie.prefix_products(Z_odo)
    lines = []
    th0 = np.arctan2(P0[:, 1, 0], P0[:, 0, 0])
    for v in range(n):
        lines.append(f"VERTEX_SE2 {v} {P0[v, 0, 2]:.6f} {P0[v, 1, 2]:.6f} {th0[v]:.6f}")

    def edge(i: int, j: int, Z: np.ndarray, info: np.ndarray) -> str:
        th = np.arctan2(Z[1, 0], Z[0, 0])
        vals = " ".join(f"{info[r, c]:.6g}" for r, c in ((0, 0), (0, 1), (0, 2), (1, 1),
                                                          (1, 2), (2, 2)))
        return f"EDGE_SE2 {i} {j} {Z[0, 2]:.6f} {Z[1, 2]:.6f} {th:.6f} {vals}"

    lines += [edge(int(a), int(a) + 1, Z_odo[a], info_odo) for a in k]
    rows = []
    order = rng.permutation(ti.size + fa.size)  # interleave true and false in the file
    allI = np.concatenate([ti, fa])
    allJ = np.concatenate([tj, fb])
    allZ = np.concatenate([Z_true, Z_false])
    labels = ["true_loop"] * ti.size + ["false_loop"] * fa.size
    kind_all = ["revisit"] * ti.size + kinds
    for o in order:
        lines.append(edge(int(allI[o]), int(allJ[o]), allZ[o], info_loop))
        rows.append((int(allI[o]), int(allJ[o]), labels[o], kind_all[o]))
    out.write_text("\n".join(lines) + "\n")
    lab = out.with_name(out.name + ".labels.csv")
    with lab.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["i", "j", "label", "kind"])
        w.writerows(rows)
    return out, lab, {"poses": n, "true_loops": int(ti.size), "false_loops": int(fa.size)}
