"""Velodyne ``VelodyneScan`` (raw packets, as the ROS velodyne driver records them) -> :class:`LidarScan`.

Many robots record the driver's raw packets rather than the point cloud made from them (a
tenth of the size): ``velodyne_msgs/VelodyneScan`` holds one revolution as 1206-byte UDP
packets, each stamped. Turning them into points needs the sensor's beam geometry and firing
timing, which the velodyne-decoder package (Valgur, after the ROS driver) carries for every
Velodyne model and reads the model from the packets' factory bytes: VLP-16, Puck Hi-Res, Puck
Lite, VLP-32A/B/C, HDL-32E, HDL-64E S1-S3, VLS-128 and Alpha Prime. The points come in the
driver's frame (x forward, y left, z up), with each point's time, intensity and ring.

``time_rel_s`` is each point's firing time relative to the scan's header stamp: the decoder
gives it relative to the packet it stamps the scan with, whose stamp is read from the message.
"""

from __future__ import annotations

import struct
import time
from types import SimpleNamespace
from typing import Any

import numpy as np

from frontdiag.errors import DecodeError
from frontdiag.records import LidarScan

VELODYNE_TYPES: tuple[str, ...] = ("velodyne_msgs/msg/VelodyneScan",)
PACKET_BYTES = 1206  # every Velodyne data packet's UDP payload

PACKET_MSG_ROS1 = "time stamp\nuint8[1206] data\n"
PACKET_MSG_ROS2 = "builtin_interfaces/Time stamp\nuint8[1206] data\n"
SCAN_MSG_ROS1 = "Header header\nvelodyne_msgs/msg/VelodynePacket[] packets\n"
SCAN_MSG_ROS2 = "std_msgs/Header header\nvelodyne_msgs/msg/VelodynePacket[] packets\n"


def register_types(ts: Any, ros_version: int) -> None:
    """Teach a rosbags typestore the velodyne_msgs messages (for bags whose files carry no
    message definitions)."""
    from rosbags.typesys import get_types_from_msg

    if "velodyne_msgs/msg/VelodyneScan" in ts.types:
        return
    types: dict[str, Any] = {}
    types.update(get_types_from_msg(PACKET_MSG_ROS1 if ros_version == 1 else PACKET_MSG_ROS2,
                                    "velodyne_msgs/msg/VelodynePacket"))
    types.update(get_types_from_msg(SCAN_MSG_ROS1 if ros_version == 1 else SCAN_MSG_ROS2,
                                    "velodyne_msgs/msg/VelodyneScan"))
    ts.register(types)


def read_scan(data: bytes | memoryview, encoding: str, topic: str = "") -> SimpleNamespace:
    """A serialised VelodyneScan (``encoding`` ``ros1`` or ``cdr``) as an object with
    ``header.stamp``, ``header.frame_id`` and ``packets`` (each ``stamp``, ``data`` as bytes),
    read from the bytes: deserialising a scan's 76-180 packets into message objects took
    17 ms a scan (rosbags), longer than decoding them.

    ROS 1 packs everything: a packet is its stamp (two uint32) and 1206 bytes. CDR aligns each
    field to its size from the end of the 4-byte encapsulation header, so every packet starts
    on a multiple of 4 (1214 bytes and 2 of padding). Checked against rosbags in the tests."""
    buf = bytes(data)
    try:
        if encoding == "ros1":
            e, body, pos = "<", 0, 4  # after the header's seq
            sec, nsec, n_id = struct.unpack_from("<III", buf, pos)
            frame_id = buf[pos + 12:pos + 12 + n_id].decode(errors="replace")
            pos += 12 + n_id
        elif encoding == "cdr":
            e, body = (">" if buf[1] == 0 else "<"), 4  # 0x0000 CDR_BE, 0x0001 CDR_LE
            sec, nsec, n_id = struct.unpack_from(e + "iII", buf, body)
            frame_id = buf[body + 12:body + 12 + max(n_id - 1, 0)].decode(errors="replace")
            pos = body + 12 + n_id
        else:
            raise ValueError(f"message encoding {encoding!r} (cdr or ros1)")

        def align(p: int) -> int:
            return p if encoding == "ros1" else body + -(-(p - body) // 4) * 4

        pos = align(pos)
        n, = struct.unpack_from(e + "I", buf, pos)
        pos += 4
        packets = []
        for _ in range(n):
            pos = align(pos)
            p_sec, p_nsec = struct.unpack_from(e + ("II" if encoding == "ros1" else "iI"),
                                               buf, pos)
            pos += 8
            chunk = buf[pos:pos + PACKET_BYTES]
            if len(chunk) < PACKET_BYTES:
                raise DecodeError(topic, "packets", f"{n} packets need more than the "
                                                    f"message's {len(buf)} bytes")
            packets.append(SimpleNamespace(stamp=SimpleNamespace(sec=p_sec, nanosec=p_nsec),
                                           data=chunk))
            pos += PACKET_BYTES
    except struct.error as exc:
        raise DecodeError(topic, "header", f"message too short ({exc})") from None
    return SimpleNamespace(header=SimpleNamespace(stamp=SimpleNamespace(sec=sec, nanosec=nsec),
                                                  frame_id=frame_id), packets=packets)


def _seconds(stamp: Any) -> float:
    sec = int(getattr(stamp, "sec", getattr(stamp, "secs", 0)))
    nsec = int(getattr(stamp, "nanosec", getattr(stamp, "nsecs", 0)))
    return sec + nsec * 1e-9


class VelodyneDecoder:
    """One topic's decoder (the model is read from the first packets and kept)."""

    def __init__(self, topic: str) -> None:
        import velodyne_decoder as vd

        self.topic = topic
        self._vd = vd
        self._dec = vd.ScanDecoder(vd.Config())

    @property
    def model(self) -> str:
        """The model the packets named (``VLP16``, ``HDL32E`` ...; empty before any)."""
        m = self._dec.model_id
        return "" if m is None else str(getattr(m, "name", m))

    @property
    def return_mode(self) -> str:
        """``strongest``, ``last`` or ``dual`` (empty before any packet)."""
        m = self._dec.return_mode
        return "" if m is None else str(getattr(m, "name", m)).lower()

    def __call__(self, msg: Any, *, index: int, log_ns: int, t_ns: int) -> LidarScan:
        start = time.perf_counter()
        vd = self._vd
        packets = vd.PacketVector()
        for p in msg.packets:
            # bytes: the binding copies them 9x faster than a numpy array
            data = p.data if isinstance(p.data, bytes) else np.asarray(p.data, np.uint8).tobytes()
            if len(data) != PACKET_BYTES:
                raise DecodeError(self.topic, "packets.data",
                                  f"a packet of {len(data)} bytes (Velodyne's are "
                                  f"{PACKET_BYTES})")
            packets.append(vd.VelodynePacket(_seconds(p.stamp), data))
        n_packets = len(packets)
        if n_packets == 0:
            pts = np.zeros((0, 8), np.float32)
            stamp_s = t_ns * 1e-9
        else:
            try:
                stamp, pts = self._dec.decode(packets)
            except Exception as exc:  # the decoder's own errors (unknown model, calibration)
                raise DecodeError(self.topic, "packets", f"not decodable as Velodyne packets "
                                                         f"({exc})") from None
            stamp_s = float(stamp.host)
            pts = np.asarray(pts, np.float32).reshape(-1, 8)
        xyz = pts[:, :3].astype(np.float64)
        keep = np.isfinite(xyz).all(axis=1) & (xyz != 0).any(axis=1)
        # the decoder's times are relative to its stamp (a packet's); the row's are relative
        # to the message's header stamp
        offset = stamp_s - t_ns * 1e-9
        return LidarScan(index=index, t_ns=t_ns, log_ns=int(log_ns), topic=self.topic,
                         xyz=xyz[keep],
                         time_rel_s=pts[keep, 4].astype(np.float64) + offset,
                         intensity=pts[keep, 3].astype(np.float32),
                         ring=pts[keep, 6].astype(np.int32),
                         frame_id=str(msg.header.frame_id), n_raw=len(pts),
                         ms_decode=(time.perf_counter() - start) * 1e3)
