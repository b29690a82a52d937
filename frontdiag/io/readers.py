"""One registry of recording readers, one protocol, integer-nanosecond timestamps.

Two backends sit behind :func:`open_recording`:

* ``rosbags`` (``AnyReader``): ROS 1 bags (a file, several files, or a folder of split bags),
  ROS 2 bag folders with sqlite3 or MCAP storage, and standalone ``.db3`` files. A ROS 1 bag
  without index is read record by record (:mod:`frontdiag.io.bag_scan`), a truncated ``.db3``
  row by row up to the damage (:mod:`frontdiag.io.db3_scan`).
* ``mcap`` (the ``mcap`` package): standalone MCAP files in ROS 2 (``cdr``) or ROS 1 encoding,
  including files written outside ROS, and Foxglove's schemas in Protobuf or JSON encoding
  (:mod:`frontdiag.io.foxglove`). It also reads MCAP files whose summary section is missing
  (a recorder that was killed), streaming records until the damage.

Which backend takes a standalone ROS 2 MCAP file was decided by measurement
(``benchmarks/bench_readers.py``); see :data:`MCAP_BACKEND`.

Messages are returned raw (bytes) and deserialised on demand into rosbags message objects, so
decoders see the same object shape whatever the container; Foxglove's schemas are given the
fields of their ``sensor_msgs`` counterparts.
"""

from __future__ import annotations

import logging
import shlex
import sqlite3
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, Protocol

from frontdiag.errors import RecordingError
from frontdiag.io import foxglove
from frontdiag.io.writer import normalise_msgtype, typestore

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TopicInfo:
    topic: str
    msgtype: str  # normalised: pkg/msg/Type
    count: int | None  # None when the container does not say (damaged MCAP)
    encoding: str = ""  # cdr | ros1 | protobuf | json


@dataclass(frozen=True)
class RawMessage:
    topic: str
    msgtype: str
    log_ns: int
    data: bytes | memoryview
    key: Any = None  # backend handle used by deserialize()


@dataclass
class ReadFault:
    """Damage found while streaming: messages before it were delivered."""

    message: str
    after_messages: int
    resumed: bool = False
    """Whether reading went on after the damage (the parts after a damaged part of a split
    recording): the messages after it were delivered too."""


def damage_hint(fault: ReadFault) -> str:
    """What of a damaged recording was analysed, for the error line's hint."""
    if fault.resumed:
        return ("the frames before the damage and those of the parts after it were analysed "
                "and kept")
    return "the frames before the damage were analysed and kept"


class Recording(Protocol):
    path: Path
    backend: str
    fault: ReadFault | None

    @property
    def topics(self) -> list[TopicInfo]: ...

    @property
    def start_ns(self) -> int | None: ...

    @property
    def end_ns(self) -> int | None: ...

    def messages(self, topics: Iterable[str], start_ns: int | None = None,
                 end_ns: int | None = None) -> Iterator[RawMessage]: ...

    def deserialize(self, raw: RawMessage) -> Any: ...

    def close(self) -> None: ...

    def __enter__(self) -> Recording: ...

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None: ...


class _Base:
    """Context management and the time span shared by the backends."""

    path: Path
    fault: ReadFault | None = None
    _start: int | None = None
    _end: int | None = None

    @property
    def start_ns(self) -> int | None:
        return self._start

    @property
    def end_ns(self) -> int | None:
        return self._end


    def __enter__(self) -> Any:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def close(self) -> None:  # pragma: no cover - overridden
        pass


# --------------------------------------------------------------------------------------------
# rosbags backend
# --------------------------------------------------------------------------------------------

class RosbagsRecording(_Base):
    backend = "rosbags"

    def __init__(self, path: Path, files: Sequence[Path], encoding: str = "cdr",
                 tail_fault: str | None = None) -> None:
        from rosbags.highlevel import AnyReader

        self.path = path
        self._encoding = encoding
        self._tail_fault = tail_fault  # damage after an intact index, reported after the messages
        self.fault = None if tail_fault is None else ReadFault(f"{path}: {tail_fault}", 0)
        self._alias = _Alias(files, encoding)
        try:
            self._reader = AnyReader(self._alias.paths, default_typestore=typestore(2))
            self._reader.open()
        except Exception as exc:  # rosbags raises several unrelated types for damage
            self._alias.cleanup()
            raise RecordingError(path, f"cannot open recording ({_short(exc)})",
                                 hint=_damage_hint(path)) from exc
        self._conns_by_topic: dict[str, list[Any]] = {}
        for conn in self._reader.connections:
            self._conns_by_topic.setdefault(conn.topic, []).append(conn)

    @property
    def topics(self) -> list[TopicInfo]:
        out = []
        for topic, conns in self._conns_by_topic.items():
            count = sum(int(c.msgcount) for c in conns)
            out.append(TopicInfo(topic, normalise_msgtype(conns[0].msgtype), count,
                                 self._encoding))
        return out

    @property
    def start_ns(self) -> int | None:
        t = self._reader.start_time
        return int(t) if t and t < 2**63 - 1 else None

    @property
    def end_ns(self) -> int | None:
        t = self._reader.end_time  # rosbags reports one past the last message
        return int(t) - 1 if t else None

    def messages(self, topics: Iterable[str], start_ns: int | None = None,
                 end_ns: int | None = None) -> Iterator[RawMessage]:
        wanted = set(topics)
        conns = [c for t in wanted for c in self._conns_by_topic.get(t, [])]
        if not conns:
            return
        n = 0
        stop = None if end_ns is None else end_ns + 1  # rosbags' stop is exclusive
        try:
            for conn, t_ns, data in self._reader.messages(connections=conns, start=start_ns,
                                                           stop=stop):
                n += 1
                yield RawMessage(conn.topic, normalise_msgtype(conn.msgtype), int(t_ns), data,
                                 conn)
        except Exception as exc:
            self.fault = ReadFault(f"{self.path}: damaged after {n} messages ({_short(exc)})", n)
            log.info("%s", self.fault.message)
            return
        if self._tail_fault is not None:
            self.fault = ReadFault(f"{self.path}: damaged after {n} messages ({self._tail_fault})",
                                   n)

    def deserialize(self, raw: RawMessage) -> Any:
        return foxglove.adapt(self._reader.deserialize(bytes(raw.data), raw.key.msgtype),
                              raw.msgtype)

    def close(self) -> None:
        try:
            self._reader.close()
        except Exception:  # pragma: no cover - closing a damaged reader
            log.debug("error while closing %s", self.path, exc_info=True)
        self._alias.cleanup()


_URI_UNSAFE = set("#?%")


class _Alias:
    """Paths rosbags can take for ``files``: rosbags picks the format by file suffix and puts
    sqlite paths into a URI unescaped, so a bag named ``RUN.BAG`` or ``run``, a renamed ``.db3``,
    a bag folder named ``run.bag`` or a path holding ``#``, ``?`` or ``%`` is read through
    symbolic links with plain names in a private temporary folder (removed on close)."""

    def __init__(self, files: Sequence[Path], encoding: str) -> None:
        self._tmp: str | None = None
        self.paths = [self._fit(f, i, encoding) for i, f in enumerate(files)]

    def _fit(self, f: Path, i: int, encoding: str) -> Path:
        unsafe = bool(_URI_UNSAFE & set(str(f.resolve())))
        if encoding == "ros1":
            if f.suffix == ".bag":
                return f
            return self._link(f, f"part{i:04d}.bag")
        if f.is_dir():
            if f.suffix != ".bag" and not unsafe:
                return f
            folder = Path(self._dir()) / f"bag{i}"
            folder.mkdir()
            for child in f.iterdir():
                (folder / child.name).symlink_to(child.resolve())
            return folder
        if f.suffix == ".db3" and not unsafe:
            return f
        return self._link(f, f"part{i:04d}.db3")

    def _dir(self) -> str:
        if self._tmp is None:
            import tempfile

            self._tmp = tempfile.mkdtemp(prefix="frontdiag-")
        return self._tmp

    def _link(self, f: Path, name: str) -> Path:
        link = Path(self._dir()) / name
        link.symlink_to(f.resolve())
        return link

    def cleanup(self) -> None:
        if self._tmp is not None:
            import shutil

            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None


class ChainedRecording(_Base):
    """Split bags read one part after another, so a damaged part costs only its own messages
    after the damage: the parts before it and after it are read whole. The first damage is the
    recording's fault, naming the part (and saying the parts after it were read)."""

    backend = "rosbags"

    def __init__(self, path: Path, parts: Sequence[Recording]) -> None:
        self.path = path
        # in time order; a part whose start is unknown (damaged before its first message) keeps
        # its place in the split's numbering, which is the recorder's order too
        known = all(p.start_ns is not None for p in parts)
        self.parts = sorted(parts, key=lambda p: p.start_ns or 0) if known else list(parts)
        self.backend = "+".join(dict.fromkeys(p.backend for p in self.parts if p.backend))
        self.fault = next((p.fault for p in self.parts if p.fault is not None), None)
        starts = [p.start_ns for p in self.parts if p.start_ns is not None]
        ends = [p.end_ns for p in self.parts if p.end_ns is not None]
        self._start = min(starts) if starts else None
        self._end = max(ends) if ends else None

    @property
    def topics(self) -> list[TopicInfo]:
        merged: dict[str, TopicInfo] = {}
        for part in self.parts:
            for t in part.topics:
                prev = merged.get(t.topic)
                count = t.count if prev is None else (
                    None if prev.count is None or t.count is None else prev.count + t.count)
                merged[t.topic] = TopicInfo(t.topic, t.msgtype, count, t.encoding)
        return list(merged.values())

    def messages(self, topics: Iterable[str], start_ns: int | None = None,
                 end_ns: int | None = None) -> Iterator[RawMessage]:
        wanted = list(topics)
        self.fault = None
        n = 0
        for k, part in enumerate(self.parts):
            for raw in part.messages(wanted, start_ns, end_ns):
                n += 1
                yield RawMessage(raw.topic, raw.msgtype, raw.log_ns, raw.data, (part, raw))
            if part.fault is not None and self.fault is None:
                inner = without_path(part.fault.message, part.path)
                _, sep, reason = inner.partition(" messages (")
                reason = reason[:-1] if sep and reason.endswith(")") else inner
                after = len(self.parts) - 1 - k
                more = f"; reading went on with the {after} part(s) after it" if after else ""
                self.fault = ReadFault(f"{self.path}: damaged after {n} messages (in "
                                       f"{part.path.name}: {reason}){more}", n,
                                       resumed=after > 0)

    def deserialize(self, raw: RawMessage) -> Any:
        part, inner = raw.key
        return part.deserialize(inner)

    def close(self) -> None:
        for part in self.parts:
            part.close()


# --------------------------------------------------------------------------------------------
# mcap backend
# --------------------------------------------------------------------------------------------

class McapRecording(_Base):
    backend = "mcap"

    def __init__(self, path: Path, unzstd: bool = False) -> None:
        from mcap.reader import make_reader

        self.path = path
        self.fault = None
        # each message compressed on its own (a ROS 2 bag of --compression-mode message)
        self._unzstd = unzstd
        try:
            self._fh = open(path, "rb")  # noqa: SIM115 - closed in close()
            self._reader = make_reader(self._fh)
            self._header = self._reader.get_header()
        except Exception as exc:
            self.close()
            raise RecordingError(path, f"not a readable MCAP file ({_short(exc)})",
                                 hint="check that the file is MCAP (magic bytes \\x89MCAP0)") from exc
        self._summary: Any = None
        try:
            self._summary = self._reader.get_summary()
        except Exception:
            self._summary = None
        if self._summary is None:
            log.info("%s has no summary section (recording cut short?); streaming it", path)
        self._schema_cache: dict[int, tuple[str, int, Any]] = {}
        self._decoders: dict[int, Any] = {}  # protobuf / json, by schema id
        self._channels: dict[str, tuple[str, str]] = {}  # topic -> (msgtype, encoding)
        self._counts: dict[str, int] = {}
        self._start: int | None = None
        self._end: int | None = None
        self._scan_channels()

    @property
    def profile(self) -> str:
        return str(getattr(self._header, "profile", ""))

    def _scan_channels(self) -> None:
        if self._summary is not None:
            schemas = self._summary.schemas
            stats = self._summary.statistics
            counts = dict(stats.channel_message_counts) if stats else {}
            for cid, ch in self._summary.channels.items():
                schema = schemas.get(ch.schema_id)
                name = schema.name if schema else ""
                self._channels[ch.topic] = (normalise_msgtype(name), ch.message_encoding)
                self._counts[ch.topic] = self._counts.get(ch.topic, 0) + int(counts.get(cid, 0))
            if stats and stats.message_count:
                self._start, self._end = int(stats.message_start_time), int(stats.message_end_time)
            return
        # No summary: one streaming pass to learn channels, counts and the time span.
        n = 0
        try:
            for schema, ch, msg in stream_mcap(self._fh, None):
                name = schema.name if schema else ""
                self._channels.setdefault(ch.topic, (normalise_msgtype(name), ch.message_encoding))
                self._counts[ch.topic] = self._counts.get(ch.topic, 0) + 1
                t = int(msg.log_time)
                self._start = t if self._start is None else min(self._start, t)
                self._end = t if self._end is None else max(self._end, t)
                n += 1
        except Exception as exc:
            self.fault = ReadFault(f"{self.path}: damaged after {n} messages ({_short(exc)})", n)

    @property
    def topics(self) -> list[TopicInfo]:
        return [TopicInfo(t, mt, self._counts.get(t), enc) for t, (mt, enc) in self._channels.items()]

    def messages(self, topics: Iterable[str], start_ns: int | None = None,
                 end_ns: int | None = None) -> Iterator[RawMessage]:
        wanted = list(set(topics))
        if not wanted:
            return
        n = 0
        try:
            if self._summary is not None and self._summary.chunk_indexes:
                it = self._reader.iter_messages(topics=wanted, starting_at=start_ns,
                                                ending_at=end_ns)
            else:  # no summary, or an unchunked file: in file order, up to any damage
                it = stream_mcap(self._fh, set(wanted))
            for schema, ch, msg in it:
                t = int(msg.log_time)
                if (start_ns is not None and t < start_ns) or (end_ns is not None and t > end_ns):
                    continue
                n += 1
                yield RawMessage(ch.topic, normalise_msgtype(schema.name if schema else ""), t,
                                 unzstd(msg.data) if self._unzstd else msg.data,
                                 (schema, ch.message_encoding))
        except Exception as exc:
            self.fault = ReadFault(f"{self.path}: damaged after {n} messages ({_short(exc)})", n)
            log.info("%s", self.fault.message)

    def deserialize(self, raw: RawMessage) -> Any:
        schema, encoding = raw.key
        if schema is None:
            raise ValueError(f"topic {raw.topic} has no schema; cannot decode")
        if encoding in foxglove.ENCODINGS:
            return foxglove.adapt(self._decoder_for(schema, encoding)(bytes(raw.data)),
                                  raw.msgtype)
        typename, version, ts = self._typestore_for(schema, encoding)
        if version == 1:
            msg = ts.deserialize_ros1(raw.data, typename)
        else:
            msg = ts.deserialize_cdr(raw.data, typename)
        return foxglove.adapt(msg, raw.msgtype)

    def _decoder_for(self, schema: Any, encoding: str) -> Any:
        """Protobuf or JSON: only Foxglove's schemas are read (:mod:`frontdiag.io.foxglove`)."""
        fn = self._decoders.get(schema.id)
        if fn is None:
            if foxglove.kind(schema.name) is None:
                raise ValueError(f"{encoding} schema {schema.name!r} is not one frontdiag reads "
                                 "(Foxglove's image, calibration, point cloud and scan schemas)")
            fn = (foxglove.protobuf_decoder(schema) if encoding == "protobuf"
                  else foxglove.json_decoder(schema))
            self._decoders[schema.id] = fn
        return fn

    def _typestore_for(self, schema: Any, encoding: str) -> tuple[str, int, Any]:
        cached = self._schema_cache.get(schema.id)
        if cached is not None:
            return cached
        if encoding == "ros1":
            version = 1
        elif encoding == "cdr":
            version = 2
        else:
            raise ValueError(f"message encoding {encoding!r} is not supported (cdr, ros1, "
                             "and protobuf or json for Foxglove's schemas)")
        ts = typestore(version)
        typename = normalise_msgtype(schema.name)
        if typename not in ts.types:
            from rosbags.typesys import get_types_from_msg

            text = schema.data.decode()
            ts.register(get_types_from_msg(text, typename))
        self._schema_cache[schema.id] = (typename, version, ts)
        return typename, version, ts

    def close(self) -> None:
        fh = getattr(self, "_fh", None)
        if fh is not None:
            fh.close()


def stream_mcap(fh: Any, topics: set[str] | None) -> Iterator[tuple[Any, Any, Any]]:
    """(schema, channel, message) in file order, raising at the first damaged record; holds
    one chunk at a time (the seeking reader's ``iter_messages`` held about 10 KiB a message).

    Unlike the mcap package's own streaming reader it stops at opcode 0 (never a valid record:
    the zeros a preallocating recorder leaves) instead of skipping 9 bytes at a time through
    them, and it refuses a record longer than the file.
    """
    import os

    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader

    size = os.fstat(fh.fileno()).st_size

    class Strict(StreamReader):
        def _read_record(self, opcode: int, length: int) -> Any:
            if opcode == 0:
                at = self._stream.count - 9
                raise ValueError(f"zeros where a record must be, from byte {at} of {size}")
            return super()._read_record(opcode, length)

    fh.seek(0)
    schemas: dict[int, Any] = {}
    channels: dict[int, Any] = {}
    for record in Strict(fh, record_size_limit=size).records:
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Message):
            ch = channels.get(record.channel_id)
            if ch is None:
                raise ValueError(f"message on unknown channel {record.channel_id}")
            if topics is None or ch.topic in topics:
                yield schemas.get(ch.schema_id), ch, record


# --------------------------------------------------------------------------------------------
# registry and choice
# --------------------------------------------------------------------------------------------

MCAP_BACKEND = "mcap"
"""Backend for standalone ROS 2 MCAP files; the mcap package measured faster (see the benchmark)
and it is the only one of the two that reads ROS 1-encoded MCAP and files cut short."""


def _rosbags(path: Path, files: Sequence[Path], container: str = "") -> Recording:
    if container.startswith("ros1"):
        return _ros1(path, files)
    if container.startswith(SPLIT_PARTS) and len(files) > 1:
        # each part on its own, so a damaged last part keeps the parts before it
        return ChainedRecording(path, _parts(files, lambda f: _rosbags(f, [f])))
    from frontdiag.io.db3_scan import bag_files, header_shortfall

    try:
        db3 = bag_files(files[0]) if len(files) == 1 and files[0].is_dir() else list(files)
    except RecordingError:  # e.g. a compressed bag: rosbags says what it makes of it
        db3 = []
    if any(f.is_file() and header_shortfall(f) for f in db3):
        # sqlite reads a file missing its last pages without complaint until a query needs
        # them; read it row by row so the shortfall is reported
        scanned = _scan_db3(path, files)
        if scanned is not None:
            return scanned
    try:
        return RosbagsRecording(path, files, "cdr")
    except RecordingError:
        scanned = _scan_db3(path, files)
        if scanned is None:
            raise
        log.info("%s: sqlite file damaged or cut short; reading its rows directly", path)
        return scanned


def _ros1(path: Path, files: Sequence[Path]) -> Recording:
    """ROS 1 bags: rosbags when the index is intact, else the record scanner; split bags part
    by part when one of them is damaged."""
    from frontdiag.io.bag_scan import ScannedBag, read_layout

    layouts = [read_layout(f) for f in files]
    if len(files) > 1:
        if all(lay.index_fault is None and lay.tail_fault is None for lay in layouts):
            try:
                return RosbagsRecording(path, files, "ros1")
            except RecordingError:
                pass
        return ChainedRecording(path, [_ros1(f, [f]) for f in files])
    (f,), (layout,) = files, layouts
    if layout.index_fault is None:
        try:
            return RosbagsRecording(path, files, "ros1", tail_fault=layout.tail_fault)
        except RecordingError:
            pass
    log.info("%s: index missing or damaged; reading records without it", path)
    return ScannedBag(f, layout)


def _scan_db3(path: Path, files: Sequence[Path]) -> Recording | None:
    """A ROS 2 sqlite3 recording rosbags refused, read row by row -- only when it is damaged.

    A file sqlite reads whole was refused for another reason (metadata, compression): that
    error stands, rather than a reader that ignores what rosbags objected to.
    """
    from frontdiag.io.db3_scan import SQLITE_MAGIC, ScannedDb3, bag_files

    try:
        if len(files) == 1 and files[0].is_dir():
            db3 = bag_files(files[0])
        else:
            db3 = [f for f in files if f.is_file() and f.suffix != ".bag"]
        if not db3 or any(_magic(f, len(SQLITE_MAGIC)) != SQLITE_MAGIC for f in db3):
            return None
        folder = files[0] if len(files) == 1 and files[0].is_dir() else None
        rec = ScannedDb3(path, db3, unzstd=folder is not None
                         and compressed_messages(folder / "metadata.yaml"))
    except (RecordingError, OSError, sqlite3.Error):
        return None
    if rec.fault is None:
        rec.close()
        return None
    return rec


def _magic(path: Path, n: int) -> bytes:
    with open(path, "rb") as fh:
        return fh.read(n)


def _mcap(path: Path, files: Sequence[Path], container: str = "", unzstd: bool = False
          ) -> Recording:
    if container.startswith(SPLIT_PARTS) and len(files) > 1:
        return ChainedRecording(path, _parts(files, lambda f: McapRecording(f, unzstd=unzstd)))
    return McapRecording(files[0] if files else path, unzstd=unzstd)


READERS: dict[str, Any] = {"rosbags": _rosbags, "mcap": _mcap}


@dataclass(frozen=True)
class _Plan:
    backend: str
    files: list[Path] = field(default_factory=list)
    container: str = ""
    unzstd: bool = False  # an MCAP bag whose messages are compressed one by one


def recording_files(path: Path) -> list[Path]:
    """The files of a recording: the file itself, or every file below a bag folder (sorted)."""
    if path.is_dir():
        return sorted(f for f in path.rglob("*") if f.is_file())
    return [path]


def recording_size(path: Path) -> int:
    """Bytes on disk of a recording (a file, or every file below a bag folder)."""
    return sum(f.stat().st_size for f in recording_files(path))


RECORDING_SUFFIXES = (".bag", ".mcap", ".db3")
DIAGNOSTICS_NAME = "diagnostics.mcap"  # what `analyze --out` writes beside its table
FLEET_SUMMARY_FILE = "fleet_summary.parquet"  # what a fleet run's --out holds (frontdiag.fleet)


def recordings_in(folder: Path) -> list[Path]:
    """The recording files and bag folders directly in ``folder``, in name order; the
    diagnostics.mcap of a result written into it (beside its manifest.json) is frontdiag's
    own output, not a recording."""
    own = folder / DIAGNOSTICS_NAME if (folder / "manifest.json").is_file() else None
    return sorted(c for c in folder.iterdir()
                  if (c.is_file() and c.suffix in RECORDING_SUFFIXES and c != own)
                  or (c.is_dir() and (c / "metadata.yaml").exists()))


def is_result_dir(path: Path) -> bool:
    """Whether ``path`` is what ``frontdiag analyze --out`` writes, for one recording (its
    diagnostics.mcap would otherwise read as a one-file bag folder) or for a fleet, and holds
    no recording of its own: results may be written into a folder of recordings (a fleet's
    --out the folder it reads), which stays a folder of recordings."""
    if (path / "metadata.yaml").exists():
        return False
    one = (path / "manifest.json").is_file() \
        and any((path / n).is_file() for n in ("frames.parquet", "frames.csv"))
    return (one or (path / FLEET_SUMMARY_FILE).is_file()) and not recordings_in(path)


def refuse_result_dir(path: Path) -> None:
    """Raise where ``path`` is a result folder (:func:`is_result_dir`), naming the commands
    that read it and the recording it was made from (its manifest's)."""
    if not path.is_dir() or not is_result_dir(path):
        return
    import json

    q = shlex.quote(str(path))
    if (path / FLEET_SUMMARY_FILE).is_file():
        hint = (f"a fleet's results: read them with `frontdiag report {q}` or `frontdiag eval "
                f"{q}`, one recording's with `frontdiag explain {shlex.quote(str(path / 'NAME'))}`")
    else:
        rec = ""
        try:
            src = json.loads((path / "manifest.json").read_text()).get("input", {}).get("path")
            if src:
                rec = f"; analyse its recording again with `frontdiag analyze {shlex.quote(src)}`"
        except (OSError, ValueError, AttributeError):
            pass
        hint = (f"read it with `frontdiag explain {q}`, `frontdiag report {q}` or "
                f"`frontdiag eval {q}`{rec}")
    raise RecordingError(path, "a frontdiag result folder (the --out of `frontdiag analyze`), "
                               "not a recording", hint=hint)


def plan(path: Path) -> _Plan:
    """Decide which backend reads ``path`` (pure: looks at names and magic bytes only)."""
    if not path.exists():
        raise RecordingError(path, "no such file or folder",
                             hint="check the path; frontdiag reads .bag, .db3, .mcap files and "
                                  "ROS 2 bag folders")
    if path.is_dir():
        refuse_result_dir(path)
        if (path / "metadata.yaml").exists():
            mcaps = sorted(path.glob("*.mcap"))
            if len(mcaps) == 1 and not list(path.glob("*.db3")):
                # a single-file MCAP bag: the faster reader, same messages
                if compressed_messages(path / "metadata.yaml"):
                    return _Plan(MCAP_BACKEND, mcaps, "ros2 bag folder (mcap, zstd messages)",
                                 unzstd=True)
                return _Plan(MCAP_BACKEND, mcaps, "ros2 bag folder (mcap)")
            return _Plan("rosbags", [path], "ros2 bag folder")
        kinds = _folder_kinds(path)
        bags, db3, mcaps = kinds.get("bag", []), kinds.get("sqlite", []), kinds.get("mcap", [])
        if kinds.get("zstd") and not bags and not mcaps:
            # ros2 bag record --compression-mode file compresses each part when it closes; a
            # recorder that was killed leaves them without the metadata.yaml that lists them
            names = ", ".join(p.name for p in kinds["zstd"][:3])
            raise RecordingError(path, f"folder holds zstd-compressed parts ({names}) but no "
                                       "metadata.yaml, so their order and format are unknown",
                                 hint="decompress them (zstd -d PART) and pass the recording "
                                      "files, or write the metadata with `ros2 bag reindex`")
        if bags:
            if split_parts(path, kinds):
                return _Plan("rosbags", bags, "ros1 split bags")
            raise RecordingError(path, f"folder holds {sum(map(len, kinds.values()))} separate "
                                       "recordings, not the parts of one split bag "
                                       "(NAME_0.bag, NAME_1.bag, ...)",
                                 hint="pass one of them; `frontdiag analyze DIR --out OUT` "
                                      "analyses each into its own folder")
        if len(db3) == 1 and not mcaps:
            return _Plan("rosbags", db3, "ros2 db3 (no metadata.yaml)")
        split = ros2_parts(path, kinds)
        if split:
            backend = "rosbags" if split[0] in db3 else MCAP_BACKEND
            return _Plan(backend, split, f"{SPLIT_PARTS} ({len(split)} parts, no metadata.yaml)")
        if len(mcaps) == 1 and not db3:
            return plan(mcaps[0])
        raise RecordingError(path, "folder holds no metadata.yaml, ROS 1 bag, single sqlite "
                                   "(.db3) or single MCAP file",
                             hint="pass the recording file itself")
    if path.stat().st_size == 0:
        raise RecordingError(path, "file is empty")
    kind = recording_kind(path)
    if kind == "mcap":
        return _Plan(MCAP_BACKEND if _mcap_profile(path) in ("ros2", "") else "mcap", [path],
                     "mcap")
    if kind == "bag":
        return _Plan("rosbags", [path], "ros1 bag")
    if kind == "sqlite":
        return _Plan("rosbags", [path], "ros2 db3 (no metadata.yaml)")
    if kind == "zstd":
        raise RecordingError(path, "a zstd-compressed file (a part of a ROS 2 bag compressed per "
                                   "file?), not a recording frontdiag reads as it is",
                             hint="pass the bag folder with its metadata.yaml, or decompress "
                                  "it first (zstd -d FILE)")
    from frontdiag.loops.graph import looks_like_graph  # only on this error's path

    hint = "frontdiag reads .bag, .db3, .mcap files and ROS 2 bag folders"
    if looks_like_graph(path):
        hint = f"it reads as a pose graph (g2o or TORO): audit its loop closures with " \
               f"`frontdiag loops {shlex.quote(str(path))}`"
    raise RecordingError(path, "unknown container (not MCAP, ROS 1 bag v2.0 or sqlite3)",
                         hint=hint)


def bag_compression(metadata: Path) -> tuple[str, str]:
    """(compression mode, compression format) of a ROS 2 bag, lower-case, from its
    metadata.yaml; empty where unset ("none" reads as unset) or the file is unreadable."""
    import yaml

    try:
        info = yaml.safe_load(metadata.read_text(errors="replace"))["rosbag2_bagfile_information"]
        mode = str(info.get("compression_mode", "") or "").lower()
        fmt = str(info.get("compression_format", "") or "").lower()
    except Exception:  # a damaged or foreign metadata.yaml: read as uncompressed
        return "", ""
    return ("" if mode == "none" else mode), fmt


def compressed_messages(metadata: Path) -> bool:
    """Whether a ROS 2 bag compresses each message on its own with zstd (``ros2 bag record
    --compression-mode message``): its storage file then holds compressed payloads, which a
    reader of the file alone must decompress (:func:`unzstd`). A file-compressed bag
    (``.mcap.zstd``, ``.db3.zstd``) is read by rosbags."""
    mode, fmt = bag_compression(metadata)
    return mode == "message" and fmt in ("zstd", "")


def unzstd(data: bytes | memoryview) -> bytes | memoryview:
    """A message rosbag2 compressed on its own (one zstd frame), decompressed; a payload that
    does not decompress is passed on as it is, so its deserialisation fails for that message
    alone (counted as undecodable) rather than ending the topic."""
    import zstandard

    global _ZSTD
    if _ZSTD is None:
        _ZSTD = zstandard.ZstdDecompressor()
    try:
        return _ZSTD.decompressobj().decompress(bytes(data))
    except zstandard.ZstdError:
        return data


_ZSTD: Any = None  # one decompressor for every message (unzstd)


_MAGIC = {b"\x89MCAP": "mcap", b"#ROSBAG V2.0": "bag", b"SQLite format 3\x00": "sqlite",
          b"\x28\xb5\x2f\xfd": "zstd"}


def _folder_kinds(path: Path) -> dict[str, list[Path]]:
    """The folder's recording files by kind (magic bytes, not names), in natural order; ROS 2
    bag folders inside it under ``folder``."""
    kinds: dict[str, list[Path]] = {}
    for f in sorted(path.iterdir(), key=_natural):
        kind = (recording_kind(f) if f.is_file()
                else "folder" if (f / "metadata.yaml").exists() else None)
        if kind:
            kinds.setdefault(kind, []).append(f)
    return kinds


def split_parts(path: Path, kinds: dict[str, list[Path]] | None = None) -> bool:
    """Whether the folder holds the parts of one ROS 1 recording and nothing else.

    ``rosbag record --split`` names its parts ``NAME_0.bag``, ``NAME_1.bag``, ... (NAME often
    a date); a folder of separate recordings (``2024-05-01-10-00-00.bag``, ``aisle.bag``) is a
    fleet, not one recording read end to end. So: every recording file in the folder is a ROS 1
    bag, and either there is one, or all share one NAME with consecutive part numbers (the last
    may be ``NAME_N.bag.active``, left by a recorder that was killed). Recordings
    named like parts of one split (``run_1.bag``, ``run_2.bag``) are read as one; name them
    (a glob, or the files) to analyse them separately.
    """
    import re

    kinds = _folder_kinds(path) if kinds is None else kinds
    bags = kinds.get("bag", [])
    if not bags or any(k != "bag" for k in kinds):
        return False
    if len(bags) == 1:
        return True
    # a recorder killed mid-split leaves its last part as NAME_N.bag.active
    parts = [re.fullmatch(r"(.+)_(\d+)", b.name.removesuffix(".active").removesuffix(".bag"))
             for b in bags]
    if not all(parts):
        return False
    names = {m.group(1) for m in parts if m}
    numbers = sorted(int(m.group(2)) for m in parts if m)
    return len(names) == 1 and numbers == list(range(numbers[0], numbers[0] + len(numbers)))


class _Unreadable(_Base):
    """A part of a split recording that cannot be opened at all (cut to its first bytes): no
    messages, and its damage as the fault, where it falls in the parts' order."""

    backend = ""  # read by nothing

    def __init__(self, path: Path, exc: RecordingError, at_ns: int | None) -> None:
        self.path = path
        self.fault = ReadFault(f"{path}: damaged after 0 messages "
                               f"({without_path(str(exc), path)})", 0)
        self._start = self._end = at_ns

    @property
    def topics(self) -> list[TopicInfo]:
        return []

    def messages(self, topics: Iterable[str], start_ns: int | None = None,
                 end_ns: int | None = None) -> Iterator[RawMessage]:
        return iter(())

    def deserialize(self, raw: RawMessage) -> Any:  # pragma: no cover - yields nothing
        raise ValueError(f"{self.path}: nothing to deserialise")


def without_path(message: str, path: Path) -> str:
    """A fault message without its leading ``path`` (an error that names the file adds it
    back); a file inside a recording folder keeps its own name."""
    for prefix in (f"{path}: ", f"{path}/"):  # the recording, or a file inside its folder
        if message.startswith(prefix):
            return message[len(prefix):]
    return message


def _parts(files: Sequence[Path], open_part: Callable[[Path], Recording]) -> list[Recording]:
    """The parts of a split recording opened in order; one that cannot be opened stands in the
    chain as its damage (no messages), and the parts after it are read."""
    out: list[Recording] = []
    first: RecordingError | None = None
    for f in files:
        try:
            out.append(open_part(f))
        except RecordingError as exc:
            first = first or exc
            out.append(_Unreadable(f, exc, out[-1].end_ns if out else None))
    if all(isinstance(p, _Unreadable) for p in out) and first is not None:
        raise first  # no part can be opened: the recording cannot be read
    return out


SPLIT_PARTS = "ros2 split parts"
"""The container of a ROS 2 bag's parts read without their metadata.yaml."""


def ros2_parts(path: Path, kinds: dict[str, list[Path]] | None = None) -> list[Path] | None:
    """The parts of one ROS 2 bag split by size or time whose metadata.yaml is missing (a
    recorder that was killed writes it only when it closes), in order; None otherwise.

    ``ros2 bag record`` names its parts ``NAME_0.db3``, ``NAME_1.db3``, ... (``.mcap`` with MCAP
    storage). So: two or more files of one kind and nothing else that is a recording, all one
    NAME with consecutive numbers. Like split ROS 1 bags, files named so are read as one
    recording; name them (a glob, or the files) to analyse them separately.
    """
    import re

    kinds = _folder_kinds(path) if kinds is None else kinds
    if len(kinds) != 1 or next(iter(kinds)) not in ("sqlite", "mcap"):
        return None
    (files,) = kinds.values()
    if len(files) < 2:
        return None
    parts = [re.fullmatch(r"(.+)_(\d+)\.(db3|mcap)", f.name) for f in files]
    if not all(parts):
        return None
    names = {m.group(1) for m in parts if m}
    numbers = [int(m.group(2)) for m in parts if m]
    if len(names) != 1 or sorted(numbers) != list(range(min(numbers), min(numbers) + len(files))):
        return None
    return [f for _, f in sorted(zip(numbers, files, strict=True))]


def recording_kind(path: Path) -> str | None:
    """``mcap``, ``bag`` or ``sqlite`` by the file's first bytes (its name is not trusted)."""
    try:
        head = _magic(path, 16)
    except OSError:
        return None
    return next((kind for magic, kind in _MAGIC.items() if head.startswith(magic)), None)


def _natural(p: Path) -> list[Any]:
    """Sort key putting run_2.bag before run_10.bag."""
    import re

    return [(0, int(s), "") if s.isdigit() else (1, 0, s) for s in re.split(r"(\d+)", p.name)]


def _mcap_profile(path: Path) -> str:
    try:
        from mcap.reader import make_reader

        with open(path, "rb") as fh:
            return str(make_reader(fh).get_header().profile)
    except Exception:
        return ""


def open_recording(path: Path | str, backend: str | None = None) -> Recording:
    """Open a recording with the registered backend that reads it (or the one named)."""
    path = Path(path)
    p = plan(path)
    name = backend or p.backend
    if name not in READERS:
        raise RecordingError(path, f"unknown reader backend {name!r}")
    if p.unzstd and name == MCAP_BACKEND:
        return READERS[name](path, p.files, p.container, unzstd=True)
    if p.unzstd:  # rosbags reads the bag folder and its metadata
        return READERS[name](path, [path], "ros2 bag folder")
    return READERS[name](path, p.files, p.container)


def _short(exc: BaseException) -> str:
    if type(exc).__name__ == "EndOfFile" and not str(exc).strip():  # mcap's, without a message
        return "cut short: the file ends inside a record"
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return text[:200]


def _damage_hint(path: Path) -> str:
    if path.suffix == ".bag":
        return "the bag may be unindexed or cut short; `rosbag reindex` repairs an unindexed bag"
    return "the recording may be damaged or cut short"
