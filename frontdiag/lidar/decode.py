"""Decode ``sensor_msgs/PointCloud2`` and ``sensor_msgs/LaserScan`` into :class:`LidarScan`.

PointCloud2 is read with one numpy structured dtype built from the message's ``PointField``
offsets (no per-point Python), for any layout: float32/float64 coordinates, padding, organised
clouds whose ``row_step`` exceeds ``width * point_step``, either byte order.

Rows whose x, y or z is NaN/inf are dropped together with their time, intensity and ring. Rows at
exactly (0, 0, 0) are dropped too: several drivers (Ouster, Hesai, Livox) mark "no return" that way
in organised clouds, and a pile of points at the sensor origin would anchor registration.

Per-point time
--------------
The first field named ``t``, ``time``, ``timestamp``, ``time_stamp``, ``offset_time`` or
``time_offset`` is used. Its unit and reference are detected from the dtype and from the median
value ``m`` against the header stamp ``H`` (the scan's ``t_ns``):

1. Unit by dtype: a floating-point field is tried as seconds first, then as nanoseconds (only if
   that makes the sweep last at least 0.1 ms); an integer field only as nanoseconds (Ouster ``t``
   uint32, Livox ``offset_time``). PointField has no 64-bit integer type, so absolute
   nanosecond stamps arrive as float64.
2. Reference by magnitude: for the unit being tried, *relative* implies a median offset ``|m|``
   from the stamp and *absolute* implies ``|m - H|``; the smaller wins, provided it is at most
   10 s. A sweep lasts a few hundred milliseconds, so a relative offset (Velodyne ``time``, which is
   negative when the stamp marks the sweep end) and an absolute stamp (Hesai ``timestamp``, float64
   seconds) cannot be confused, even in a simulated log whose stamps start near zero.
3. If no unit fits, the times are absolute on another clock (the sensor's, not the recorder's):
   they are taken relative to the earliest point, which assumes the stamp marks the sweep start.

The result is ``time_rel_s``: seconds relative to ``t_ns`` (float64).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from frontdiag.errors import DecodeError
from frontdiag.io.decode import stamp_ns
from frontdiag.records import LidarScan

# sensor_msgs/PointField datatype -> numpy kind
_PF_TYPES: dict[int, str] = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}

TIME_FIELDS: tuple[str, ...] = ("t", "time", "timestamp", "time_stamp", "offset_time",
                                "time_offset")
INTENSITY_FIELDS: tuple[str, ...] = ("intensity", "i", "reflectivity")
RING_FIELDS: tuple[str, ...] = ("ring", "line", "channel")

_ABS_WINDOW_S = 10.0
_MIN_SPAN_S = 1e-4


def _pick(names: dict[str, Any], candidates: tuple[str, ...]) -> str | None:
    for c in candidates:
        if c in names:
            return names[c]
    return None


def detect_time_rel_s(values: np.ndarray, t_ns: int) -> tuple[np.ndarray, str]:
    """Per-point times (any unit, any reference) -> seconds relative to ``t_ns``, and the rule
    that matched (see the module docstring)."""
    if values.size == 0:
        return np.zeros(0), "empty"
    is_float = values.dtype.kind == "f"
    v64 = values.astype(np.float64)
    med = float(np.median(v64))
    t_s = t_ns * 1e-9
    # (unit, reference) candidates in order of preference for this dtype; the median offset
    # from the stamp each one implies, in seconds
    units = ("s", "ns") if is_float else ("ns",)
    for unit in units:
        scale = 1.0 if unit == "s" else 1e-9
        rel_off = abs(med * scale)
        abs_off = abs(med - t_s) if unit == "s" else abs(med - t_ns) * 1e-9
        best = min(("relative", rel_off), ("absolute", abs_off), key=lambda c: c[1])
        if best[1] > _ABS_WINDOW_S:
            continue
        if unit == "ns" and is_float and (float(v64.max()) - float(v64.min())) * 1e-9 < _MIN_SPAN_S:
            continue  # seconds on another clock, not a sweep of a few nanoseconds
        if best[0] == "relative":
            return v64 * scale, f"relative_{unit}"
        if unit == "s":  # subtract whole seconds first to keep float64 precision
            return (v64 - t_ns // 1_000_000_000) - (t_ns % 1_000_000_000) * 1e-9, "absolute_s"
        if values.dtype.kind in "iu":
            return (values.astype(np.int64) - np.int64(t_ns)).astype(np.float64) * 1e-9, \
                "absolute_ns"
        return (v64 - float(t_ns)) * 1e-9, "absolute_ns"
    if is_float and abs(med) < 1e11:
        return v64 - float(np.min(v64)), "other_clock_s"
    iv = values.astype(np.int64)
    return (iv - iv.min()).astype(np.float64) * 1e-9, "other_clock_ns"


def _point_dtype(msg: Any, topic: str) -> tuple[np.dtype, dict[str, str]]:
    order = ">" if bool(msg.is_bigendian) else "<"
    point_step = int(msg.point_step)
    if point_step <= 0:
        raise DecodeError(topic, "point_step", f"must be positive, got {point_step}")
    names: list[str] = []
    formats: list[Any] = []
    offsets: list[int] = []
    lower: dict[str, str] = {}
    for f in msg.fields:
        name = str(f.name)
        key = name.lower()
        wanted = key in ("x", "y", "z") or key in TIME_FIELDS or key in INTENSITY_FIELDS \
            or key in RING_FIELDS
        if not wanted or key in lower:
            continue
        kind = _PF_TYPES.get(int(f.datatype))
        if kind is None:
            raise DecodeError(topic, name, f"unknown PointField datatype {int(f.datatype)}")
        count = max(int(getattr(f, "count", 1) or 1), 1)
        dt = np.dtype(order + kind if kind[1] != "1" else kind)
        off = int(f.offset)
        if off < 0 or off + dt.itemsize * count > point_step:
            raise DecodeError(topic, name, f"offset {off} + size {dt.itemsize * count} exceeds "
                                           f"point_step {point_step}")
        names.append(name)
        formats.append(dt if count == 1 else (dt, (count,)))
        offsets.append(off)
        lower[key] = name
    for axis in ("x", "y", "z"):
        if axis not in lower:
            raise DecodeError(topic, axis, "PointCloud2 has no such field")
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets,
                      "itemsize": point_step})
    return dtype, lower


def _first_component(a: np.ndarray) -> np.ndarray:
    return a[..., 0] if a.ndim > 1 else a


PLANAR_Z_SPREAD_M = 1e-6
"""A PointCloud2 whose points all share one z (to this spread) is a 2D scan and registered as
one (SE(2)): read as 3D it has no vertical structure, and too few points survive the 3D voxel
grid and point-count minimum to register at all."""


def decode_pointcloud2(msg: Any, *, topic: str, index: int, log_ns: int) -> LidarScan:
    """A rosbags ``sensor_msgs/PointCloud2`` (ROS 1 or ROS 2) -> :class:`LidarScan`.

    Raises :class:`DecodeError` for a malformed message (missing x/y/z, fields beyond the point,
    data shorter than the declared size).
    """
    start = time.perf_counter()
    t_ns = stamp_ns(msg, log_ns)
    dtype, names = _point_dtype(msg, topic)
    height, width = int(msg.height), int(msg.width)
    point_step, row_step = int(msg.point_step), int(msg.row_step)
    raw = msg.data
    data = np.frombuffer(raw, dtype=np.uint8) if isinstance(raw, bytes | bytearray | memoryview) \
        else np.asarray(raw, dtype=np.uint8).reshape(-1)
    n_raw = height * width
    if n_raw == 0:
        xyz = np.zeros((0, 3))
        return LidarScan(index=index, t_ns=t_ns, log_ns=int(log_ns), topic=topic, xyz=xyz,
                         time_rel_s=None, frame_id=str(msg.header.frame_id), n_raw=0,
                         ms_decode=(time.perf_counter() - start) * 1e3)
    if row_step < width * point_step:
        if height == 1:
            row_step = width * point_step  # some writers leave row_step 0 on unorganised clouds
        else:
            raise DecodeError(topic, "row_step", f"{row_step} < width * point_step "
                                                 f"({width} * {point_step})")
    need = row_step * (height - 1) + width * point_step
    if data.size < need:
        raise DecodeError(topic, "data", f"{data.size} bytes, the layout needs {need}")
    pts = np.ndarray(shape=(height, width), dtype=dtype, buffer=data,
                     strides=(row_step, point_step)).reshape(-1)
    x = _first_component(pts[names["x"]]).astype(np.float64)
    y = _first_component(pts[names["y"]]).astype(np.float64)
    z = _first_component(pts[names["z"]]).astype(np.float64)
    keep = np.isfinite(x) & np.isfinite(y) & np.isfinite(z) & ((x != 0) | (y != 0) | (z != 0))
    xyz = np.stack([x[keep], y[keep], z[keep]], axis=1)

    tname = _pick(names, TIME_FIELDS)
    time_rel: np.ndarray | None = None
    if tname is not None:
        tv = _first_component(pts[tname])[keep]
        tv = tv.astype(tv.dtype.newbyteorder("="))
        time_rel, _rule = detect_time_rel_s(tv, t_ns)
        if not np.all(np.isfinite(time_rel)):
            time_rel = None
    iname = _pick(names, INTENSITY_FIELDS)
    intensity = None if iname is None else \
        _first_component(pts[iname])[keep].astype(np.float32)
    rname = _pick(names, RING_FIELDS)
    ring = None if rname is None else _first_component(pts[rname])[keep].astype(np.int32)
    # a 2D scanner published as PointCloud2 (laser_geometry's projection): every z the same
    planar = bool(len(xyz)) and float(np.ptp(xyz[:, 2])) <= PLANAR_Z_SPREAD_M
    return LidarScan(index=index, t_ns=t_ns, log_ns=int(log_ns), topic=topic, xyz=xyz,
                     time_rel_s=time_rel, intensity=intensity, ring=ring, planar=planar,
                     frame_id=str(msg.header.frame_id), n_raw=n_raw,
                     ms_decode=(time.perf_counter() - start) * 1e3)


def decode_laserscan(msg: Any, *, topic: str, index: int, log_ns: int) -> LidarScan:
    """A rosbags ``sensor_msgs/LaserScan`` -> planar :class:`LidarScan` (z = 0).

    Ranges outside [range_min, range_max] or non-finite are dropped. Point ``i`` was measured
    ``i * time_increment`` after the stamp (the ROS convention: the stamp is the first ray).
    """
    start = time.perf_counter()
    t_ns = stamp_ns(msg, log_ns)
    ranges = np.asarray(msg.ranges, dtype=np.float64).reshape(-1)
    n = ranges.size
    inc = float(msg.angle_increment)
    if n and not np.isfinite(inc):
        raise DecodeError(topic, "angle_increment", f"not finite ({inc})")
    ang = float(msg.angle_min) + inc * np.arange(n)
    rmin, rmax = float(msg.range_min), float(msg.range_max)
    keep = np.isfinite(ranges) & (ranges >= rmin) & (ranges <= rmax)
    r = ranges[keep]
    xyz = np.stack([r * np.cos(ang[keep]), r * np.sin(ang[keep]), np.zeros_like(r)], axis=1)
    t_inc = float(msg.time_increment)
    time_rel = (t_inc * np.arange(n))[keep] if t_inc != 0 and np.isfinite(t_inc) else None
    inten = np.asarray(msg.intensities, dtype=np.float32).reshape(-1)
    intensity = inten[keep] if inten.size == n and n else None
    return LidarScan(index=index, t_ns=t_ns, log_ns=int(log_ns), topic=topic, xyz=xyz,
                     time_rel_s=time_rel, intensity=intensity, planar=True,
                     frame_id=str(msg.header.frame_id), n_raw=n,
                     ms_decode=(time.perf_counter() - start) * 1e3)
