"""Throughput and memory of `analyze` on a 1280x720 recording, single process, one thread.

Measured in the same run on the same file:
  * analyze frames/s (camera frontend, ORB 1000, everything on),
  * decode-only frames/s (read + deserialise + grey conversion),
  * ORB detect+describe alone on the same decoded frames,
and the two ratios. Then peak RSS of analyze on two recording lengths, each in a fresh
process, to show memory does not grow with the length of the log.

    python benchmarks/bench_analyze.py [--frames 300] [--long 900] [--repeat 3]
"""

from __future__ import annotations

import argparse
import os

# one core: OpenCV, OpenMP and BLAS threads pinned before numpy and cv2 load
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np


def textured_world(h: int, w: int, seed: int = 0) -> np.ndarray:
    """A large textured canvas: 1/f-ish noise plus rectangles and glyph-like strokes."""
    rng = np.random.default_rng(seed)
    acc = np.zeros((h, w), np.float32)
    for sigma, amp in ((16, 50.0), (6, 30.0), (2, 18.0)):
        n = rng.normal(0, 1, (h, w)).astype(np.float32)
        acc += cv2.GaussianBlur(n, (0, 0), sigma) * amp * sigma ** 0.5 / 3
    img = np.clip(acc + 128, 0, 255).astype(np.uint8)
    for _ in range(h * w // 4000):
        x, y = int(rng.integers(0, w - 20)), int(rng.integers(0, h - 20))
        cv2.rectangle(img, (x, y), (x + int(rng.integers(3, 18)), y + int(rng.integers(3, 18))),
                      int(rng.integers(0, 255)), -1 if rng.random() < 0.5 else 1)
    return img


def write_recording(path: Path, n: int, fmt: str = "mcap") -> None:
    from frontdiag.io.writer import RecordingWriter, camera_info_msg, image_msg

    world = textured_world(900, 1280 + 2 * n + 200)
    K = np.array([[900.0, 0, 640], [0, 900.0, 360], [0, 0, 1]])
    with RecordingWriter(path, fmt) as w:
        for i in range(n):
            t = 1_000_000_000 + i * 33_333_333
            x, y = 100 + 2 * i, 90 + int(20 * np.sin(i / 15))
            frame = np.ascontiguousarray(world[y:y + 720, x:x + 1280])
            w.write("/cam/image_raw", "sensor_msgs/msg/Image", image_msg(frame, "mono8", t), t)
            w.write("/cam/camera_info", "sensor_msgs/msg/CameraInfo",
                    camera_info_msg(K, 1280, 720, t), t)


def measure(path: Path, repeat: int = 3) -> dict[str, float]:
    """Best of ``repeat`` interleaved passes of each: decode only, ORB alone, analyze.

    Interleaving spreads load from elsewhere on the machine over all three; the fastest pass
    of each is the one least disturbed by it.
    """
    from frontdiag.api import AnalysisOptions, iter_camera_frames, run_analysis
    from frontdiag.io.readers import open_recording

    cv2.setNumThreads(1)
    orb = cv2.ORB_create(nfeatures=1000, scaleFactor=1.2, nlevels=8)
    t_decode = t_orb = t_an = float("inf")
    n = 0
    table = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        frames = []
        with open_recording(path) as rec:
            for f in iter_camera_frames(rec, "/cam/image_raw", "sensor_msgs/msg/Image"):
                frames.append(f.gray)
        t_decode = min(t_decode, time.perf_counter() - t0)
        n = len(frames)
        t0 = time.perf_counter()
        for g in frames:
            orb.detectAndCompute(g, None)
        t_orb = min(t_orb, time.perf_counter() - t0)
        del frames
        t0 = time.perf_counter()
        res = run_analysis(path, AnalysisOptions())
        t_an = min(t_an, time.perf_counter() - t0)
        assert len(res.table) == n, (len(res.table), n)
        table = res.table
    assert table is not None
    stages = {c: float(table[c].median()) for c in table.columns
              if c.startswith("ms_") and table[c].notna().any()}
    return {"frames": n, "analyze_fps": n / t_an, "decode_fps": n / t_decode,
            "orb_fps": n / t_orb, "stages_ms_median": stages}  # type: ignore[dict-item]


def peak_rss_of_analyze(path: Path) -> float:
    code = ("import resource, cv2; cv2.setNumThreads(1);"
            "from frontdiag.api import run_analysis;"
            f"r = run_analysis({str(path)!r});"
            "print(len(r.table), resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    return int(out[1]) / 1024.0  # MiB (ru_maxrss is KiB on Linux)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--long", type=int, default=900, help="length of the second recording")
    ap.add_argument("--repeat", type=int, default=3, help="passes of each; the fastest counts")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        short = Path(tmp) / "short.mcap"
        write_recording(short, args.frames)
        res = measure(short, args.repeat)
        long = Path(tmp) / "long.mcap"
        write_recording(long, args.long)
        rss_short = peak_rss_of_analyze(short)
        rss_long = peak_rss_of_analyze(long)
    res["rss_mib_short"] = rss_short
    res["rss_mib_long"] = rss_long
    if args.json:
        print(json.dumps(res, indent=2))
        return
    n = res["frames"]
    print(f"1280x720 mono8, {n} frames, ORB 1000, one thread (cv2.setNumThreads(1)), "
          f"best of {args.repeat}")
    print(f"  analyze       {res['analyze_fps']:7.1f} frames/s")
    print(f"  decode only   {res['decode_fps']:7.1f} frames/s   "
          f"analyze/decode time ratio {res['decode_fps'] / res['analyze_fps']:.2f}x")
    print(f"  ORB alone     {res['orb_fps']:7.1f} frames/s   "
          f"analyze/ORB time ratio {res['orb_fps'] / res['analyze_fps']:.2f}x")
    print("  median stage times (ms): " + ", ".join(
        f"{k}={v:.2f}" for k, v in res["stages_ms_median"].items()))  # type: ignore[union-attr]
    print(f"  peak RSS: {rss_short:.0f} MiB ({args.frames} frames) vs {rss_long:.0f} MiB "
          f"({args.long} frames)")


if __name__ == "__main__":
    main()
