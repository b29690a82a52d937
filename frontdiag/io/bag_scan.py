"""Sequential reader for ROS 1 bags whose index is missing or damaged (a recorder killed mid-run).

rosbags needs the index at the end of the file; a bag cut short has none. This reader walks the
records from the start (bag format v2.0: chunks holding connection and message-data records) and
stops at the first damaged record, so the messages before the damage can still be analysed.
"""

from __future__ import annotations

import bz2
import struct
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any, BinaryIO

from frontdiag.errors import RecordingError
from frontdiag.io.readers import RawMessage, ReadFault, TopicInfo, _Base
from frontdiag.io.writer import normalise_msgtype, typestore

OP_MSG_DATA, OP_BAG_HEADER, OP_CHUNK, OP_CONNECTION = 0x02, 0x03, 0x05, 0x07
MAGIC = b"#ROSBAG V2.0\n"


def _fields(buf: bytes) -> dict[str, bytes]:
    out: dict[str, bytes] = {}
    pos = 0
    while pos + 4 <= len(buf):
        (n,) = struct.unpack_from("<I", buf, pos)
        pos += 4
        if n == 0 or pos + n > len(buf):
            raise ValueError("bad header field length")
        name, _, value = buf[pos:pos + n].partition(b"=")
        out[name.decode()] = value
        pos += n
    return out


def _records(data: bytes) -> Iterator[tuple[dict[str, bytes], bytes]]:
    pos = 0
    while pos < len(data):
        if pos + 4 > len(data):
            raise ValueError("record header length cut short")
        (hlen,) = struct.unpack_from("<I", data, pos)
        hdr = _fields(data[pos + 4:pos + 4 + hlen])
        pos += 4 + hlen
        if pos + 4 > len(data):
            raise ValueError("record data length cut short")
        (dlen,) = struct.unpack_from("<I", data, pos)
        if pos + 4 + dlen > len(data):
            raise ValueError("record data cut short")
        yield hdr, data[pos + 4:pos + 4 + dlen]
        pos += 4 + dlen


def _read_record(fh: BinaryIO) -> tuple[dict[str, bytes], bytes] | None:
    head = fh.read(4)
    if not head:
        return None
    if len(head) < 4:
        raise ValueError("record cut short")
    (hlen,) = struct.unpack("<I", head)
    hbuf = fh.read(hlen)
    dl = fh.read(4)
    if len(hbuf) < hlen or len(dl) < 4:
        raise ValueError("record header cut short")
    (dlen,) = struct.unpack("<I", dl)
    data = fh.read(dlen)
    if len(data) < dlen:
        raise ValueError("record data cut short")
    return _fields(hbuf), data


class ScannedBag(_Base):
    """A damaged ROS 1 bag, read sequentially. Holds message records only while iterating."""

    backend = "bag-scan"

    def __init__(self, path: Path) -> None:
        self.path = path
        self.fault: ReadFault | None = None
        with open(path, "rb") as fh:
            if fh.read(len(MAGIC)) != MAGIC:
                raise RecordingError(path, "not a ROS 1 bag v2.0")
        self._conns: dict[int, tuple[str, str, str]] = {}  # id -> (topic, type, msgdef)
        self._counts: dict[str, int] = {}
        self._start: int | None = None
        self._end: int | None = None
        for _ in self._iterate(None, count=True):
            pass

    def _iterate(self, wanted: set[str] | None, count: bool = False) -> Iterator[RawMessage]:
        n = 0
        try:
            with open(self.path, "rb") as fh:
                fh.seek(len(MAGIC))
                while True:
                    rec = _read_record(fh)
                    if rec is None:
                        break
                    hdr, data = rec
                    op = hdr.get("op", b"\x00")[0]
                    if op == OP_CHUNK:
                        for msg in self._chunk(hdr, data, wanted, count):
                            n += 1
                            yield msg
                    elif op == OP_CONNECTION:
                        self._connection(hdr, data)
        except Exception as exc:
            if self.fault is None:
                self.fault = ReadFault(f"{self.path}: damaged after {n} messages ({exc})", n)

    def _chunk(self, hdr: dict[str, bytes], data: bytes, wanted: set[str] | None,
               count: bool) -> Iterator[RawMessage]:
        comp = hdr.get("compression", b"none").decode()
        if comp == "bz2":
            data = bz2.decompress(data)
        elif comp == "lz4":
            import lz4.frame

            data = lz4.frame.decompress(data)
        elif comp != "none":
            raise ValueError(f"unknown chunk compression {comp}")
        for rhdr, rdata in _records(data):
            op = rhdr.get("op", b"\x00")[0]
            if op == OP_CONNECTION:
                self._connection(rhdr, rdata)
            elif op == OP_MSG_DATA:
                (cid,) = struct.unpack("<I", rhdr["conn"])
                sec, nsec = struct.unpack("<II", rhdr["time"])
                t = sec * 1_000_000_000 + nsec
                topic, msgtype, _ = self._conns[cid]
                if count:
                    self._counts[topic] = self._counts.get(topic, 0) + 1
                    self._start = t if self._start is None else min(self._start, t)
                    self._end = t if self._end is None else max(self._end, t)
                if wanted is None or topic in wanted:
                    yield RawMessage(topic, msgtype, t, rdata, cid)

    def _connection(self, hdr: dict[str, bytes], data: bytes) -> None:
        (cid,) = struct.unpack("<I", hdr["conn"])
        if cid in self._conns:
            return
        info = _fields(data)
        topic = hdr.get("topic", info.get("topic", b"")).decode()
        msgtype = normalise_msgtype(info["type"].decode())
        self._conns[cid] = (topic, msgtype, info.get("message_definition", b"").decode())

    @property
    def topics(self) -> list[TopicInfo]:
        seen: dict[str, TopicInfo] = {}
        for topic, msgtype, _ in self._conns.values():
            seen.setdefault(topic, TopicInfo(topic, msgtype, self._counts.get(topic, 0), "ros1"))
        return list(seen.values())

    def messages(self, topics: Iterable[str], start_ns: int | None = None,
                 end_ns: int | None = None) -> Iterator[RawMessage]:
        self.fault = None
        for raw in self._iterate(set(topics)):
            if (start_ns is not None and raw.log_ns < start_ns) or \
                    (end_ns is not None and raw.log_ns > end_ns):
                continue
            yield raw

    def deserialize(self, raw: RawMessage) -> Any:
        _, msgtype, msgdef = self._conns[raw.key]
        ts = typestore(1)
        if msgtype not in ts.types:
            from rosbags.typesys import get_types_from_msg

            ts.register(get_types_from_msg(msgdef, msgtype))
        return ts.deserialize_ros1(raw.data, msgtype)

    def close(self) -> None:
        pass
