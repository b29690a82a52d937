"""The rows of a pass, held compactly once they can no longer change.

A row as the frontend makes it is a dict of about 90 Python objects: some 4 KB. A pass over an
hour of 30 Hz video makes 108 000 of them; held as dicts they outweighed everything else the
process holds, and grew with the recording. :class:`RowStore` keeps the newest rows as dicts,
where the frontend may still complete them (readings taken when a keyframe interval closes),
and packs the rest, every ``CHUNK_ROWS`` rows, once its owner says that no row made so far can
change (:meth:`RowStore.settled`).

A packed chunk is the pickle of its rows, compressed by zlib (about 0.3 KB a row on real
recordings, 0.65 KB uncompressed): exact, so a chunk can be cut at
a frame or a row in it completed later, needs only the standard library (a window worker packs
its rows without loading pandas, and they cross to the main process as bytes), and becomes a
DataFrame only when the table is built (:meth:`RowStore.frame`). That table is the one
``pd.DataFrame.from_records`` gives for all the rows at once, whatever the chunks
(:func:`canonical_types`; tests/test_rowstore.py).
"""

from __future__ import annotations

import pickle
import zlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import pandas as pd

CHUNK_ROWS = 2048
"""Rows per packed chunk. Per 1 000 real rows (KITTI 02): packing 6.8 ms (1.2 without zlib),
unpacking into a DataFrame 8.7 ms (7.1)."""


def add_values(row: dict[str, Any], values: dict[str, Any]) -> None:
    """Complete ``row`` with readings taken later: ``ms_*`` times add to what the row holds,
    other columns are set."""
    for k, v in values.items():
        row[k] = row.get(k, 0.0) + v if k.startswith("ms_") else v


PACK_LEVEL = 1
"""zlib's level for a packed chunk: the pickle of real rows (KITTI 02, 627 bytes a row) shrinks
2.1× at level 1 (293 bytes), 2.4× at level 6 at seven times the time."""


def _pack(rows: list[dict[str, Any]]) -> tuple[int, bytes]:
    return len(rows), zlib.compress(pickle.dumps(rows, protocol=pickle.HIGHEST_PROTOCOL),
                                    PACK_LEVEL)


def _unpack(chunk: tuple[int, bytes]) -> list[dict[str, Any]]:
    # bytes this process or its worker packed
    rows: list[dict[str, Any]] = pickle.loads(zlib.decompress(chunk[1]))
    return rows


class RowStore:
    """Rows in the order they were made: the oldest packed, the newest as dicts. ``append``
    returns the row's position, by which ``update`` completes it later."""

    def __init__(self, chunk: int | None = None) -> None:
        self.chunk = max(1, chunk or CHUNK_ROWS)
        self._chunks: list[tuple[int, bytes]] = []  # (rows, compressed pickle of the rows)
        self._packed = 0  # rows in the chunks
        self._tail: list[dict[str, Any]] = []

    def __len__(self) -> int:
        return self._packed + len(self._tail)

    def append(self, row: dict[str, Any]) -> int:
        self._tail.append(row)
        return len(self) - 1

    def extend(self, other: RowStore) -> None:
        """Add another store's rows after these."""
        if other._chunks:
            self.compact()
            self._chunks.extend(other._chunks)
            self._packed += other._packed
        self._tail.extend(other._tail)

    def update(self, pos: int, values: dict[str, Any]) -> None:
        """Complete the row at ``pos`` (see :func:`add_values`)."""
        if pos >= self._packed:
            add_values(self._tail[pos - self._packed], values)
            return
        # a packed row: its owner said it could not change, so the passes of this package do
        # not come here; for any other owner the chunk is unpacked, completed and packed again
        at = pos
        for i, chunk in enumerate(self._chunks):
            if at < chunk[0]:
                rows = _unpack(chunk)
                add_values(rows[at], values)
                self._chunks[i] = _pack(rows)
                return
            at -= chunk[0]

    def settled(self) -> None:
        """No row made so far can change any more: pack the dicts if there are enough."""
        if len(self._tail) >= self.chunk:
            self.compact()

    def compact(self) -> None:
        """Pack every row held as a dict."""
        if self._tail:
            self._chunks.append(_pack(self._tail))
            self._packed += len(self._tail)
            self._tail = []

    def after_frame(self, frame: int) -> RowStore:
        """The rows whose ``frame`` is greater than ``frame``, as a new store."""
        out = RowStore(self.chunk)
        for chunk in self._chunks:
            kept = [r for r in _unpack(chunk) if r["frame"] > frame]
            if kept:
                out._chunks.append(_pack(kept))
                out._packed += len(kept)
        out._tail = [r for r in self._tail if r["frame"] > frame]
        return out

    def frame(self) -> pd.DataFrame:
        """All the rows as one table (no rows: no columns), the store emptied as it is built:
        each chunk is unpacked into a DataFrame of its own, then they are joined."""
        import pandas as pd

        self.compact()
        parts: list[pd.DataFrame] = []
        self._chunks.reverse()
        while self._chunks:  # each chunk's bytes let go as its DataFrame is made
            parts.append(pd.DataFrame.from_records(_unpack(self._chunks.pop())))
        self._packed = 0
        if not parts:
            return pd.DataFrame()
        return canonical_types(parts[0] if len(parts) == 1
                               else pd.concat(parts, ignore_index=True))


def canonical_types(df: pd.DataFrame) -> pd.DataFrame:
    """The column types a table of all the rows at once has, whatever the chunks were.

    A chunk whose rows hold only None in a column reads it as float NaN, one with a string or
    a list there as objects, so joined chunks can leave a column of objects where one table
    would have strings or floats: such columns are inferred again. Columns still holding
    objects (lists, booleans beside missing values) read None wherever a value is missing,
    whether the row said None or did not have the column."""
    import pandas as pd

    for col in [c for c in df.columns if df[c].dtype == object]:
        s = df[col].infer_objects()
        if s.dtype == object:
            s = pd.Series([None if v is None or (isinstance(v, float) and v != v) else v
                           for v in s], index=s.index, dtype=object)
        df[col] = s
    return df
