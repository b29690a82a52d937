"""Measure this machine's budget coefficients with small microbenchmarks of the same operations.

Single-threaded (``cv2.setNumThreads(1)``, one worker for SciPy), seeded synthetic inputs so two
runs time the same work, a warm-up call, and the median of ``repeats`` timings per operation. The
result is a :class:`~frontdiag.budget.targets.Target` with ``how = "measured"`` and a source per
coefficient that says exactly what was timed.
"""

from __future__ import annotations

import datetime as _dt
import math
import os
import platform
import socket
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from frontdiag.budget import formulas as f
from frontdiag.budget.targets import Coefficient, Target

W, H, LEVELS, SCALE = 1280, 720, 8, 1.2
N_KP = 1000
M_CORR = 400
PNP_POINTS, PNP_ITERS = 200, 4
LIDAR_RAW, LIDAR_KEPT, LIDAR_MAP = 128 * 1800, 15000, 20000


_SPREADS: list[float] = []
"""p90/p10 of each timing taken since the last coefficient was recorded (see :class:`_Timed`)."""


def _median_s(fn: Callable[[], object], repeats: int) -> float:
    fn()  # warm-up: first-call allocations and lazy initialisation are not the steady state
    samples = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - t0)
    lo, hi = np.percentile(samples, [10, 90])
    _SPREADS.append(float(hi / lo) if lo > 0 else float("inf"))
    return statistics.median(samples)


class _Timed(dict[str, tuple[float, str]]):
    """Coefficient -> (value, source), remembering the widest spread of the timings taken for
    each entry (a coefficient built from two timings is as noisy as the noisier one)."""

    def __init__(self) -> None:
        super().__init__()
        self.spread: dict[str, float] = {}

    def __setitem__(self, key: str, value: tuple[float, str]) -> None:
        super().__setitem__(key, value)
        self.spread[key] = max(_SPREADS) if _SPREADS else 1.0
        _SPREADS.clear()


def _image(rng: np.random.Generator) -> np.ndarray:
    """A textured 1280×720 grey image: blurred noise plus rectangles, so FAST finds corners."""
    import cv2

    small = rng.integers(0, 256, (H // 8, W // 8), dtype=np.uint8)
    img: np.ndarray = cv2.resize(small, (W, H), interpolation=cv2.INTER_CUBIC)
    for _ in range(150):
        x, y = int(rng.integers(0, W - 60)), int(rng.integers(0, H - 60))
        w, h = int(rng.integers(10, 60)), int(rng.integers(10, 60))
        cv2.rectangle(img, (x, y), (x + w, y + h), int(rng.integers(0, 256)), -1)
    return img


def _two_views(rng: np.random.Generator, n: int, inlier_ratio: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """3D points, their pixels in two views (a small motion), with outliers; K."""
    K = np.array([[500.0, 0, W / 2], [0, 500.0, H / 2], [0, 0, 1]])
    X = rng.uniform([-3, -2, 4], [3, 2, 12], (n, 3))
    p1 = X[:, :2] / X[:, 2:] * 500 + K[:2, 2]
    X2 = X + np.array([0.15, 0.01, 0.05])
    p2 = X2[:, :2] / X2[:, 2:] * 500 + K[:2, 2] + rng.normal(0, 0.5, (n, 2))
    bad = rng.random(n) >= inlier_ratio
    p2[bad] = rng.uniform([0, 0], [W, H], (int(bad.sum()), 2))
    return X, p1, p2, K


def _camera(rng: np.random.Generator, repeats: int) -> _Timed:
    import cv2

    out = _Timed()
    img = _image(rng)
    K = np.array([[700.0, 0, W / 2], [0, 700.0, H / 2], [0, 0, 1]])
    D = np.array([-0.25, 0.08, 0.0, 0.0, 0.0])
    map1, map2 = cv2.initUndistortRectifyMap(K, D, None, K, (W, H), cv2.CV_16SC2)
    px = f.pyramid_pixels(W, H, LEVELS, SCALE)

    def pyramid() -> list[np.ndarray]:
        levels = [cv2.remap(img, map1, map2, cv2.INTER_LINEAR)]
        for i in range(1, LEVELS):
            size = (round(W / SCALE**i), round(H / SCALE**i))
            levels.append(cv2.resize(levels[-1], size, interpolation=cv2.INTER_LINEAR))
        return levels

    out["resample_ns_per_px"] = (
        _median_s(pyramid, repeats) * 1e9 / px,
        f"cv2.remap (undistort) + {LEVELS - 1} cv2.resize levels at {SCALE} on a {W}x{H} image, "
        f"median time / {px:,.0f} pyramid px")

    levels = pyramid()
    fast = cv2.FastFeatureDetector_create(  # type: ignore[attr-defined]
        threshold=20, nonmaxSuppression=True)
    out["fast_ns_per_px"] = (
        _median_s(lambda: [fast.detect(lv) for lv in levels], repeats) * 1e9 / px,
        f"cv2.FastFeatureDetector (t=20, NMS) on all {LEVELS} levels, median time / "
        f"{px:,.0f} pyramid px")

    border = 40
    kps = [k for k in fast.detect(levels[0])
           if border <= k.pt[0] < W - border and border <= k.pt[1] < H - border]
    kps = sorted(kps, key=lambda k: -k.response)[:N_KP]
    for k in kps:
        k.size, k.octave = 31.0, 0
    orb = cv2.ORB_create(  # type: ignore[attr-defined]
        nfeatures=N_KP, nlevels=1, edgeThreshold=31, patchSize=31)
    out["describe_us_per_kp"] = (
        _median_s(lambda: orb.compute(levels[0], kps), repeats) * 1e6 / len(kps),
        f"cv2.ORB compute (orientation + rBRIEF, one level) of {len(kps)} FAST keypoints, "
        "median time / keypoints")

    d1 = rng.integers(0, 256, (N_KP, 32), dtype=np.uint8)
    d2 = rng.integers(0, 256, (N_KP, 32), dtype=np.uint8)
    bf = cv2.BFMatcher(cv2.NORM_HAMMING)
    ham_ns = _median_s(lambda: bf.knnMatch(d1, d2, k=2), repeats) * 1e9 / (N_KP * N_KP)
    out["hamming_ns_per_comparison"] = (
        ham_ns, f"cv2.BFMatcher(NORM_HAMMING).knnMatch k=2, {N_KP} x {N_KP} descriptors, "
        "median time / 10^6 comparisons")

    cand = max(2, math.ceil(f.guided_candidates(N_KP, 25.0, W, H)))
    small = d2[:cand]
    t_query = _median_s(lambda: bf.knnMatch(d1, small, k=2), repeats) * 1e6 / N_KP
    out["match_us_per_query"] = (
        max(t_query - cand * ham_ns * 1e-3, 0.01 * t_query),
        f"cv2.BFMatcher knnMatch k=2 of {N_KP} queries against {cand} candidates (a guided "
        "window), median time / queries minus the comparisons; excludes projecting map points")

    _, p1, p2, Kc = _two_views(rng, M_CORR, 0.2)
    F = cv2.findFundamentalMat(p1, p2, cv2.FM_8POINT)[0]
    big = 20_000
    x1, y1 = rng.uniform(0, W, big), rng.uniform(0, H, big)
    x2, y2 = x1 + rng.normal(0, 2, big), y1 + rng.normal(0, 2, big)
    (a, b, c), (d, e, g), (h, i, j) = F

    def sampson() -> np.ndarray:
        # elementwise only: no BLAS call that could start threads of its own
        l2x, l2y, l2z = a * x1 + b * y1 + c, d * x1 + e * y1 + g, h * x1 + i * y1 + j
        l1x, l1y = a * x2 + d * y2 + h, b * x2 + e * y2 + i
        num = (x2 * l2x + y2 * l2y + l2z) ** 2
        return num / (l2x * l2x + l2y * l2y + l1x * l1x + l1y * l1y)

    sampson_ns = _median_s(sampson, repeats) * 1e9 / big
    out["sampson_ns_per_residual"] = (
        sampson_ns, f"NumPy elementwise Sampson distance over {big:,} correspondences, median "
        "time / residuals")

    lo, hi = 10, 50

    def ransac(iters: int) -> Callable[[], object]:
        return lambda: cv2.findEssentialMat(p1, p2, Kc, method=cv2.RANSAC,
                                            prob=1 - 1e-9, threshold=1.0, maxIters=iters)

    per_iter_us = (_median_s(ransac(hi), repeats) - _median_s(ransac(lo), repeats)) * 1e6 / (
        hi - lo)
    out["solve_5pt_us"] = (
        max(per_iter_us - M_CORR * sampson_ns * 1e-3, 0.01 * per_iter_us),
        f"cv2.findEssentialMat RANSAC on {M_CORR} correspondences at w = 0.2: (median time at "
        f"{hi} minus at {lo} iterations) / {hi - lo}, minus {M_CORR} Sampson residuals")
    out["solve_8pt_us"] = (
        _median_s(lambda: cv2.findFundamentalMat(p1[:8], p2[:8], cv2.FM_8POINT), repeats * 4)
        * 1e6, "cv2.findFundamentalMat FM_8POINT on 8 correspondences, median time per call")

    Xp, _, uv, Kp = _two_views(rng, PNP_POINTS, 0.8)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, PNP_ITERS, 0.0)

    def pnp() -> object:
        ok, rvec, tvec, inl = cv2.solvePnPRansac(
            Xp, uv, Kp, None, flags=cv2.SOLVEPNP_AP3P, reprojectionError=2.45,
            confidence=0.99, iterationsCount=100)
        if ok and inl is not None and len(inl) >= 6:
            idx = inl.ravel()
            cv2.solvePnPRefineLM(Xp[idx], uv[idx], Kp, None, rvec, tvec, crit)
        return ok

    out["pnp_ns_per_residual"] = (
        _median_s(pnp, repeats) * 1e9 / (PNP_POINTS * PNP_ITERS),
        f"cv2.solvePnPRansac (AP3P, {PNP_POINTS} points, 80 % inliers) + solvePnPRefineLM "
        f"({PNP_ITERS} iterations), median time / {PNP_POINTS * PNP_ITERS} residuals")
    return out


def _lidar(rng: np.random.Generator, repeats: int) -> _Timed:
    from scipy.spatial import cKDTree

    out = _Timed()
    # a box-shaped room: floor and four walls, 20 m x 10 m x 4 m, with range noise
    n = LIDAR_RAW
    face = rng.integers(0, 5, n)
    u, v = rng.random(n), rng.random(n)
    pts = np.column_stack([u * 20 - 10, v * 10 - 5, v * 4])
    pts[face == 0, 2] = 0.0
    pts[face == 1, 0] = -10.0
    pts[face == 2, 0] = 10.0
    pts[face == 3, 1] = -5.0
    pts[face == 4, 1] = 5.0
    pts += rng.normal(0, 0.02, pts.shape)
    t_rel = np.sort(rng.random(n)) * 0.1

    def deskew() -> np.ndarray:
        yaw = 0.5 * t_rel
        c, s = np.cos(yaw), np.sin(yaw)
        x = c * pts[:, 0] - s * pts[:, 1] + 1.5 * t_rel
        y = s * pts[:, 0] + c * pts[:, 1]
        return np.column_stack([x, y, pts[:, 2]])

    out["deskew_ns_per_point"] = (
        _median_s(deskew, repeats) * 1e9 / n,
        f"NumPy per-point constant-velocity motion compensation of {n:,} points, median time / "
        "points")

    def voxel() -> object:
        import small_gicp

        return small_gicp.voxelgrid_sampling(pts, 0.4, num_threads=1)

    out["voxel_ns_per_point"] = (
        _median_s(voxel, repeats) * 1e9 / n,
        f"small_gicp.voxelgrid_sampling (0.4 m, one thread) of {n:,} points, median time / points")

    map_pts = pts[rng.choice(n, LIDAR_MAP, replace=False)]
    src = pts[rng.choice(n, LIDAR_KEPT, replace=False)] + 0.05
    out["kdtree_ns_per_nlogn"] = (
        _median_s(lambda: cKDTree(map_pts), repeats) * 1e9 / f.nlogn(LIDAR_MAP),
        f"scipy cKDTree build on {LIDAR_MAP:,} points, median time / n log2 n")
    tree = cKDTree(map_pts)
    out["nn_ns_per_query_log"] = (
        _median_s(lambda: tree.query(src, k=1, workers=1), repeats) * 1e9
        / (LIDAR_KEPT * math.log2(LIDAR_MAP)),
        f"scipy cKDTree query k=1, one worker, {LIDAR_KEPT:,} queries on {LIDAR_MAP:,} points, "
        "median time / (queries x log2 n)")
    _, j = tree.query(src, k=1, workers=1)
    dst = map_pts[j]

    def solve() -> np.ndarray:
        # einsum without optimize stays off BLAS, so the solve is single-threaded
        ca, cb = src.mean(0), dst.mean(0)
        h = np.einsum("ni,nj->ij", src - ca, dst - cb)
        u_, _, vt = np.linalg.svd(h)
        d = np.sign(np.linalg.det(vt.T @ u_.T))
        r = vt.T @ np.diag([1.0, 1.0, d]) @ u_.T
        return np.einsum("ij,nj->ni", r, src) + (cb - r @ ca)

    out["icp_solve_ns_per_point"] = (
        _median_s(solve, repeats) * 1e9 / LIDAR_KEPT,
        f"NumPy closed-form rigid solve (centroids, cross-covariance, 3x3 SVD) + apply on "
        f"{LIDAR_KEPT:,} points, median time / points")
    return out


def machine_info() -> dict[str, str]:
    import cv2

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"hostname": socket.gethostname(), "cpu": cpu,
            "logical_cpus": str(os.cpu_count() or 0), "python": platform.python_version(),
            "opencv": cv2.__version__, "numpy": np.__version__}


def _prime_allocator() -> None:
    """Put the C allocator in the state a long analysis runs in before timing anything.

    glibc serves large blocks with mmap until a freed block raises its dynamic threshold, and
    trims the heap above twice that threshold. A fresh process is in the cold state, where every
    multi-megabyte NumPy temporary is a fresh mapping that page-faults on first touch: the
    per-point deskew timing read 2.3x slower in a process's first calibration than in its second
    (benchmarks/bench_calibrate.py). Allocating and releasing one touched 30 MiB block raises the
    threshold as an analysis's own allocations soon do; elsewhere it is a harmless allocation.
    """
    block = np.ones(30 * 2**20 // 8)
    del block


def calibrate(repeats: int = 15, seed: int = 0, name: str | None = None) -> Target:
    """Time every coefficient on this machine; seeded inputs, one thread, median of repeats."""
    import cv2

    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    _prime_allocator()
    try:
        rng = np.random.default_rng(seed)
        _SPREADS.clear()
        cam, lid = _camera(rng, repeats), _lidar(rng, repeats)
        measured = {**cam, **lid}
        spread = {**cam.spread, **lid.spread}
    finally:
        cv2.setNumThreads(threads)
    info = machine_info()
    info["calibrated_utc"] = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    info["repeats"] = str(repeats)
    info["threads"] = "1"
    host = info["hostname"]
    return Target(
        name=name or f"calibrated-{host}",
        description=f"{info['cpu']} on {host}, one thread, measured by frontdiag budget "
                    "--calibrate",
        provenance="calibrated",
        coefficients={k: Coefficient(k, float(v), "measured", src, spread.get(k))
                      for k, (v, src) in measured.items()},
        machine=info,
    )
