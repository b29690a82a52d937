"""ROS 1 bags whose index rosbags refuses, and the damage rosbags does not look for.

rosbags needs an intact index; a bag cut short (a recorder killed mid-run) has none, and a bag
whose index-data records are damaged is refused even when its chunk-info records at the end are
intact. :class:`ScannedBag` reads such a bag by the chunk-info records when they are usable,
otherwise record by record from the start, and stops at the first damaged record, so the messages
before the damage can still be analysed. :func:`read_layout` also finds damage after an intact
index (zero padding from a recorder that preallocated the file, trailing garbage).

Format: bag v2.0 -- a bag-header record, chunks (holding connection and message-data records)
each followed by index-data records, then the index: connection and chunk-info records.
"""

from __future__ import annotations

import bz2
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

from frontdiag.errors import RecordingError
from frontdiag.io.readers import RawMessage, ReadFault, TopicInfo, _Base
from frontdiag.io.writer import normalise_msgtype, typestore

OP_MSG_DATA, OP_BAG_HEADER, OP_INDEX_DATA, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION = (
    0x02, 0x03, 0x04, 0x05, 0x06, 0x07)
KNOWN_OPS = {OP_MSG_DATA, OP_BAG_HEADER, OP_INDEX_DATA, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION}
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
        out[name.decode(errors="replace")] = value
        pos += n
    if pos != len(buf):
        raise ValueError("bad header field length")
    return out


def _op(hdr: dict[str, bytes]) -> int:
    op = hdr.get("op", b"")
    if len(op) != 1:
        raise ValueError("record header without an op field")
    return op[0]


def _u32(hdr: dict[str, bytes], name: str) -> int:
    v = hdr.get(name, b"")
    if len(v) != 4:
        raise ValueError(f"record header field {name} missing or malformed")
    return int(struct.unpack("<I", v)[0])


def _u64(hdr: dict[str, bytes], name: str) -> int:
    v = hdr.get(name, b"")
    if len(v) != 8:
        raise ValueError(f"record header field {name} missing or malformed")
    return int(struct.unpack("<Q", v)[0])


def _records(data: bytes) -> Iterator[tuple[dict[str, bytes], bytes]]:
    """The records inside a (decompressed) chunk."""
    pos = 0
    while pos < len(data):
        if pos + 4 > len(data):
            raise ValueError("record header length cut short")
        (hlen,) = struct.unpack_from("<I", data, pos)
        if hlen == 0:
            raise ValueError("zeros where a record must be (inside a chunk)")
        hdr = _fields(data[pos + 4:pos + 4 + hlen])
        pos += 4 + hlen
        if pos + 4 > len(data):
            raise ValueError("record data length cut short")
        (dlen,) = struct.unpack_from("<I", data, pos)
        if pos + 4 + dlen > len(data):
            raise ValueError("record data cut short")
        yield hdr, data[pos + 4:pos + 4 + dlen]
        pos += 4 + dlen


def _read_record(fh: BinaryIO, size: int) -> tuple[dict[str, bytes], bytes] | None:
    """The record at the file position; None at a clean end of file; ValueError at damage."""
    at = fh.tell()
    head = fh.read(4)
    if not head:
        return None
    if len(head) < 4:
        raise ValueError(f"record at byte {at} cut short")
    (hlen,) = struct.unpack("<I", head)
    if hlen == 0:
        raise ValueError(f"zeros where a record must be, from byte {at} of {size}")
    if at + 8 + hlen > size:
        raise ValueError(f"record header at byte {at} cut short")
    hbuf = fh.read(hlen)
    dl = fh.read(4)
    (dlen,) = struct.unpack("<I", dl)
    if fh.tell() + dlen > size:
        raise ValueError(f"record data at byte {at} cut short")
    hdr = _fields(hbuf)
    op = _op(hdr)
    if op not in KNOWN_OPS:
        raise ValueError(f"record at byte {at} has an unknown op 0x{op:02x}")
    return hdr, fh.read(dlen)


@dataclass
class ChunkInfo:
    pos: int
    start: int
    end: int
    counts: dict[int, int]  # connection id -> messages


@dataclass
class BagLayout:
    """What the bag header and the index at its end say, and what is wrong with them."""

    size: int
    index_pos: int = 0
    # the index's connection records, parsed: id -> (topic, message type, message definition)
    connections: list[tuple[int, tuple[str, str, str]]] = field(default_factory=list)
    chunks: list[ChunkInfo] = field(default_factory=list)
    index_fault: str | None = None  # the index cannot be used; read record by record
    tail_fault: str | None = None  # the index is intact, but damage follows it


def _parse_connection(hdr: dict[str, bytes], data: bytes) -> tuple[int, tuple[str, str, str]]:
    """A connection record's id and (topic, message type, message definition); ValueError
    when it is malformed."""
    cid = _u32(hdr, "conn")
    info = _fields(data)
    topic = hdr.get("topic", info.get("topic", b"")).decode(errors="replace")
    if "type" not in info:
        raise ValueError(f"connection {cid} has no message type")
    msgtype = normalise_msgtype(info["type"].decode(errors="replace"))
    return cid, (topic, msgtype, info.get("message_definition", b"").decode(errors="replace"))


def read_layout(path: Path) -> BagLayout:
    """Read the bag header and the index section (small: no message data is read)."""
    size = path.stat().st_size
    with open(path, "rb") as fh:
        if fh.read(len(MAGIC)) != MAGIC:
            raise RecordingError(path, "not a ROS 1 bag v2.0")
        try:
            rec = _read_record(fh, size)
            if rec is None or _op(rec[0]) != OP_BAG_HEADER:
                raise ValueError("the bag header record is missing")
            hdr = rec[0]
            layout = BagLayout(size, _u64(hdr, "index_pos"))
            conn_count, chunk_count = _u32(hdr, "conn_count"), _u32(hdr, "chunk_count")
        except (ValueError, struct.error) as exc:
            return BagLayout(size, index_fault=f"bag header damaged ({exc})")
        if layout.index_pos == 0:
            layout.index_fault = "no index: the recording was not closed (cut short?)"
            return layout
        if layout.index_pos >= size:
            layout.index_fault = (f"cut short: the index should start at byte "
                                  f"{layout.index_pos} of a {size}-byte file")
            return layout
        fh.seek(layout.index_pos)
        try:
            while True:
                at = fh.tell()
                rec = _read_record(fh, size)
                if rec is None:
                    break
                op = _op(rec[0])
                if op == OP_CONNECTION:  # a damaged one makes the index unusable
                    layout.connections.append(_parse_connection(*rec))
                elif op == OP_CHUNK_INFO:
                    layout.chunks.append(_chunk_info(*rec))
                else:
                    raise ValueError(f"record at byte {at} (op 0x{op:02x}) does not belong in "
                                     "the index")
        except (ValueError, struct.error) as exc:
            if len(layout.chunks) == chunk_count and len(layout.connections) >= conn_count:
                layout.tail_fault = f"{exc}, after the index"
            else:
                layout.index_fault = f"index damaged ({exc})"
            return layout
        if len(layout.chunks) != chunk_count or any(c.pos >= size for c in layout.chunks):
            layout.index_fault = (f"index damaged (it lists {len(layout.chunks)} usable chunks, "
                                  f"the header says {chunk_count})")
        return layout


def _chunk_info(hdr: dict[str, bytes], data: bytes) -> ChunkInfo:
    if _u32(hdr, "ver") != 1:
        raise ValueError("unsupported chunk-info version")
    n = _u32(hdr, "count")
    if len(data) != 8 * n:
        raise ValueError("chunk-info record length does not match its count")
    pairs = struct.unpack(f"<{2 * n}I", data)
    sec, nsec = struct.unpack("<II", hdr["start_time"])
    sec2, nsec2 = struct.unpack("<II", hdr["end_time"])
    return ChunkInfo(_u64(hdr, "chunk_pos"), sec * 1_000_000_000 + nsec,
                     sec2 * 1_000_000_000 + nsec2, dict(zip(pairs[::2], pairs[1::2], strict=True)))


class ScannedBag(_Base):
    """A ROS 1 bag read without rosbags: by its chunk-info records when they are intact,
    otherwise record by record from the start. Holds one chunk at a time while iterating."""

    backend = "bag-scan"

    def __init__(self, path: Path, layout: BagLayout | None = None) -> None:
        self.path = path
        self.fault: ReadFault | None = None
        self.layout = layout if layout is not None else read_layout(path)
        self._conns: dict[int, tuple[str, str, str]] = {}  # id -> (topic, type, msgdef)
        self._counts: dict[str, int] = {}
        self._start: int | None = None
        self._end: int | None = None
        self._by_index = self.layout.index_fault is None and bool(self.layout.chunks)
        if self._by_index:
            for cid, info in self.layout.connections:
                self._conns.setdefault(cid, info)
            for c in self.layout.chunks:
                for cid, k in c.counts.items():
                    topic = self._conns.get(cid, (f"#{cid}",))[0]
                    self._counts[topic] = self._counts.get(topic, 0) + k
                self._start = c.start if self._start is None else min(self._start, c.start)
                self._end = c.end if self._end is None else max(self._end, c.end)
        else:  # no usable index: one pass to learn connections, counts and the time span
            for _ in self._iterate(None, count=True):
                pass

    def _iterate(self, wanted: set[str] | None, count: bool = False) -> Iterator[RawMessage]:
        n = 0
        size = self.layout.size
        try:
            with open(self.path, "rb") as fh:
                if self._by_index:
                    for c in sorted(self.layout.chunks, key=lambda c: (c.start, c.pos)):
                        fh.seek(c.pos)
                        rec = _read_record(fh, size)
                        if rec is None or _op(rec[0]) != OP_CHUNK:
                            raise ValueError(f"no chunk at byte {c.pos}, where the index "
                                             "says one starts")
                        for msg in self._chunk(*rec, wanted, count):
                            n += 1
                            yield msg
                    if self.layout.tail_fault:
                        raise ValueError(self.layout.tail_fault)
                    return
                fh.seek(len(MAGIC))
                while True:
                    rec = _read_record(fh, size)
                    if rec is None:
                        break
                    hdr, data = rec
                    op = _op(hdr)
                    if op == OP_CHUNK:
                        for msg in self._chunk(hdr, data, wanted, count):
                            n += 1
                            yield msg
                    elif op == OP_CONNECTION:
                        self._connection(hdr, data)
                # every record read, but the index the header points to was not usable
                raise ValueError(self.layout.index_fault or "no index")
        except (ValueError, KeyError, struct.error, OSError, EOFError) as exc:
            if self.fault is None:
                self.fault = ReadFault(f"{self.path}: damaged after {n} messages ({exc})", n)
        except Exception as exc:  # a decompressor's own error type (bz2, lz4)
            if self.fault is None:
                self.fault = ReadFault(f"{self.path}: damaged after {n} messages "
                                       f"(chunk cannot be decompressed: {exc})", n)

    def _chunk(self, hdr: dict[str, bytes], data: bytes, wanted: set[str] | None,
               count: bool) -> Iterator[RawMessage]:
        comp = hdr.get("compression", b"none").decode(errors="replace")
        if comp == "bz2":
            data = bz2.decompress(data)
        elif comp == "lz4":
            import lz4.frame

            data = lz4.frame.decompress(data)
        elif comp != "none":
            raise ValueError(f"unknown chunk compression {comp!r}")
        for rhdr, rdata in _records(data):
            op = _op(rhdr)
            if op == OP_CONNECTION:
                self._connection(rhdr, rdata)
            elif op == OP_MSG_DATA:
                cid = _u32(rhdr, "conn")
                t = _u64(rhdr, "time")
                t = (t & 0xFFFFFFFF) * 1_000_000_000 + (t >> 32)  # sec, nsec (little-endian)
                if cid not in self._conns:
                    raise ValueError(f"message on unknown connection {cid}")
                topic = self._conns[cid][0]
                if count:
                    self._counts[topic] = self._counts.get(topic, 0) + 1
                    self._start = t if self._start is None else min(self._start, t)
                    self._end = t if self._end is None else max(self._end, t)
                if wanted is None or topic in wanted:
                    yield RawMessage(topic, self._conns[cid][1], t, rdata, cid)
            else:
                raise ValueError(f"record with op 0x{op:02x} inside a chunk")

    def _connection(self, hdr: dict[str, bytes], data: bytes) -> None:
        cid = _u32(hdr, "conn")
        if cid not in self._conns:
            self._conns[cid] = _parse_connection(hdr, data)[1]

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

