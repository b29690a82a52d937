"""Which backend reads a standalone ROS 2 MCAP faster: rosbags' AnyReader or the mcap package?

Writes a 1280x720 mono8 recording (default 300 frames) and times, in the same run, a full pass
that reads and deserialises every image with each backend. Prints messages/s and MB/s.

    python benchmarks/bench_readers.py [--frames 300] [--repeats 3]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from frontdiag.io.readers import McapRecording, RosbagsRecording
from frontdiag.io.writer import RecordingWriter, image_msg


def write(path: Path, n: int) -> None:
    rng = np.random.default_rng(0)
    base = rng.integers(0, 255, (720, 1280 + n), dtype=np.uint8)
    with RecordingWriter(path, "mcap") as w:
        for i in range(n):
            t = 1_000_000_000 + i * 33_333_333
            w.write("/cam/image_raw", "sensor_msgs/msg/Image",
                    image_msg(np.ascontiguousarray(base[:, i:i + 1280]), "mono8", t), t)


def run(rec_factory, path: Path) -> tuple[float, int]:  # type: ignore[no-untyped-def]
    t0 = time.perf_counter()
    n = 0
    with rec_factory(path) as rec:
        for raw in rec.messages(["/cam/image_raw"]):
            msg = rec.deserialize(raw)
            n += int(msg.data.shape[0] > 0)
    return time.perf_counter() - t0, n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.mcap"
        write(path, args.frames)
        size_mb = path.stat().st_size / 1e6
        backends = {"mcap": McapRecording,
                    "rosbags": lambda p: RosbagsRecording(p, [p])}
        best: dict[str, float] = {}
        for _ in range(args.repeats):
            for name, factory in backends.items():
                dt, n = run(factory, path)
                assert n == args.frames
                best[name] = min(best.get(name, float("inf")), dt)
        print(f"recording: {args.frames} frames 1280x720 mono8, {size_mb:.0f} MB")
        for name, dt in best.items():
            print(f"  {name:8s} {args.frames / dt:8.1f} msgs/s  {size_mb / dt:8.1f} MB/s "
                  f"(best of {args.repeats})")
        print(f"  ratio mcap/rosbags: {best['rosbags'] / best['mcap']:.2f}x")


if __name__ == "__main__":
    main()
