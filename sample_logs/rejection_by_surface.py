"""Where a simulated scene's ratio-test rejections come from, by the surface under each keypoint.

    python sample_logs/rejection_by_surface.py repetitive_aisle 1280x720 [--seed 21]
        [--rate 30] [--pan 1.57]

Renders pairs of consecutive frames (15 Hz unless ``--rate``; ``--pan`` turns the camera head
that many radians to the left of the scenario's heading) along the scenario's first part, runs the frontend's
ORB extractor and the ratio test (0.8) of every query against all features of the previous
frame, and prints, per surface kind (crate faces, labels, uprights, blank paint): its share of
the features and its rejection rate. Two columns say why queries were rejected:

- ``ambiguous``: the best candidate is as close as this frame's median accepted match, and a
  second one is as good, the "two equally good candidates" of the matching table;
- ``same corner``: the second candidate is the same corner found at another pyramid level
  (inside the first candidate's patch), not a different object.

Two more come from the scene geometry: each query's surface point, projected into the previous
frame, is where its true correspondence lies. ``re-found`` is the share of queries with a
keypoint of the previous frame within 2.5 px of that spot, and ``d_true`` the median Hamming
distance to the best of those (an accepted match typically reads 25-35 bits; two unrelated ORB
descriptors about 128). Rejections with the true partner missing or far are not ambiguity.
``wrong`` is the share of queries the ratio test accepted whose partner is not that spot: a
copy taken with confidence, the opposite outcome of the same ambiguity.
"""

from __future__ import annotations

import argparse
from collections import defaultdict

import numpy as np

from frontdiag.camera.features import OrbExtractor
from frontdiag.camera.matching import hamming_matrix
from frontdiag.sim.render import Intrinsics, expose, render
from frontdiag.sim.run import Timeline, camera_T
from frontdiag.sim.scenarios import SCENARIOS
from frontdiag.sim.scenes import Builder
from frontdiag.sim.world import World

TRUE_RADIUS_PX = 2.5
PATCH_HALF = 15.5  # ORB's 31 px patch, at level 0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenario", choices=sorted(SCENARIOS))
    ap.add_argument("size", help="WxH, e.g. 1280x720")
    ap.add_argument("--seed", type=int, default=21)
    ap.add_argument("--pairs", type=int, default=10)
    ap.add_argument("--rate", type=float, default=15.0, help="camera rate, Hz")
    ap.add_argument("--pan", type=float, default=0.0, help="camera head pan, rad (left +)")
    a = ap.parse_args()
    w_px, h_px = (int(v) for v in a.size.lower().split("x"))
    parts = SCENARIOS[a.scenario].make(8.0)
    tl = Timeline(parts)
    intr = Intrinsics.from_hfov(w_px, h_px, 70.0)
    world = World()
    parts[0].build(Builder(world, np.random.default_rng([a.seed, 1, 0]), w_px / 640.0))
    ex = OrbExtractor(1000)
    acc: dict[str, np.ndarray] = defaultdict(lambda: np.zeros(5))
    d_true: dict[str, list[int]] = defaultdict(list)
    K_inv = np.linalg.inv(intr.K)
    for k in range(5, 5 + 6 * a.pairs, 6):
        t0, t1 = k / a.rate, (k + 1) / a.rate
        if tl.part_index(t1) != 0:
            break
        T0, T1 = (camera_T(_panned(tl.pose(t, 0), a.pan)) for t in (t0, t1))
        r0, _ = render(world, intr, T0)
        r1, sid = render(world, intr, T1)
        gain = 0.55 / max(float(r0.mean()), 1e-3)
        fa = ex.detect_and_compute(expose(r0, gain, np.random.default_rng([a.seed, 2, k])))
        fb = ex.detect_and_compute(expose(r1, gain, np.random.default_rng([a.seed, 3, k])))
        d = hamming_matrix(fb.des, fa.des)
        rows = np.arange(len(d))
        j = np.argsort(d, axis=1, kind="stable")[:, :2]
        d1, d2 = d[rows, j[:, 0]], d[rows, j[:, 1]]
        rej = ~(d1 < 0.8 * d2)
        m = float(np.median(d1[~rej])) if (~rej).any() else np.nan
        ambiguous = rej & (d1 <= m)
        sep = np.linalg.norm(fa.xy[j[:, 0]] - fa.xy[j[:, 1]], axis=1)
        same = rej & (sep <= PATCH_HALF * 1.2 ** np.maximum(fa.octave[j[:, 0]],
                                                              fa.octave[j[:, 1]]))
        xy = np.clip(fb.xy.astype(int), 0, [w_px - 1, h_px - 1])
        ids = sid[xy[:, 1], xy[:, 0]]
        kinds = np.array([world.surfaces[i].kind if i >= 0 else "background" for i in ids])
        spots = _true_spots(world, intr, K_inv, T0, T1, fb.xy, ids)
        off = np.linalg.norm(fa.xy[j[:, 0]] - spots, axis=1) > TRUE_RADIUS_PX  # NaN: False
        wrong = ~rej & off
        for kind in np.unique(kinds):
            sel = kinds == kind
            acc[kind] += [sel.sum(), rej[sel].sum(), ambiguous[sel].sum(), same[sel].sum(),
                          wrong[sel].sum()]
        for qi, uv in enumerate(spots):
            near = np.linalg.norm(fa.xy - uv, axis=1) <= TRUE_RADIUS_PX
            d_true[kinds[qi]].append(int(d[qi, near].min()) if near.any() else -1)
    total = sum(v[0] for v in acc.values())
    print(f"{a.scenario} {a.size} seed {a.seed}: {int(total)} features over the pairs, "
          f"rejection {sum(v[1] for v in acc.values()) / total:.2f}")
    print(f"  {'surface':12s} {'share':>6s} {'rejected':>9s} {'ambiguous':>10s} "
          f"{'same corner':>12s} {'re-found':>9s} {'d_true':>7s} {'wrong':>6s}")
    for kind, (n, r, amb, same_n, wrong_n) in sorted(acc.items(), key=lambda kv: -kv[1][0]):
        dt = np.array(d_true[kind])
        found = dt[dt >= 0]
        med = f"{np.median(found):7.0f}" if len(found) else f"{'-':>7s}"
        print(f"  {kind:12s} {n / total:6.2f} {r / n:9.2f} {amb / n:10.2f} {same_n / n:12.2f} "
              f"{len(found) / max(len(dt), 1):9.2f} {med} {wrong_n / n:6.2f}")


def _panned(pose: tuple[float, float, float, float], pan: float
            ) -> tuple[float, float, float, float]:
    x, y, yaw, p = pose
    return x, y, yaw, p + pan


def _true_spots(world: World, intr: Intrinsics, K_inv: np.ndarray, T0: np.ndarray,
                T1: np.ndarray, xy: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """Where the surface point under each keypoint of frame 1 projects in frame 0 (NaN where
    no surface, or behind the camera)."""
    out = np.full((len(xy), 2), np.nan)
    for qi, ((u, v), i) in enumerate(zip(xy, ids, strict=True)):
        if i < 0:
            continue
        s = world.surfaces[i]
        n = np.cross(s.eu, s.ev)
        ray = T1[:3, :3] @ (K_inv @ np.array([u, v, 1.0]))
        if abs(n @ ray) < 1e-9:
            continue
        X = T1[:3, 3] + (n @ (s.origin - T1[:3, 3])) / (n @ ray) * ray
        pc = T0[:3, :3].T @ (X - T0[:3, 3])
        if pc[2] > 0.05:
            out[qi] = intr.project(pc[None])[0]
    return out


if __name__ == "__main__":
    main()
