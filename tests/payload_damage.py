"""Recordings whose containers are intact and whose message payloads are damaged: H.264
pictures, Foxglove images and Velodyne packets, so that the damage reaches the decoders.

Used by ``tests/test_faults_inject.py`` (a few seeded cases in CI) and by
``benchmarks/fuzz_payloads.py`` (the longer campaign, which describes each source). Every file is
written by the caller into its own temporary folder.
"""

from __future__ import annotations

import random
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from foxglove_factory import camera_items, h264_packets, write_json, write_protobuf
from recording_factory import frame
from velodyne_factory import scan_msg, vlp16_scan

T0 = 1_700_000_000_000_000_000
DT = 50_000_000
K = np.array([[150.0, 0.0, 80.0], [0.0, 150.0, 60.0], [0.0, 0.0, 1.0]])


def _frames(n: int) -> list[np.ndarray]:
    return [np.clip(frame(i).astype(np.float32) * 0.7 + 30, 0, 255).astype(np.uint8)
            for i in range(n)]


def mutate(b: bytes, rng: random.Random, same_size: bool = False) -> bytes:
    """One damage to a payload: bits flipped, a zeroed run, or (unless ``same_size``) cut
    short, emptied, replaced by random bytes or doubled."""
    kinds = ["flip", "zeros"] if same_size else ["flip", "zeros", "cut", "empty", "random",
                                                 "double"]
    kind = rng.choice(kinds)
    if not b:
        return b
    if kind == "flip":
        a = bytearray(b)
        for _ in range(rng.randint(1, 20)):
            i = rng.randrange(len(a))
            a[i] ^= 1 << rng.randrange(8)
        return bytes(a)
    if kind == "zeros":
        i = rng.randrange(len(b))
        j = min(len(b), i + rng.randint(1, 500))
        return b[:i] + bytes(j - i) + b[j:]
    if kind == "cut":
        return b[:rng.randrange(len(b))]
    if kind == "empty":
        return b""
    if kind == "random":
        return bytes(rng.getrandbits(8) for _ in range(rng.randint(1, 300)))
    return b + b


def video(path: Path, rng: random.Random) -> Path:
    items: list[tuple[str, str, int, dict[str, Any]]] = []
    calib = {"frame_id": "cam", "width": 160, "height": 120, "distortion_model": "plumb_bob",
             "D": [0.0] * 5, "K": [float(v) for v in K.ravel()]}
    for i, pkt in enumerate(h264_packets(_frames(24), 6)):
        if rng.random() < 0.25:
            pkt = mutate(pkt, rng)
        fmt = "h264" if rng.random() > 0.05 else rng.choice(["", "h265", "H264", "vp9",
                                                              "mjpeg"])
        t = T0 + i * DT
        items.append(("/cam/video", "CompressedVideo", t,
                      {"frame_id": "cam", "data": pkt, "format": fmt}))
        items.append(("/cam/calibration", "CameraCalibration", t, calib))
    return write_protobuf(path, iter(items))


def images(writer: Callable[..., Path]) -> Callable[[Path, random.Random], Path]:
    def make(path: Path, rng: random.Random) -> Path:
        kind = rng.choice(["RawImage", "CompressedImage"])
        out = []
        for topic, schema, t, fields in camera_items(_frames(9), K, T0, DT, kind=kind):
            fields = dict(fields)
            if rng.random() < 0.3:
                key = rng.choice(sorted(fields))
                v = fields[key]
                if isinstance(v, bytes):
                    fields[key] = mutate(v, rng)
                elif isinstance(v, int):
                    fields[key] = rng.choice([0, -1, v * 2, v + 1, 2**31 - 1])
                elif isinstance(v, str):
                    fields[key] = rng.choice(["", "rgb8", "bgr8", "mono16", "16UC1", "jpeg",
                                              "weird", "rgb16", "bayer_rggb16", "nv12",
                                              "nv21", "bgra16"])
                elif isinstance(v, list):
                    fields[key] = v[:rng.randrange(len(v) + 1)]
            out.append((topic, schema, t, fields))
        return writer(path, iter(out))
    return make


def velodyne(fmt: str) -> Callable[[Path, random.Random], Path]:
    from frontdiag.io.writer import RecordingWriter

    def make(path: Path, rng: random.Random) -> Path:
        with RecordingWriter(path, fmt) as w:
            for k in range(4):
                pose = np.eye(4)
                pose[:3, 3] = [2.0 + 0.1 * k, 0.3, 1.2]
                packets, _, _ = vlp16_scan(pose, 1.7e9 + 0.1 * k)
                if rng.random() < 0.5:
                    packets = [(t, mutate(d, rng, same_size=True) if rng.random() < 0.2 else d)
                               for t, d in packets]
                if rng.random() < 0.1:
                    packets = packets[:rng.randrange(1, len(packets))]
                w.write("/velodyne_packets", "velodyne_msgs/msg/VelodyneScan",
                        scan_msg(packets), int(packets[-1][0] * 1e9))
        return path
    return make


PAYLOAD_SOURCES: dict[str, tuple[str, Callable[[Path, random.Random], Path]]] = {
    "video": (".mcap", video),
    "pb-image": (".mcap", images(write_protobuf)),
    "json-image": (".mcap", images(write_json)),
    "velo-bag": (".bag", velodyne("bag")),
    "velo-mcap": (".mcap", velodyne("mcap")),
}

# damage that the writer itself refuses (a negative width in a Protobuf unsigned field)
NOT_WRITABLE_ERRORS = (ValueError, TypeError, OverflowError)
