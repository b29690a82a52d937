"""LiDAR frontend throughput against KISS-ICP on the same scans, single-threaded.

Synthesises a drive through a ray-cast warehouse (60 x 40 m, racking, pallets) at 1.5 m/s while
turning at 0.2 rad/s, as a 128 x 1800 sensor (230,400 points per sweep) and a 32 x 1024 one, then
runs each pipeline in its own fresh process on the same scans and prints scans/s per core, the
stage breakdown, the drift against the true trajectory and each process's peak RSS (the pipeline
plus the one scan in hand: workers read the scans from disk one at a time).

    OMP_NUM_THREADS=1 python benchmarks/bench_lidar.py            # both sizes, 20 scans each
    python benchmarks/bench_lidar.py --scans 40 --open3d          # also the Open3D backend

KISS-ICP (``pip install kiss-icp``, extra ``frontdiag[bench]``) runs its own pipeline through its
Python API, ``kiss_icp.kiss_icp.KissICP`` with the default configuration (``load_config(None)``:
max range 100 m, voxel 1 m) and ``max_num_threads = 1``. frontdiag runs with its defaults
(voxel 0.5 m, small_gicp with one thread) and computes the degeneracy spectrum on every scan.
This is a script that prints figures, not a test.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # before numpy / Open3D load their thread pools

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

SIZES = {"128x1800": (128, 1800, (-22.5, 22.5)), "32x1024": (32, 1024, (-22.5, 22.5))}
TWIST = np.array([0.0, 0.0, 0.2, 1.5, 0.0, 0.0])
PERIOD_S = 0.1
START = (-3.0, -10.0, 0.0)


def synthesise(size: str, n: int, out: Path) -> None:
    """Write scan k to ``out/xyz{k}.npy`` and ``out/t{k}.npy``; workers read one at a time, so
    their peak RSS is the pipeline's plus one scan, not the whole sequence."""
    from frontdiag.lidar.se3 import se3_exp
    from frontdiag.lidar.synth import spinning_scan, warehouse_scene

    beams, cols, fov = SIZES[size]
    scene = warehouse_scene()
    pose0 = np.eye(4)
    pose0[:3, 3] = START
    out.mkdir(parents=True, exist_ok=True)
    for k in range(n):
        pose = pose0 @ se3_exp(TWIST * PERIOD_S * k)
        xyz, t = spinning_scan(scene, beams=beams, columns=cols, fov_deg=fov, pose0=pose,
                               twist=TWIST, period_s=PERIOD_S, seed=k)
        keep = np.isfinite(xyz).all(axis=-1)
        np.save(out / f"xyz{k}.npy", xyz[keep])
        np.save(out / f"t{k}.npy", t[keep])


def _scans(path: Path):
    """Yield (xyz, t) one scan at a time."""
    k = 0
    while (path / f"xyz{k}.npy").exists():
        yield np.load(path / f"xyz{k}.npy"), np.load(path / f"t{k}.npy")
        k += 1


def _travel_error(est_rel: np.ndarray, n: int) -> dict:
    """Error of the estimated motion from the first to the last scan against the truth."""
    from frontdiag.lidar.se3 import inv, rotation_angle_deg, se3_exp

    truth = se3_exp(TWIST * PERIOD_S * (n - 1))
    err = inv(truth) @ est_rel
    return {"travel_m": float(np.linalg.norm(truth[:3, 3])),
            "drift_m": float(np.linalg.norm(err[:3, 3])),
            "drift_deg": rotation_angle_deg(err)}


def worker_frontdiag(path: Path, backend: str) -> dict:
    from frontdiag.lidar.frontend import LidarFrontend, LidarParams
    from frontdiag.lidar.se3 import inv
    from frontdiag.records import LidarScan

    fe = LidarFrontend(LidarParams(backend=backend, num_threads=1))
    walls, cpus, rows, poses = [], [], [], []
    n_points = 0
    for k, (xyz, t) in enumerate(_scans(path)):
        n_points = len(xyz)
        scan = LidarScan(index=k, t_ns=k * 100_000_000, log_ns=0, topic="/points", xyz=xyz,
                         time_rel_s=t, n_raw=len(xyz))
        w0, c0 = time.perf_counter(), time.process_time()
        rows.append(fe.process(scan))
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
        poses.append(fe.pose if fe.pose is not None else np.eye(4))
    steady = slice(2, None)  # skip the first scan (map bootstrap) and the first registration
    res = _summary(walls[steady], cpus[steady], n_points)
    res.update(_travel_error(inv(poses[0]) @ poses[-1], len(poses)))
    ok = [r for r in rows[steady] if r["status"] == "ok"]
    for key in ("n_points_used", "icp_iters", "icp_fitness", "lidar_eig_min", "lidar_cond",
                "deskew_m", "ms_lidar_preprocess", "ms_lidar_register", "ms_lidar_map"):
        res[key] = float(np.median([r[key] for r in ok])) if ok else float("nan")
    res["weak_dir"] = ok[-1]["lidar_weak_dir"] if ok else ""
    res["statuses"] = sorted({r["status"] for r in rows})
    return res


def worker_kiss(path: Path) -> dict:
    from kiss_icp.config import load_config
    from kiss_icp.kiss_icp import KissICP

    from frontdiag.lidar.se3 import inv

    cfg = load_config(None)
    cfg.registration.max_num_threads = 1
    kiss = KissICP(cfg)
    walls, cpus, poses = [], [], []
    n_points = 0
    for xyz, t in _scans(path):
        n_points = len(xyz)
        stamps = (t - t.min()) / max(float(t.max() - t.min()), 1e-9)  # KISS wants [0, 1]
        w0, c0 = time.perf_counter(), time.process_time()
        kiss.register_frame(xyz, stamps)
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
        poses.append(kiss.last_pose.copy())
    res = _summary(walls[2:], cpus[2:], n_points)
    res.update(_travel_error(inv(poses[0]) @ poses[-1], len(poses)))
    res["voxel_m"] = cfg.mapping.voxel_size
    return res


def _summary(walls: list[float], cpus: list[float], n_points: int) -> dict:
    """Throughput over all steady scans (map rebuilds included). ``scans_per_cpu_s`` is scans
    per second of one core's CPU time: on a shared machine it does not count the time the
    process waited for a core, which wall-clock figures do."""
    w, c = np.asarray(walls), np.asarray(cpus)
    return {"points": n_points, "scans_per_cpu_s": float(len(c) / c.sum()),
            "scans_per_s": float(len(w) / w.sum()),
            "ms_median": float(np.median(w) * 1e3), "ms_p95": float(np.percentile(w, 95) * 1e3),
            "cpu_per_wall": float(c.sum() / w.sum()),
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}


def _spawn(args: list[str]) -> dict:
    env = dict(os.environ, OMP_NUM_THREADS="1")
    proc = subprocess.run([sys.executable, __file__, *args], capture_output=True, text=True,
                          env=env, check=False)
    if proc.returncode != 0:
        return {"error": proc.stderr.strip().splitlines()[-1] if proc.stderr else "failed"}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scans", type=int, default=20)
    ap.add_argument("--sizes", nargs="+", default=list(SIZES))
    ap.add_argument("--open3d", action="store_true", help="also run the Open3D backend")
    ap.add_argument("--repeat", type=int, default=3,
                    help="alternate the pipelines this many times and keep each one's best run")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    ap.add_argument("--data", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.worker:
        path = Path(a.data)
        out = worker_kiss(path) if a.worker == "kiss" else worker_frontdiag(path, a.worker)
        print(json.dumps(out))
        return

    with tempfile.TemporaryDirectory() as tmp:
        for size in a.sizes:
            path = Path(tmp) / size
            t0 = time.perf_counter()
            synthesise(size, a.scans, path)
            print(f"\n== {size}: {a.scans} scans synthesised in {time.perf_counter() - t0:.1f} s "
                  f"(warehouse, 1.5 m/s, 0.2 rad/s, one thread per pipeline)")
            workers = {"frontdiag/small_gicp": "small_gicp", "kiss-icp": "kiss"}
            if a.open3d:
                workers["frontdiag/open3d"] = "open3d"
            runs: dict[str, dict] = {}
            for _ in range(max(a.repeat, 1)):  # alternate, so load from other processes is shared
                for name, worker in workers.items():
                    r = _spawn(["--worker", worker, "--data", str(path)])
                    best = runs.get(name)
                    if best is None or "error" in best:
                        runs[name] = r
                    elif "error" not in r:  # best CPU-time run; best wall-clock kept separately
                        wall = max(best["scans_per_s"], r["scans_per_s"])
                        if r["scans_per_cpu_s"] > best["scans_per_cpu_s"]:
                            runs[name] = r
                        runs[name]["scans_per_s"] = wall
            for name, r in runs.items():
                if "error" in r:
                    print(f"  {name:22s} not run: {r['error']}")
                    continue
                print(f"  {name:22s} {r['scans_per_cpu_s']:6.1f} scans/s per core (CPU time), "
                      f"{r['scans_per_s']:5.1f} wall (best run); median {r['ms_median']:6.1f} ms"
                      f"  p95 {r['ms_p95']:6.1f} ms  cpu/wall {r['cpu_per_wall']:.2f}"
                      f"  peak RSS {r['peak_rss_mb']:6.0f} MB  drift {r['drift_m'] * 100:5.1f} cm"
                      f" / {r['drift_deg']:.2f} deg over {r['travel_m']:.2f} m")
                if "lidar_eig_min" in r:
                    print(f"  {'':22s} points {r['points']} -> {r['n_points_used']:.0f} used, "
                          f"iters {r['icp_iters']:.0f}, fitness {r['icp_fitness']:.3f}, "
                          f"lambda_min {r['lidar_eig_min']:.0f}, cond {r['lidar_cond']:.1f} "
                          f"({r['weak_dir']}), deskew {r['deskew_m']:.3f} m")
                    print(f"  {'':22s} stages (median ms): preprocess {r['ms_lidar_preprocess']:.1f}"
                          f", register+spectrum {r['ms_lidar_register']:.1f}, map "
                          f"{r['ms_lidar_map']:.1f}; statuses {r['statuses']}")
            fd, kiss = runs["frontdiag/small_gicp"], runs["kiss-icp"]
            if "error" not in fd and "error" not in kiss:
                print(f"  ratio frontdiag/kiss-icp: {fd['scans_per_cpu_s'] / kiss['scans_per_cpu_s']:.2f}x"
                      f" per core, {fd['scans_per_s'] / kiss['scans_per_s']:.2f}x wall")


if __name__ == "__main__":
    main()
