"""H.264 video (Foxglove CompressedVideo) against JPEG frames: decode cost, and whether the verdicts change.

For each source the same real frames are written twice, as JPEG CompressedImage (quality 90)
and as H.264 CompressedVideo (x264, CRF 23, a keyframe every 30 frames, no B-frames: what a
camera streaming at a few Mbit/s records). In the same run it prints, per frame:

* decoding: JPEG (cv2.imdecode to grey), H.264 with frontdiag's luma (the Y plane stretched to
  full range), and H.264 with FFmpeg's own conversion to grey, which gives the same values;
* analyze (one process, one OpenCV thread) on both recordings: frames/s, its ratio, and the
  frames whose conditions differ between the two.

Sources: the real photographs of ../shared/data (real_recordings.py: KITTI 1226x370, TUM
640x480 and 1280x720, slowly warped, so they measure speed, not verdicts) and any recording
passed with --recording (a real video, e.g. the validation set's udacity_highway.bag or
kitti02_road.mcap, where the verdicts mean something).

    python benchmarks/bench_video.py --data ../shared/data [--recording REC ...] [--frames 150]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # validation/
import real_recordings

cv2.setNumThreads(1)
T0 = real_recordings.T0


def frames_of(path: Path, n: int) -> tuple[list[np.ndarray], list[int], np.ndarray | None]:
    """Up to ``n`` grey frames of a recording's camera, their log times, and its K."""
    from frontdiag.api import AnalysisOptions, resolve_intrinsics
    from frontdiag.io.images import GrayConverter
    from frontdiag.io.readers import open_recording
    from frontdiag.io.topics import choose_topics

    out, stamps = [], []
    with open_recording(path) as rec:
        choice = choose_topics(rec.topics, use_lidar=False)
        intr = resolve_intrinsics(rec, choice, AnalysisOptions(), [])
        conv = GrayConverter(choice.camera or "")
        for raw in rec.messages([choice.camera or ""]):
            gray, _ = conv(rec.deserialize(raw), raw.msgtype)
            out.append(gray[: gray.shape[0] // 2 * 2, : gray.shape[1] // 2 * 2])
            stamps.append(raw.log_ns)
            if len(out) >= n:
                break
    return out, stamps, None if intr is None else np.asarray(intr.K)


def h264(frames: list[np.ndarray]) -> list[bytes]:
    """CRF 23, a keyframe every 30 frames (validation/video.py's encoder)."""
    from validation.video import Encoder

    h, w = frames[0].shape
    enc = Encoder(w, h, crf=23, keyint=30)
    pk = [p for img in frames for p in enc(img)]
    return pk + enc.flush()


def write_pair(tmp: Path, name: str, frames: list[np.ndarray], stamps: list[int],
               K: np.ndarray | None) -> tuple[Path, Path, list[bytes], list[bytes]]:
    from mcap_protobuf.writer import Writer

    from frontdiag.io.writer import RecordingWriter, camera_info_msg, compressed_image_msg

    h, w = frames[0].shape
    jpegs = [cv2.imencode(".jpg", f, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes()
             for f in frames]
    packets = h264(frames)
    jpg_path, vid_path = tmp / f"{name}_jpeg.mcap", tmp / f"{name}_h264.mcap"
    with RecordingWriter(jpg_path, "mcap") as wr:
        for t, buf in zip(stamps, jpegs, strict=True):
            wr.write("/cam/image/compressed", "sensor_msgs/msg/CompressedImage",
                     compressed_image_msg(buf, "jpeg", t), t)
            if K is not None:
                wr.write("/cam/camera_info", "sensor_msgs/msg/CameraInfo",
                         camera_info_msg(K, w, h, t), t)
    from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
    from foxglove_schemas_protobuf.CompressedVideo_pb2 import CompressedVideo
    from google.protobuf.timestamp_pb2 import Timestamp

    with open(vid_path, "wb") as fh, Writer(fh) as wr:
        for t, pkt in zip(stamps, packets, strict=True):
            ts = Timestamp(seconds=t // 10**9, nanos=t % 10**9)
            wr.write_message("/cam/video", CompressedVideo(timestamp=ts, frame_id="cam",
                                                           data=pkt, format="h264"), t, t)
            if K is not None:
                wr.write_message("/cam/calibration", CameraCalibration(
                    timestamp=ts, frame_id="cam", width=w, height=h,
                    distortion_model="plumb_bob", D=[0.0] * 5,
                    K=[float(v) for v in np.asarray(K).ravel()]), t, t)
    return jpg_path, vid_path, jpegs, packets


def decode_ms(jpegs: list[bytes], packets: list[bytes], repeat: int) -> dict[str, float]:
    import av

    from frontdiag.io.images import luma

    def jpeg() -> None:
        for b in jpegs:
            cv2.imdecode(np.frombuffer(b, np.uint8), cv2.IMREAD_GRAYSCALE)

    def video(own: bool) -> None:
        ctx = av.CodecContext.create("h264", "r")
        ctx.thread_type = "NONE"
        for p in packets:
            for f in ctx.decode(av.Packet(p)):
                luma(f) if own else f.to_ndarray(format="gray")

    out = {}
    for key, fn in (("jpeg", jpeg), ("h264 luma", lambda: video(True)),
                    ("h264 swscale", lambda: video(False))):
        best = min(_timed(fn) for _ in range(repeat))
        out[key] = best / len(jpegs) * 1e3
    return out


def _timed(fn) -> float:  # type: ignore[no-untyped-def]
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def compare(jpg_path: Path, vid_path: Path) -> dict[str, float]:
    from frontdiag.api import AnalysisOptions, run_analysis

    res = {}
    for key, path in (("jpeg", jpg_path), ("h264", vid_path)):
        t0 = time.perf_counter()
        res[key] = run_analysis(path, AnalysisOptions())
        res[key + "_s"] = time.perf_counter() - t0
    a, b = res["jpeg"].table, res["h264"].table
    ca = a["conditions"].map(lambda v: ",".join(sorted(v))).to_numpy()
    cb = b["conditions"].map(lambda v: ",".join(sorted(v))).to_numpy()
    n = min(len(ca), len(cb))
    return {"frames": n, "fps_jpeg": len(a) / res["jpeg_s"], "fps_h264": len(b) / res["h264_s"],
            "differ": int((ca[:n] != cb[:n]).sum()),
            "flagged_jpeg": int((ca != "").sum()), "flagged_h264": int((cb != "").sum())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=None, help="../shared/data")
    ap.add_argument("--recording", type=Path, action="append", default=[],
                    help="a real recording with a camera (repeatable)")
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    print("per frame: decode ms (best of --repeat); analyze frames/s on one core; frames whose "
          "conditions differ between the JPEG and the H.264 recording")
    print(f"  {'source':28s} {'size':>9s} {'kB/frame':>13s} {'jpeg':>6s} {'h264':>6s} "
          f"{'swscale':>7s} {'fps jpeg':>8s} {'fps h264':>8s} {'differ':>10s} "
          f"{'flagged j/h':>11s}")
    with tempfile.TemporaryDirectory() as tmp_s:
        tmp = Path(tmp_s)
        jobs: list[tuple[str, Path]] = []
        if args.data is not None:
            for key in ("kitti", "tum", "tum720"):
                p = tmp / f"src_{key}.mcap"
                real_recordings.write(p, key, args.frames, root=args.data)
                jobs.append((real_recordings.SOURCES[key].name, p))
        jobs += [(p.name, p) for p in args.recording]
        for name, src in jobs:
            frames, stamps, K = frames_of(src, args.frames)
            jp, vp, jpegs, packets = write_pair(tmp, name.replace(" ", "_"), frames, stamps, K)
            ms = decode_ms(jpegs, packets, args.repeat)
            cmp = compare(jp, vp)
            h, w = frames[0].shape
            kb = f"{np.mean([len(b) for b in jpegs]) / 1024:.1f}/{np.mean([len(b) for b in packets]) / 1024:.1f}"
            print(f"  {name:28s} {w:>4d}x{h:<4d} {kb:>13s} {ms['jpeg']:6.2f} {ms['h264 luma']:6.2f} "
                  f"{ms['h264 swscale']:7.2f} {cmp['fps_jpeg']:8.1f} {cmp['fps_h264']:8.1f} "
                  f"{cmp['differ']:>4d}/{cmp['frames']:<5d} "
                  f"{cmp['flagged_jpeg']:>5d}/{cmp['flagged_h264']:<5d}")


if __name__ == "__main__":
    main()
