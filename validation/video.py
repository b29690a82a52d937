"""A recording's camera re-encoded as H.264 video (Foxglove CompressedVideo), stamps and
calibration kept: what the same camera gives when it is recorded as a video stream.

    python validation/score.py --video 23      # the dev half, every recording as H.264 CRF 23

x264 (``preset medium``, ``tune zerolatency``, no B-frames, a keyframe every ``keyint``
frames carrying its SPS and PPS), grey frames as yuv420p, one message a picture, each stamped
with its frame's header stamp and log time, so the recording's labels still apply. Odd image
sizes lose their last column or row (4:2:0 needs even sizes), which leaves K as it is.
"""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np


class Encoder:
    """Grey frames to H.264 (``libx264``) or H.265 (``libx265``) access units in decode
    order, a keyframe every ``keyint`` frames carrying its parameter sets; one per frame
    without B-frames (``bframes=0``, the default)."""

    def __init__(self, width: int, height: int, crf: int, keyint: int, *,
                 codec: str = "libx264", bframes: int = 0, preset: str = "medium") -> None:
        import av

        self._av = av
        self.ctx = av.CodecContext.create(codec, "w")
        self.ctx.width, self.ctx.height, self.ctx.pix_fmt = width, height, "yuv420p"
        self.ctx.time_base = Fraction(1, 30)
        params = f"keyint={keyint}:min-keyint={keyint}:bframes={bframes}:repeat-headers=1"
        if codec == "libx265":
            opts = {"x265-params": params + ":log-level=error"}
        else:
            opts = {"x264-params": params + ":threads=1"}
            if not bframes:
                opts["tune"] = "zerolatency"  # which also turns B-frames off
        self.ctx.options = {"preset": preset, "crf": str(crf), **opts}
        self.n = 0

    def __call__(self, gray: np.ndarray) -> list[bytes]:
        f = self._av.VideoFrame.from_ndarray(
            np.ascontiguousarray(gray[:self.ctx.height, :self.ctx.width]), format="gray")
        f = f.reformat(format="yuv420p")
        f.pts = self.n
        self.n += 1
        return [bytes(p) for p in self.ctx.encode(f)]

    def flush(self) -> list[bytes]:
        return [bytes(p) for p in self.ctx.encode(None)]


def to_h264(src: Path, dst: Path, crf: int = 23, keyint: int = 30) -> Path:
    """Write ``src``'s camera (and its calibration) to ``dst`` as Foxglove CompressedVideo and
    CameraCalibration in Protobuf MCAP."""
    from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
    from foxglove_schemas_protobuf.CompressedVideo_pb2 import CompressedVideo
    from google.protobuf.timestamp_pb2 import Timestamp
    from mcap_protobuf.writer import Writer

    from frontdiag.api import AnalysisOptions, resolve_intrinsics
    from frontdiag.io.decode import header_stamp_ns
    from frontdiag.io.images import GrayConverter
    from frontdiag.io.readers import open_recording
    from frontdiag.io.topics import choose_topics

    enc: Encoder | None = None
    stamps: list[tuple[int, int]] = []  # (header stamp, log time) per frame, in order
    packets: list[bytes] = []
    calib: dict[str, Any] | None = None
    with open_recording(src) as rec:
        choice = choose_topics(rec.topics, use_lidar=False)
        assert choice.camera is not None
        intr = resolve_intrinsics(rec, choice, AnalysisOptions(), [])
        conv = GrayConverter(choice.camera)
        for raw in rec.messages([choice.camera]):
            msg = rec.deserialize(raw)
            gray, _ = conv(msg, raw.msgtype)
            if enc is None:
                h, w = gray.shape
                enc = Encoder(w - w % 2, h - h % 2, crf, keyint)
                if intr is not None:
                    calib = {"width": enc.ctx.width, "height": enc.ctx.height,
                             "distortion_model": intr.model or "plumb_bob",
                             "D": [float(v) for v in np.asarray(intr.D).ravel()],
                             "K": [float(v) for v in np.asarray(intr.K).ravel()]}
            t = header_stamp_ns(msg) or raw.log_ns
            stamps.append((t, raw.log_ns))
            packets += enc(gray)
    if enc is None:
        raise ValueError(f"{src}: no camera frames")
    packets += enc.flush()
    assert len(packets) == len(stamps), "one access unit per frame (no B-frames)"
    with open(dst, "wb") as fh, Writer(fh) as wr:
        for (t, log_t), pkt in zip(stamps, packets, strict=True):
            ts = Timestamp(seconds=t // 10**9, nanos=t % 10**9)
            wr.write_message("/camera/video", CompressedVideo(
                timestamp=ts, frame_id="camera", data=pkt, format="h264"), log_t, log_t)
            if calib is not None:
                wr.write_message("/camera/calibration", CameraCalibration(
                    timestamp=ts, frame_id="camera", **calib), log_t, log_t)
    return dst
