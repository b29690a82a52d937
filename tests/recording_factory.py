"""Tiny recordings of every container and encoding, written into a test's tmp_path."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path

import cv2
import numpy as np

from frontdiag.io.writer import (
    RecordingWriter,
    camera_info_msg,
    compressed_image_msg,
    image_msg,
)

W, H = 160, 120
K = np.array([[120.0, 0.0, 80.0], [0.0, 120.0, 60.0], [0.0, 0.0, 1.0]])
T0 = 1_700_000_000_000_000_000
DT = 50_000_000  # 20 Hz

CONTAINERS = {  # name -> (writer format, path suffix)
    "bag": ("bag", "run.bag"),
    "ros2-db3": ("ros2-db3", "run_db3"),
    "ros2-mcap": ("ros2-mcap", "run_mcap"),
    "mcap": ("mcap", "run.mcap"),
    "mcap-ros1": ("mcap-ros1", "run_ros1.mcap"),
}


def scene(seed: int = 0, size: tuple[int, int] = (W, H)) -> np.ndarray:
    """A textured grey image with blobs and edges ORB can find (larger than one frame)."""
    w, h = size
    rng = np.random.default_rng(seed)
    big = np.zeros((h + 40, w + 40), np.float32)
    noise = rng.normal(0, 1, big.shape).astype(np.float32)
    big += cv2.GaussianBlur(noise, (0, 0), 3) * 60 + 120
    for _ in range(60):
        x, y = int(rng.integers(0, w + 40)), int(rng.integers(0, h + 40))
        r = int(rng.integers(2, 8))
        cv2.rectangle(big, (x, y), (x + 2 * r, y + r), float(rng.integers(0, 255)), -1)
    return np.clip(big, 0, 255).astype(np.uint8)


def frame(i: int, seed: int = 0, size: tuple[int, int] = (W, H), shift: int = 1) -> np.ndarray:
    """Frame i: a window sliding over the scene by ``shift`` px per frame."""
    big = scene(seed, size)
    w, h = size
    x = (i * shift) % 40
    return np.ascontiguousarray(big[10:10 + h, x:x + w])


def encode(gray: np.ndarray, encoding: str) -> tuple[str, np.ndarray | bytes]:
    """(msg kind, payload) carrying ``gray`` in a given encoding."""
    if encoding == "mono8":
        return "raw", gray
    if encoding == "mono16":
        return "raw", gray.astype(np.uint16) * 257
    if encoding in ("rgb8", "bgr8"):
        return "raw", np.dstack([gray, gray, gray])
    if encoding in ("rgba8", "bgra8"):
        return "raw", np.dstack([gray, gray, gray, np.full_like(gray, 255)])
    if encoding in ("rgb16", "bgr16"):
        return "raw", np.dstack([gray, gray, gray]).astype(np.uint16) * 257
    if encoding in ("rgba16", "bgra16"):
        g16 = gray.astype(np.uint16) * 257
        return "raw", np.dstack([g16, g16, g16, np.full_like(g16, 65535)])
    if encoding.startswith("bayer_"):
        return "raw", gray  # a flat-colour scene has the same value in every Bayer site
    if encoding in ("jpeg", "png"):
        ok, buf = cv2.imencode("." + ("jpg" if encoding == "jpeg" else "png"), gray)
        assert ok
        return "compressed", buf.tobytes()
    raise ValueError(encoding)


def write_recording(path: Path, fmt: str, *, n: int = 6, encoding: str = "mono8",
                    topic: str = "/cam/image_raw", with_info: bool = True, seed: int = 0,
                    extra: Callable[[RecordingWriter, int, int], None] | None = None,
                    stamps: Iterable[int] | None = None, shift: int = 1,
                    chunk_bytes: int = 1024 * 1024, compression: str | None = None) -> Path:
    """Write ``n`` frames (and a CameraInfo per frame) to ``path`` in container ``fmt``; the
    scene slides ``shift`` pixels per frame; ``chunk_bytes=0`` writes an unchunked MCAP;
    ``compression`` as ``RecordingWriter`` takes it."""
    stamp_list = list(stamps) if stamps is not None else [T0 + i * DT for i in range(n)]
    with RecordingWriter(path, fmt, chunk_bytes=chunk_bytes, compression=compression) as w:
        for i, t in enumerate(stamp_list):
            log_t = T0 + i * DT
            kind, payload = encode(frame(i, seed, shift=shift), encoding)
            if kind == "raw":
                w.write(topic, "sensor_msgs/msg/Image",
                        image_msg(np.asarray(payload), encoding, t), log_t)
            else:
                w.write(topic + "/compressed" if not topic.endswith("compressed") else topic,
                        "sensor_msgs/msg/CompressedImage",
                        compressed_image_msg(bytes(payload), encoding, t), log_t)
            if with_info:
                w.write("/cam/camera_info", "sensor_msgs/msg/CameraInfo",
                        camera_info_msg(K, W, H, t), log_t)
            if extra is not None:
                extra(w, i, log_t)
    return path


def cut_recording(tmp: Path, fmt: str, name: str, *, n: int = 150,
                  fraction: float = 0.6) -> Path:
    """``n`` frames in ``fmt``, cut to ``fraction`` of their bytes like a recorder killed mid-write.

    Returns ``tmp / ("cut_" + name)``. A ROS 2 bag folder keeps its metadata.yaml and has its
    storage file cut; a ``name`` ending in ``.db3`` is the cut sqlite file on its own.
    """
    import shutil

    (tmp / "full").mkdir(parents=True, exist_ok=True)
    full = write_recording(tmp / "full" / ("bag" if name.endswith(".db3") else name), fmt, n=n)
    cut = tmp / ("cut_" + name)
    if full.is_dir():
        (storage,) = [p for p in full.iterdir() if p.suffix in (".db3", ".mcap")]
        if name.endswith(".db3"):
            src, dest = storage, cut
        else:
            shutil.copytree(full, cut)
            src = dest = cut / storage.name
    else:
        src, dest = full, cut
    data = src.read_bytes()
    dest.write_bytes(data[: int(len(data) * fraction)])
    return cut
