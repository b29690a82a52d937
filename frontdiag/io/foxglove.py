"""Foxglove's message schemas, read as the ``sensor_msgs`` messages they stand for.

Recordings made outside ROS (the Foxglove SDK, or any MCAP writer that uses Foxglove's
schemas) carry camera and LiDAR data as ``foxglove.CompressedImage``, ``foxglove.RawImage``,
``foxglove.CompressedVideo``, ``foxglove.CameraCalibration``, ``foxglove.PointCloud`` and
``foxglove.LaserScan``, in Protobuf or JSON encoding; ROS 1 and ROS 2 systems carry the same
schemas as ``foxglove_msgs/msg/*`` (https://docs.foxglove.dev/docs/sdk/schemas). Each is turned
here into an object with the fields of its ``sensor_msgs`` counterpart (``header.stamp``,
``encoding``, ``k`` ...), so that every decoder reads one shape whatever the recording's origin.

``CompressedVideo`` has no ``sensor_msgs`` counterpart: one message is one H.264, H.265, VP9 or
AV1 picture that depends on the pictures before it back to a keyframe
(:class:`frontdiag.io.images.VideoDecoder`).

Decoding stays here, not in the readers: an MCAP channel names its message encoding
(``protobuf``: the schema record holds a ``FileDescriptorSet``; ``json``: a JSON Schema, with
``bytes`` fields as base64 strings and times as ``{"sec", "nsec"}``).
"""

from __future__ import annotations

import base64
import json
from collections.abc import Callable
from types import SimpleNamespace
from typing import Any

import numpy as np

# Foxglove schema -> the sensor_msgs message whose fields the adapted message has
_ROS_EQUIVALENT = {
    "CompressedImage": "sensor_msgs/msg/CompressedImage",
    "RawImage": "sensor_msgs/msg/Image",
    "CameraCalibration": "sensor_msgs/msg/CameraInfo",
    "PointCloud": "sensor_msgs/msg/PointCloud2",
    "LaserScan": "sensor_msgs/msg/LaserScan",
    "CompressedVideo": "foxglove.CompressedVideo",
}
_PREFIXES = ("foxglove.", "foxglove_msgs/msg/")

IMAGE_TYPES = tuple(p + k for p in _PREFIXES for k in ("CompressedImage", "RawImage",
                                                         "CompressedVideo"))
CAMERA_INFO_TYPES = tuple(p + "CameraCalibration" for p in _PREFIXES)
LIDAR_TYPES = tuple(p + k for p in _PREFIXES for k in ("PointCloud", "LaserScan"))
VIDEO_TYPES = tuple(p + "CompressedVideo" for p in _PREFIXES)
ENCODINGS = ("protobuf", "json")
"""MCAP message encodings read for Foxglove schemas (besides ``cdr`` and ``ros1``)."""


def kind(msgtype: str) -> str | None:
    """``CompressedImage`` for ``foxglove.CompressedImage`` or ``foxglove_msgs/msg/...``;
    None for any other message type."""
    for p in _PREFIXES:
        if msgtype.startswith(p):
            k = msgtype[len(p):]
            return k if k in _ROS_EQUIVALENT else None
    return None


def ros_type(msgtype: str) -> str:
    """The message type whose fields an adapted message has: the ``sensor_msgs`` counterpart
    of a Foxglove schema, ``foxglove.CompressedVideo`` for video, else ``msgtype`` itself."""
    k = kind(msgtype)
    return msgtype if k is None else _ROS_EQUIVALENT[k]


# --------------------------------------------------------------------------------------------
# decoding the container's bytes
# --------------------------------------------------------------------------------------------

def protobuf_decoder(schema: Any) -> Callable[[bytes], Any]:
    """A function from a message's bytes to its Protobuf message, for an MCAP schema record
    whose data is a ``FileDescriptorSet`` (the mcap-protobuf-support package builds the class)."""
    from mcap_protobuf.decoder import DecoderFactory

    fn = DecoderFactory().decoder_for("protobuf", schema)
    if fn is None:
        raise ValueError(f"schema {schema.name!r} is not a Protobuf schema "
                         f"(its encoding is {schema.encoding!r})")
    return fn


def json_decoder(schema: Any) -> Callable[[bytes], Any]:
    """A function from a JSON message's bytes to nested namespaces; ``bytes`` fields (base64
    strings in Foxglove's JSON schemas) stay strings until :func:`adapt` reads them."""
    def decode(data: bytes) -> Any:
        return _ns(json.loads(bytes(data)))
    return decode


def _ns(value: Any) -> Any:
    if isinstance(value, dict):
        return SimpleNamespace(**{k: _ns(v) for k, v in value.items()})
    if isinstance(value, list):
        return [_ns(v) for v in value]
    return value


# --------------------------------------------------------------------------------------------
# the sensor_msgs shape
# --------------------------------------------------------------------------------------------

def adapt(msg: Any, msgtype: str) -> Any:
    """``msg`` (Protobuf, JSON or ROS ``foxglove_msgs``) with the fields of its ``sensor_msgs``
    counterpart; messages of other types are returned as they are."""
    k = kind(msgtype)
    if k is None:
        return msg
    header = SimpleNamespace(stamp=_stamp(getattr(msg, "timestamp", None)),
                             frame_id=str(getattr(msg, "frame_id", "") or ""))
    if k in ("CompressedImage", "CompressedVideo"):
        return SimpleNamespace(header=header, format=str(getattr(msg, "format", "") or ""),
                               data=_bytes(getattr(msg, "data", b"")))
    if k == "RawImage":
        # Foxglove's 16-bit encodings are little-endian; there is no is_bigendian field
        return SimpleNamespace(header=header, width=int(msg.width), height=int(msg.height),
                               encoding=str(msg.encoding), step=int(msg.step), is_bigendian=0,
                               data=_bytes(msg.data))
    if k == "CameraCalibration":
        return SimpleNamespace(header=header, width=int(msg.width), height=int(msg.height),
                               distortion_model=str(getattr(msg, "distortion_model", "") or ""),
                               d=_floats(msg, "D"), k=_floats(msg, "K"), r=_floats(msg, "R"),
                               p=_floats(msg, "P"), binning_x=0, binning_y=0, roi=None)
    if k == "PointCloud":
        return _point_cloud(msg, header)
    return _laser_scan(msg, header)


def _stamp(ts: Any) -> SimpleNamespace:
    """Protobuf ``Timestamp`` (seconds, nanos), ROS ``Time`` (sec, nanosec) or JSON
    (sec, nsec): as ROS 2's (sec, nanosec)."""
    if ts is None:
        return SimpleNamespace(sec=0, nanosec=0)
    for s, n in (("seconds", "nanos"), ("sec", "nanosec"), ("sec", "nsec")):
        if hasattr(ts, s) and hasattr(ts, n):
            return SimpleNamespace(sec=int(getattr(ts, s)), nanosec=int(getattr(ts, n)))
    return SimpleNamespace(sec=int(getattr(ts, "sec", 0) or 0), nanosec=0)


def _bytes(value: Any) -> Any:
    """A ``bytes`` field as ROS's ``uint8[]`` (a uint8 array): Protobuf's bytes wrapped without
    a copy, JSON's base64 text decoded; ROS arrays as they are."""
    if isinstance(value, str):
        value = base64.b64decode(value)
    if isinstance(value, bytes | bytearray | memoryview):
        return np.frombuffer(value, np.uint8)
    return value


def _floats(msg: Any, name: str) -> list[float]:
    """``K`` in Protobuf, JSON and ROS 1; ``k`` in ROS 2."""
    value = getattr(msg, name, None)
    if value is None:
        value = getattr(msg, name.lower(), [])
    return [float(v) for v in value]


# Foxglove's PackedElementField numeric types -> sensor_msgs/PointField datatypes
_POINT_TYPES = {1: 2, 2: 1, 3: 4, 4: 3, 5: 6, 6: 5, 7: 7, 8: 8}  # UINT8 -> PointField.UINT8 ...


def _pose_matrix(pose: Any) -> np.ndarray | None:
    """4x4 of a Foxglove ``Pose`` (the points' origin in ``frame_id``); None for identity
    (also an unset pose, whose orientation is all zero)."""
    from frontdiag.io.decode import pose_matrix

    if pose is None:
        return None
    p, q = getattr(pose, "position", None), getattr(pose, "orientation", None)
    t = [float(getattr(p, a, 0.0) or 0.0) for a in "xyz"] if p is not None else [0.0] * 3
    quat = ([float(getattr(q, a, 0.0) or 0.0) for a in "xyzw"] if q is not None
            else [0.0, 0.0, 0.0, 1.0])
    T = pose_matrix(t, quat)
    return None if np.array_equal(T, np.eye(4)) else T


def _point_cloud(msg: Any, header: SimpleNamespace) -> SimpleNamespace:
    """A ``PointCloud2`` of one row; ``pose_T`` (4x4, or None for the identity) is where the
    points' origin sits in ``frame_id``, applied after decoding (:func:`apply_pose`)."""
    stride = int(msg.point_stride)
    data = _bytes(msg.data)
    fields = [SimpleNamespace(name=str(f.name), offset=int(f.offset),
                              datatype=_POINT_TYPES.get(int(f.type), 0), count=1)
              for f in msg.fields]
    width = len(data) // stride if stride > 0 else 0
    return SimpleNamespace(header=header, height=1, width=width, fields=fields,
                           is_bigendian=False, point_step=stride, row_step=width * stride,
                           data=data, is_dense=True,
                           pose_T=_pose_matrix(getattr(msg, "pose", None)))


def _laser_scan(msg: Any, header: SimpleNamespace) -> SimpleNamespace:
    """A ``LaserScan``: Foxglove gives the first and last angles, ROS the first and the step.
    ``pose_T`` as for a point cloud; one that tilts the scan out of its plane is refused, since
    frontdiag registers a planar scan in its plane."""
    ranges = [float(r) for r in msg.ranges]
    start, end = float(msg.start_angle), float(msg.end_angle)
    T = _pose_matrix(getattr(msg, "pose", None))
    if T is not None and abs(T[2, 2] - 1.0) > 1e-6:
        raise ValueError("its pose tilts the scan out of its plane; frontdiag registers planar "
                         "scans in their plane")
    n = len(ranges)
    inc = (end - start) / (n - 1) if n > 1 else 0.0
    # Foxglove has no range limits: a zero range (no return) is dropped, as PointCloud2
    # decoding drops points at the origin
    return SimpleNamespace(header=header, angle_min=start, angle_max=end, angle_increment=inc,
                           time_increment=0.0, scan_time=0.0, range_min=1e-9,
                           range_max=float("inf"), ranges=ranges,
                           intensities=[float(v) for v in getattr(msg, "intensities", [])],
                           pose_T=T)


def apply_pose(xyz: np.ndarray, T: np.ndarray | None) -> np.ndarray:
    """Points in the frame ``T`` places them in (Foxglove's ``pose`` of a cloud or scan)."""
    if T is None or len(xyz) == 0:
        return xyz
    return np.asarray(xyz @ T[:3, :3].T + T[:3, 3], dtype=xyz.dtype)
