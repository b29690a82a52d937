"""Livox ``CustomMsg`` (livox_ros_driver, livox_ros_driver2, livox_interfaces) -> :class:`LidarScan`.

Livox drivers publish their own message, not ``sensor_msgs/PointCloud2``, and LIO systems
(FAST-LIO, Point-LIO, LIO-Livox) record it, because it carries each point's time::

    Header header        # stamp: usually the scan's timebase
    uint64 timebase      # ns, the time the first point was measured
    uint32 point_num
    uint8 lidar_id
    uint8[3] rsvd
    CustomPoint[] points # uint32 offset_time (ns after timebase), float32 x, y, z,
                         # uint8 reflectivity, tag, line

A scan holds 10,000-100,000 points; deserialising them into one Python object each costs
30-40 ms a scan, so the points are read from the message bytes with one numpy dtype. Their place
follows from the fields before them: in ROS 1 serialisation everything is packed (19 bytes a
point); in CDR (ROS 2) every field is aligned to its own size from the start of the payload, so
a point takes 20 bytes (19 and one byte of padding before the next point's uint32) and the
uint64 ``timebase`` starts on a multiple of 8. Both are checked against rosbags' own
deserialisation in the tests.

Points at exactly (0, 0, 0) (no return) and non-finite ones are dropped, and so are the later
returns of a multi-return pulse: ``tag`` bits 4-5 other than 0x00 or 0x10, the returns FAST-LIO's
preprocessing keeps (Xu et al. 2022), so that one surface does not count twice. ``time_rel_s``
is ``timebase + offset_time`` relative to the scan's stamp.
"""

from __future__ import annotations

import struct
import time
from typing import Any

import numpy as np

from frontdiag.errors import DecodeError
from frontdiag.records import LidarScan

LIVOX_TYPES: tuple[str, ...] = ("livox_ros_driver/msg/CustomMsg",
                                "livox_ros_driver2/msg/CustomMsg",
                                "livox_interfaces/msg/CustomMsg")

POINT_MSG = """uint32 offset_time
float32 x
float32 y
float32 z
uint8 reflectivity
uint8 tag
uint8 line
"""

SCAN_MSG_ROS1 = """Header header
uint64 timebase
uint32 point_num
uint8 lidar_id
uint8[3] rsvd
CustomPoint[] points
"""

SCAN_MSG_ROS2 = SCAN_MSG_ROS1.replace("Header header", "std_msgs/Header header")


def register_types(ts: Any, ros_version: int) -> None:
    """Teach a rosbags typestore the Livox messages (so bags whose files carry no message
    definitions can still be opened and listed)."""
    from rosbags.typesys import get_types_from_msg

    types: dict[str, Any] = {}
    for pkg in ("livox_ros_driver", "livox_ros_driver2", "livox_interfaces"):
        if f"{pkg}/msg/CustomMsg" in ts.types:
            continue
        point = f"{pkg}/msg/CustomPoint"
        scan = (SCAN_MSG_ROS1 if ros_version == 1 else SCAN_MSG_ROS2).replace(
            "CustomPoint[]", f"{point}[]")
        types.update(get_types_from_msg(POINT_MSG, point))
        types.update(get_types_from_msg(scan, f"{pkg}/msg/CustomMsg"))
    if types:
        ts.register(types)


def _points_dtype(big_endian: bool) -> np.dtype:
    """One point's 19 bytes; the stride between points (19 or 20) is the array's."""
    e = ">" if big_endian else "<"
    return np.dtype({"names": ["offset_time", "x", "y", "z", "reflectivity", "tag", "line"],
                     "formats": [e + "u4", e + "f4", e + "f4", e + "f4", "u1", "u1", "u1"],
                     "offsets": [0, 4, 8, 12, 16, 17, 18], "itemsize": 19})


def _layout(data: bytes, encoding: str
            ) -> tuple[int, int, str, int, int, int, int, bool]:
    """(stamp sec, stamp nsec, frame_id, timebase, first point's offset, point count, stride,
    big endian) of a serialised CustomMsg."""
    if encoding == "ros1":
        sec, nsec, n_id = struct.unpack_from("<III", data, 4)
        frame_id = data[16:16 + n_id].decode(errors="replace")
        pos = 16 + n_id
        timebase, = struct.unpack_from("<Q", data, pos)
        pos += 8 + 4 + 1 + 3
        n, = struct.unpack_from("<I", data, pos)
        return sec, nsec, frame_id, timebase, pos + 4, n, 19, False
    if encoding != "cdr":
        raise ValueError(f"message encoding {encoding!r} (cdr or ros1)")
    big = data[1] == 0  # encapsulation: 0x0000 CDR_BE, 0x0001 CDR_LE
    e = ">" if big else "<"
    body = 4  # CDR aligns from the end of the 4-byte encapsulation header

    def align(p: int, a: int) -> int:
        return body + -(-(p - body) // a) * a

    sec, nsec, n_id = struct.unpack_from(e + "iII", data, body)
    frame_id = data[body + 12:body + 12 + max(n_id - 1, 0)].decode(errors="replace")  # NUL
    pos = align(body + 12 + n_id, 8)
    timebase, = struct.unpack_from(e + "Q", data, pos)
    pos = align(pos + 8 + 4 + 1 + 3, 4)
    n, = struct.unpack_from(e + "I", data, pos)
    return sec, nsec, frame_id, timebase, pos + 4, n, 20, big


def header_stamp(data: bytes | memoryview, encoding: str) -> Any:
    """The message's header stamp as an object with ``header.stamp.sec`` / ``.nanosec`` (what
    the stamp rules read from deserialised messages)."""
    from types import SimpleNamespace

    sec, nsec = _layout(bytes(data), encoding)[:2]
    return SimpleNamespace(header=SimpleNamespace(stamp=SimpleNamespace(sec=sec, nanosec=nsec)))


def livox_point_count(data: bytes | memoryview, encoding: str) -> int:
    """``point_num``'s array length, read from the bytes."""
    return _layout(bytes(data), encoding)[5]


def decode_livox(data: bytes | memoryview, encoding: str, *, topic: str, index: int,
                 log_ns: int) -> LidarScan:
    """A serialised Livox CustomMsg (``encoding`` ``cdr`` or ``ros1``) -> :class:`LidarScan`.

    Raises :class:`DecodeError` naming the field when the bytes are shorter than the point
    count says.
    """
    start = time.perf_counter()
    buf = bytes(data)
    try:
        sec, nsec, frame_id, timebase, first, n, stride, big = _layout(buf, encoding)
    except struct.error as exc:
        raise DecodeError(topic, "header", f"message too short ({exc})") from None
    need = first + (n - 1) * stride + 19 if n else first
    if len(buf) < need:
        raise DecodeError(topic, "points", f"{n} points need {need} bytes, the message has "
                                           f"{len(buf)}")
    t_ns = sec * 1_000_000_000 + nsec
    t_ns = t_ns if t_ns > 0 else int(log_ns)
    pts = np.ndarray(shape=(n,), dtype=_points_dtype(big), buffer=buf, offset=first,
                     strides=(stride,))
    x, y, z = (pts[k].astype(np.float64) for k in ("x", "y", "z"))
    ret = pts["tag"] & 0x30  # bits 4-5: which return of a multi-return pulse
    keep = np.isfinite(x) & np.isfinite(y) & np.isfinite(z) & ((x != 0) | (y != 0) | (z != 0)) \
        & ((ret == 0x00) | (ret == 0x10))
    xyz = np.stack([x[keep], y[keep], z[keep]], axis=1)
    t_rel = ((timebase - t_ns) + pts["offset_time"][keep].astype(np.float64)) * 1e-9
    return LidarScan(index=index, t_ns=t_ns, log_ns=int(log_ns), topic=topic, xyz=xyz,
                     time_rel_s=t_rel if len(t_rel) else None,
                     intensity=pts["reflectivity"][keep].astype(np.float32),
                     ring=pts["line"][keep].astype(np.int32), planar=False,
                     frame_id=frame_id, n_raw=n, ms_decode=(time.perf_counter() - start) * 1e3)
