"""Direct reader for ROS 2 sqlite3 (``.db3``) files that rosbags cannot open (a file cut short).

SQLite refuses a file shorter than the page count written in its header ("database disk image is
malformed") before any query runs, so rosbags yields nothing. With ``PRAGMA writable_schema=ON``
SQLite accepts the shorter file and reports damage only when a query reaches a missing or broken
page. The connection stays read-only and immutable (``mode=ro&immutable=1``, ``query_only``):
nothing is written to the recording and no -journal/-wal file or lock is created beside it.

Rows of ``messages`` are read in rowid order (the order the recorder inserted them), in bounded
chunks, up to the first damaged page; the messages before the damage are delivered and the damage
is reported as a :class:`ReadFault`, like the ROS 1 bag scan and the MCAP stream.
"""

from __future__ import annotations

import logging
import re
import sqlite3
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any
from urllib.parse import quote

from frontdiag.errors import RecordingError
from frontdiag.io.readers import (
    RawMessage,
    ReadFault,
    TopicInfo,
    _Base,
    _short,
    bag_compression,
    compressed_messages,
    unzstd,
)
from frontdiag.io.writer import normalise_msgtype, typestore

log = logging.getLogger(__name__)

CHUNK = 256  # rows per query: a statement never stays open across more than one chunk
SQLITE_MAGIC = b"SQLite format 3\x00"


def connect_readonly(path: Path) -> sqlite3.Connection:
    """An immutable read-only connection that also opens files shorter than their header says."""
    uri = f"file:{quote(str(path.resolve()))}?mode=ro&immutable=1"
    con = sqlite3.connect(uri, uri=True, check_same_thread=False)
    con.execute("PRAGMA query_only=ON")
    # Without it SQLite rejects a truncated file outright; with it, only the missing pages fail.
    con.execute("PRAGMA writable_schema=ON")
    return con


def header_shortfall(path: Path) -> int:
    """Bytes missing from ``path`` according to its sqlite header (0 when none or unknown)."""
    with open(path, "rb") as fh:
        head = fh.read(100)
    if len(head) < 100 or not head.startswith(SQLITE_MAGIC):
        return 0
    page_size = int.from_bytes(head[16:18], "big")
    page_size = 65536 if page_size == 1 else page_size
    n_pages = int.from_bytes(head[28:32], "big")
    # the in-header size is valid only when written by the same change as the counter
    if head[24:28] != head[92:96] or n_pages == 0:
        return 0
    return max(0, page_size * n_pages - path.stat().st_size)


def bag_files(folder: Path) -> list[Path]:
    """The .db3 files of a ROS 2 bag folder in recording order (metadata.yaml, else by name)."""
    meta = folder / "metadata.yaml"
    names: list[str] = []
    if meta.exists():
        try:
            import yaml

            info = yaml.safe_load(meta.read_text())["rosbag2_bagfile_information"]
            mode, _fmt = bag_compression(meta)
            if mode and not compressed_messages(meta):
                raise RecordingError(folder, f"compressed bag ({mode}) cannot be read past damage")
            names = [Path(p).name for p in info.get("relative_file_paths", [])]
        except RecordingError:
            raise
        except Exception:  # an unreadable metadata.yaml: fall back to the names on disk
            names = []
    files = [folder / n for n in names if n.endswith(".db3") and (folder / n).exists()]
    if files:
        return files

    def natural(p: Path) -> list[Any]:
        return [int(s) if s.isdigit() else s for s in re.split(r"(\d+)", p.name)]

    return sorted(folder.glob("*.db3"), key=natural)


class _File:
    """One .db3 file: its connection and its topics (id -> (topic, msgtype, format))."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.con = connect_readonly(path)
        try:
            rows = self.con.execute(
                "SELECT id, name, type, serialization_format FROM topics ORDER BY id").fetchall()
        except sqlite3.DatabaseError as exc:
            self.con.close()
            raise RecordingError(path, f"cannot read the topics table ({_short(exc)})",
                                 hint="the recording may be damaged or cut short") from exc
        self.topics = {int(i): (str(n), normalise_msgtype(str(t)), str(f))
                       for i, n, t, f in rows}
        self.msgdefs: dict[str, tuple[str, str]] = {}  # msgtype -> (encoding, text)
        try:
            for typ, enc, text in self.con.execute(
                    "SELECT topic_type, encoding, encoded_message_definition "
                    "FROM message_definitions"):
                if text:
                    self.msgdefs[normalise_msgtype(str(typ))] = (str(enc), str(text))
        except sqlite3.DatabaseError:  # older bags have no such table; a damaged one is optional
            pass

    def rows(self, columns: str, topic_ids: Sequence[int] | None) -> Iterator[tuple[Any, ...]]:
        """``(id, columns...)`` rows in rowid order; raises sqlite3.DatabaseError at the damage."""
        where = ""
        if topic_ids is not None:
            where = f" AND topic_id IN ({','.join(str(int(i)) for i in topic_ids)})"
        last = -(2**63)  # rowids are signed 64-bit
        chunk = CHUNK
        while True:
            cur = self.con.execute(
                f"SELECT id, {columns} FROM messages WHERE id > ?{where} ORDER BY id LIMIT ?",
                (last, chunk))
            got = 0
            try:
                for row in cur:
                    # a page missing from a cut file can read back as a row of NULLs
                    if row[0] is None or int(row[0]) <= last or None in row[1:]:
                        raise sqlite3.DatabaseError(f"unreadable row after message id {last}")
                    got += 1
                    last = int(row[0])
                    yield row
            except sqlite3.DatabaseError:
                # The cursor steps one row ahead, so the error can hide an intact row: go on
                # one row per query (LIMIT 1 never steps past its row) until the damage itself.
                if chunk == 1:
                    raise
                chunk = 1
                continue
            finally:
                cur.close()
            if got < chunk:
                return


class ScannedDb3(_Base):
    """A damaged ROS 2 sqlite3 recording (one .db3 or a bag folder of them), read by rowid."""

    backend = "db3-scan"

    def __init__(self, path: Path, files: Sequence[Path], unzstd: bool = False) -> None:
        self.path = path
        self.fault: ReadFault | None = None
        self._unzstd = unzstd  # each message compressed on its own (--compression-mode message)
        self._files: list[_File] = []
        try:
            for file in files:
                self._files.append(_File(file))
        except RecordingError:
            self.close()
            raise
        self._types: dict[str, tuple[str, str]] = {}  # topic -> (msgtype, format)
        for f in self._files:
            for topic, msgtype, fmt in f.topics.values():
                self._types.setdefault(topic, (msgtype, fmt))
        self._counts: dict[str, int] = dict.fromkeys(self._types, 0)
        self._start: int | None = None
        self._end: int | None = None
        self._typestores: dict[str, Any] = {}
        self._scan()

    def _scan(self) -> None:
        """One pass over the rows (not their payloads): counts, time span, and any damage."""
        n = 0
        for f in self._files:
            try:
                for _, tid, t in f.rows("topic_id, timestamp", None):
                    topic = f.topics.get(int(tid))
                    if topic is None:
                        continue
                    self._counts[topic[0]] += 1
                    t = int(t)
                    self._start = t if self._start is None else min(self._start, t)
                    self._end = t if self._end is None else max(self._end, t)
                    n += 1
            except sqlite3.DatabaseError as exc:
                self._damaged(f, n, exc)
                return
            missing = header_shortfall(f.path)
            if missing:
                self._damaged(f, n, f"{missing} bytes shorter than its header says")
                return

    def _damaged(self, f: _File, n: int, why: BaseException | str) -> None:
        text = _short(why) if isinstance(why, BaseException) else why
        where = f"{f.path.name}: " if f.path != self.path else ""
        self.fault = ReadFault(f"{self.path}: damaged after {n} messages ({where}{text})", n)

    @property
    def topics(self) -> list[TopicInfo]:
        return [TopicInfo(t, mt, self._counts.get(t, 0), fmt)
                for t, (mt, fmt) in self._types.items()]

    def messages(self, topics: Iterable[str], start_ns: int | None = None,
                 end_ns: int | None = None) -> Iterator[RawMessage]:
        """Messages in recording (rowid) order up to the first damaged page."""
        wanted = set(topics)
        if not wanted:
            return
        n = 0
        for f in self._files:
            ids = [i for i, (topic, _, _) in f.topics.items() if topic in wanted]
            if not ids:
                continue
            try:
                for _, tid, t, data in f.rows("topic_id, timestamp, data", ids):
                    t = int(t)
                    if (start_ns is not None and t < start_ns) or \
                            (end_ns is not None and t > end_ns):
                        continue
                    topic, msgtype, fmt = f.topics[int(tid)]
                    n += 1
                    yield RawMessage(topic, msgtype, t, unzstd(data) if self._unzstd else data,
                                     (f, fmt))
            except sqlite3.DatabaseError as exc:
                self._damaged(f, n, exc)
                log.info("%s", self.fault.message if self.fault else exc)
                return

    def deserialize(self, raw: RawMessage) -> Any:
        f, fmt = raw.key
        if fmt != "cdr":
            raise ValueError(f"serialization format {fmt!r} is not supported (cdr)")
        return self._typestore_for(f, raw.msgtype).deserialize_cdr(raw.data, raw.msgtype)

    def _typestore_for(self, f: _File, msgtype: str) -> Any:
        """The recording's own definition of ``msgtype`` when it has one (as rosbags uses it)."""
        ts = self._typestores.get(msgtype)
        if ts is not None:
            return ts
        ts = typestore(2)
        definition = f.msgdefs.get(msgtype)
        if definition is not None:
            try:
                ts = _store_from_definition(msgtype, *definition)
            except Exception:  # an unparsable stored definition: the standard one decodes it
                log.debug("cannot parse the stored definition of %s", msgtype, exc_info=True)
                ts = typestore(2)
        self._typestores[msgtype] = ts
        return ts

    def close(self) -> None:
        for f in self._files:
            f.con.close()
        self._files = []


def _store_from_definition(msgtype: str, encoding: str, text: str) -> Any:
    from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore

    types: dict[str, Any] = {}
    if encoding == "ros2idl":
        sep = "=" * 80 + "\n"
        parts = text.split(sep)[1:] if text.startswith(f"{sep}IDL: ") else [text]
        for part in parts:
            idl = part.split("\n", 1)[1] if part.startswith("IDL: ") else part
            types.update(get_types_from_idl(idl))
    else:
        types.update(get_types_from_msg(text, msgtype))
    ts = get_typestore(Stores.EMPTY)
    ts.register(types)
    if msgtype not in ts.types:
        raise ValueError(f"definition does not hold {msgtype}")
    return ts
