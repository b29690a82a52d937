"""Decode one selected message into a record the frontends take (``CameraFrame``, ``LidarScan``).

Errors name the topic and field and are counted by the caller's stream (``skip``); a message
the deserialiser cannot parse becomes a :class:`~frontdiag.errors.DecodeError` too.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any, Protocol

import numpy as np

from frontdiag.errors import DecodeError
from frontdiag.io import foxglove
from frontdiag.io.images import GrayConverter
from frontdiag.io.readers import RawMessage, Recording
from frontdiag.records import CameraFrame, LidarScan


class StampSink(Protocol):
    """What decoding reports to: the message's position, its stamp, and skipped messages."""

    index: int
    decoders: dict[str, Any]  # per-topic decoder state a message type needs (Velodyne)

    def stamp(self, msg: Any, log_ns: int) -> int: ...

    def skip(self, exc: Exception) -> None: ...


def header_stamp_ns(msg: Any) -> int:
    st = msg.header.stamp
    return int(st.sec) * 1_000_000_000 + int(st.nanosec)


def stamp_ns(msg: Any, log_ns: int) -> int:
    """Header stamp in integer nanoseconds, or the log time when the stamp is zero."""
    st = msg.header.stamp
    sec = int(getattr(st, "sec", getattr(st, "secs", 0)))
    nsec = int(getattr(st, "nanosec", getattr(st, "nsecs", 0)))
    t = sec * 1_000_000_000 + nsec
    return t if t > 0 else int(log_ns)


def odometry_pose(msg: Any) -> np.ndarray:
    """4x4 pose from nav_msgs/Odometry, geometry_msgs/PoseWithCovarianceStamped (both hold
    ``pose.pose``) or geometry_msgs/PoseStamped (``pose``)."""
    pose = msg.pose
    pose = getattr(pose, "pose", pose)
    p, q = pose.position, pose.orientation
    return pose_matrix((p.x, p.y, p.z), (q.x, q.y, q.z, q.w))


def pose_matrix(position: Any, quat_xyzw: Any) -> np.ndarray:
    """4x4 of a position and a quaternion (x, y, z, w), normalised here; an all-zero
    quaternion (an unset orientation) is the identity."""
    x, y, z, w = (float(v) for v in quat_xyzw)
    n = x * x + y * y + z * z + w * w
    s = 2.0 / n if n > 0 else 0.0
    R = np.array([
        [1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
        [s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w)],
        [s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y)],
    ])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = [float(v) for v in position]
    return T


def decode_camera(rec: Recording, raw: RawMessage, stream: StampSink,
                  conv: GrayConverter, repeats: Callable[[np.ndarray, Any, int], bool] | None
                  = None) -> CameraFrame | None:
    """The message's grey picture, or None where it was skipped (undecodable, reported to
    ``stream``; or a repeat of the previous picture, which ``repeats`` counts)."""
    t0 = time.perf_counter()
    try:
        msg = rec.deserialize(raw)
        gray, encoding = conv(msg, raw.msgtype)
        if repeats is not None and repeats(gray, msg, raw.log_ns):
            return None
        t_ns = stream.stamp(msg, raw.log_ns)
    except DecodeError as exc:
        stream.skip(exc)
        return None
    except Exception as exc:  # a message the deserialiser cannot parse
        stream.skip(DecodeError(raw.topic, "message", f"undecodable ({exc})"))
        return None
    ms = (time.perf_counter() - t0) * 1e3
    header = getattr(msg, "header", None)
    return CameraFrame(index=stream.index, t_ns=t_ns, log_ns=raw.log_ns, topic=raw.topic,
                       gray=gray, encoding=encoding, ms_decode=ms,
                       frame_id=str(getattr(header, "frame_id", "") or ""))


def decode_lidar(rec: Recording, raw: RawMessage, stream: StampSink) -> LidarScan | None:
    from frontdiag.lidar.decode import decode_laserscan, decode_pointcloud2
    from frontdiag.lidar.livox import LIVOX_TYPES, decode_livox, header_stamp
    from frontdiag.lidar.velodyne import VELODYNE_TYPES, VelodyneDecoder, read_scan

    t0 = time.perf_counter()
    try:
        if raw.msgtype in VELODYNE_TYPES:  # raw packets: the decoder keeps the sensor model
            enc = next((t.encoding for t in rec.topics if t.topic == raw.topic), "cdr")
            msg = read_scan(raw.data, enc or "cdr", raw.topic)
            t_ns = stream.stamp(msg, raw.log_ns)
            dec = stream.decoders.get("velodyne")
            if dec is None:
                dec = stream.decoders["velodyne"] = VelodyneDecoder(raw.topic)
            scan = dec(msg, index=stream.index, log_ns=raw.log_ns, t_ns=t_ns)
            return replace(scan, ms_decode=(time.perf_counter() - t0) * 1e3)
        if raw.msgtype in LIVOX_TYPES:  # read from the bytes: 30-40 ms a scan saved
            enc = next((t.encoding for t in rec.topics if t.topic == raw.topic), "cdr")
            scan = decode_livox(raw.data, enc or "cdr", topic=raw.topic, index=stream.index,
                                log_ns=raw.log_ns)
            t_ns = stream.stamp(header_stamp(raw.data, enc or "cdr"), raw.log_ns)
            return replace(scan, t_ns=t_ns, ms_decode=(time.perf_counter() - t0) * 1e3)
        msg = rec.deserialize(raw)
        t_ns = stream.stamp(msg, raw.log_ns)
        kind = foxglove.ros_type(raw.msgtype)
        fn = decode_laserscan if kind.endswith("LaserScan") else decode_pointcloud2
        scan = fn(msg, topic=raw.topic, index=stream.index, log_ns=raw.log_ns)
        pose = getattr(msg, "pose_T", None)  # Foxglove's: where the points' origin sits
        if pose is not None:
            scan = replace(scan, xyz=foxglove.apply_pose(scan.xyz, pose))
    except DecodeError as exc:
        stream.skip(exc)
        return None
    except Exception as exc:
        stream.skip(DecodeError(raw.topic, "message", f"undecodable ({exc})"))
        return None
    # one stamp rule for every sensor: header stamp, log time when the stamp is zero
    return replace(scan, t_ns=t_ns, ms_decode=(time.perf_counter() - t0) * 1e3)
