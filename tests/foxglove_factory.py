"""MCAP recordings in Foxglove's schemas (Protobuf and JSON encodings), and H.264 video."""

from __future__ import annotations

import base64
import json
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # validation/ (the encoder) is not part of the package
    sys.path.insert(0, str(ROOT))

# Foxglove's JSON Schemas, reduced to what a reader needs to know (their published versions
# add descriptions); bytes fields are base64 strings ("contentEncoding": "base64")
_TIME = {"type": "object", "properties": {"sec": {"type": "integer"},
                                          "nsec": {"type": "integer"}}}
JSON_SCHEMAS = {
    "foxglove.CompressedImage": {"type": "object", "properties": {
        "timestamp": _TIME, "frame_id": {"type": "string"},
        "data": {"type": "string", "contentEncoding": "base64"}, "format": {"type": "string"}}},
    "foxglove.RawImage": {"type": "object", "properties": {
        "timestamp": _TIME, "frame_id": {"type": "string"}, "width": {"type": "integer"},
        "height": {"type": "integer"}, "encoding": {"type": "string"},
        "step": {"type": "integer"}, "data": {"type": "string", "contentEncoding": "base64"}}},
    "foxglove.CameraCalibration": {"type": "object", "properties": {
        "timestamp": _TIME, "frame_id": {"type": "string"}, "width": {"type": "integer"},
        "height": {"type": "integer"}, "distortion_model": {"type": "string"},
        "D": {"type": "array"}, "K": {"type": "array"}, "R": {"type": "array"},
        "P": {"type": "array"}}},
    "foxglove.LaserScan": {"type": "object", "properties": {
        "timestamp": _TIME, "frame_id": {"type": "string"}, "pose": {"type": "object"},
        "start_angle": {"type": "number"}, "end_angle": {"type": "number"},
        "ranges": {"type": "array"}, "intensities": {"type": "array"}}},
}


def _calibration(K: np.ndarray, w: int, h: int) -> dict[str, Any]:
    P = np.zeros((3, 4))
    P[:, :3] = K
    return {"width": w, "height": h, "distortion_model": "plumb_bob", "D": [0.0] * 5,
            "K": [float(v) for v in K.ravel()], "R": [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0],
            "P": [float(v) for v in P.ravel()]}


def write_protobuf(path: Path, items: Iterator[tuple[str, str, int, dict[str, Any]]]) -> Path:
    """``(topic, schema, t_ns, fields)`` as Foxglove Protobuf messages in one MCAP file;
    ``schema`` names a module of foxglove_schemas_protobuf (``CompressedImage``, ...)."""
    import importlib

    from google.protobuf.timestamp_pb2 import Timestamp
    from mcap_protobuf.writer import Writer

    with open(path, "wb") as fh, Writer(fh) as w:
        for topic, schema, t_ns, fields in items:
            cls = getattr(importlib.import_module(f"foxglove_schemas_protobuf.{schema}_pb2"),
                          schema)
            msg = cls(timestamp=Timestamp(seconds=t_ns // 10**9, nanos=t_ns % 10**9), **fields)
            w.write_message(topic=topic, message=msg, log_time=t_ns, publish_time=t_ns)
    return path


def write_json(path: Path, items: Iterator[tuple[str, str, int, dict[str, Any]]]) -> Path:
    """The same as :func:`write_protobuf` in JSON encoding (``schema`` as there)."""
    from mcap.writer import Writer

    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start()
        schemas: dict[str, int] = {}
        channels: dict[str, int] = {}
        for topic, schema, t_ns, fields in items:
            name = f"foxglove.{schema}"
            if name not in schemas:
                schemas[name] = w.register_schema(
                    name, "jsonschema", json.dumps(JSON_SCHEMAS[name]).encode())
            if topic not in channels:
                channels[topic] = w.register_channel(topic, "json", schemas[name])
            body = {k: (base64.b64encode(v).decode() if isinstance(v, bytes) else v)
                    for k, v in fields.items()}
            body["timestamp"] = {"sec": t_ns // 10**9, "nsec": t_ns % 10**9}
            w.add_message(channels[topic], log_time=t_ns, data=json.dumps(body).encode(),
                          publish_time=t_ns)
        w.finish()
    return path


def camera_items(frames: list[np.ndarray], K: np.ndarray, t0: int, dt: int, *,
                 kind: str = "CompressedImage", topic: str = "/cam/image"
                 ) -> Iterator[tuple[str, str, int, dict[str, Any]]]:
    """Frames (grey) as Foxglove ``CompressedImage`` (PNG, lossless) or ``RawImage`` (mono8),
    each with a ``CameraCalibration`` on ``/cam/calibration``."""
    import cv2

    h, w = frames[0].shape
    for i, img in enumerate(frames):
        t = t0 + i * dt
        if kind == "CompressedImage":
            ok, buf = cv2.imencode(".png", img)
            assert ok
            yield topic, kind, t, {"frame_id": "cam", "data": buf.tobytes(), "format": "png"}
        else:
            yield topic, kind, t, {"frame_id": "cam", "width": w, "height": h,
                                   "encoding": "mono8", "step": w, "data": img.tobytes()}
        yield "/cam/calibration", "CameraCalibration", t, {"frame_id": "cam",
                                                          **_calibration(K, w, h)}


def h264_packets(frames: list[np.ndarray], keyint: int) -> list[bytes]:
    """Grey frames encoded as H.264 (x264, no B-frames, a keyframe every ``keyint`` frames with
    its SPS and PPS, Annex B): one access unit per frame, as Foxglove's CompressedVideo holds."""
    out = encode_video(frames, keyint)
    assert len(out) == len(frames)
    return out


def encode_video(frames: list[np.ndarray], keyint: int, *, encoder: str = "libx264",
                 bframes: int = 0) -> list[bytes]:
    """Grey frames as H.264 (``libx264``) or H.265 (``libx265``) access units in decode order
    (validation/video.py's encoder, fast and nearly lossless: ultrafast, CRF 12)."""
    from validation.video import Encoder

    h, w = frames[0].shape
    enc = Encoder(w, h, crf=12, keyint=keyint, codec=encoder, bframes=bframes,
                  preset="ultrafast")
    return [p for img in frames for p in enc(img)] + enc.flush()
