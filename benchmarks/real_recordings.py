"""Recordings made of real camera images (../shared/data), for the benchmarks.

The frames are real photographs: KITTI 06 (1226x370 grey), TUM fr3 long office (640x480 RGB,
also enlarged 2x to 1280x720), EuRoC V1 (752x480 grey). The sets hold only 2-17 frames each, so
each photograph is held for a segment of frames over which the view slowly pans, rotates and
zooms (a homography of the real image); the next photograph starts a new segment, as a cut.
Texture, corner density, noise and compression are real; the motion is not (it is planar), so
these recordings measure speed, not verdicts.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
T0 = 1_700_000_000_000_000_000


@dataclass(frozen=True)
class Source:
    name: str
    files: tuple[str, ...]  # globs under DATA
    K: tuple[float, float, float, float]  # fx, fy, cx, cy of the written frames
    size: tuple[int, int] | None = None  # (w, h) to enlarge and centre-crop to
    rate_hz: float = 10.0


SOURCES = {
    "kitti": Source("kitti 1226x370", ("kitti06_pairs/images/kitti06-[0-9][0-9].png",
                                       "kitti06_pairs/images/kitti06-[0-9][0-9][0-9].png"),
                    (707.0912, 707.0912, 601.8873, 183.1104)),
    "tum": Source("tum 640x480", ("tum_fr3_long_office_17f/rgb/*.png",),
                  (535.4, 539.2, 320.1, 247.6), rate_hz=30.0),
    "euroc": Source("euroc 752x480", ("euroc_lk_pair_slambook/LK*.png",),
                    (458.654, 457.296, 367.215, 248.375), rate_hz=20.0),
    "tum720": Source("tum 1280x720 (2x)", ("tum_fr3_long_office_17f/rgb/*.png",),
                     (1070.8, 1078.4, 640.2, 375.2), size=(1280, 720), rate_hz=30.0),
    "tum160": Source("tum 160x120 (1/4)", ("tum_fr3_long_office_17f/rgb/*.png",),
                     (133.85, 134.8, 80.0, 61.9), size=(160, 120), rate_hz=30.0),
}


def data_dir(path: Path | None = None) -> Path:
    return (path or DATA).resolve()


def photos(src: Source, root: Path | None = None) -> list[np.ndarray]:
    root = data_dir(root)
    files = sorted(p for g in src.files for p in root.glob(g))
    if not files:
        raise FileNotFoundError(f"no images for {src.name} under {root}")
    out = []
    for f in files:
        img = cv2.imread(str(f), cv2.IMREAD_COLOR)
        if img is None:
            raise FileNotFoundError(f"cannot read {f}")
        if src.size is not None:
            w, h = src.size
            s = max(w / img.shape[1], h / img.shape[0])
            img = cv2.resize(img, None, fx=s, fy=s, interpolation=cv2.INTER_CUBIC)
            y0, x0 = (img.shape[0] - h) // 2, (img.shape[1] - w) // 2
            img = img[y0:y0 + h, x0:x0 + w]
        out.append(np.ascontiguousarray(img))
    return out


def view(img: np.ndarray, j: int) -> np.ndarray:
    """Frame j of a segment: a slow pan, roll and zoom of the photograph."""
    h, w = img.shape[:2]
    M = cv2.getRotationMatrix2D((w / 2 + 0.6 * j, h / 2 + 0.25 * j), 0.04 * j, 1.0 + 0.0015 * j)
    return cv2.warpAffine(img, M, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def write(path: Path, key: str, n: int, *, jpeg_quality: int = 90, seg: int = 60,
          root: Path | None = None, first: int = 0) -> Path:
    """``n`` frames of source ``key`` as JPEG CompressedImage (and CameraInfo) in MCAP,
    starting at photograph ``first``."""
    from frontdiag.io.writer import RecordingWriter, camera_info_msg, compressed_image_msg

    src = SOURCES[key]
    imgs = photos(src, root)
    h, w = imgs[0].shape[:2]
    fx, fy, cx, cy = src.K
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    dt = round(1e9 / src.rate_hz)
    with RecordingWriter(path, "mcap") as wr:
        for i in range(n):
            t = T0 + i * dt
            frame = view(imgs[(first + i // seg) % len(imgs)], i % seg)
            ok, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
            assert ok
            wr.write("/cam/image/compressed", "sensor_msgs/msg/CompressedImage",
                     compressed_image_msg(buf.tobytes(), "jpeg", t), t)
            if i % 10 == 0:
                wr.write("/cam/camera_info", "sensor_msgs/msg/CameraInfo",
                         camera_info_msg(K, w, h, t), t)
    return path
