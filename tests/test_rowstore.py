"""The rows of a pass packed into chunks give the table of the rows held as dicts."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
from recording_factory import write_recording

from frontdiag import rowstore
from frontdiag.api import AnalysisOptions, run_analysis
from frontdiag.rowstore import RowStore, add_values, canonical_types

SAMPLES = Path(__file__).resolve().parents[1] / "sample_logs"


def _rows(n: int, seed: int) -> list[dict[str, Any]]:
    """Rows of the kinds a pass makes: camera and LiDAR rows with different keys, ints, floats,
    NaN, None, strings, booleans and lists, and keys that only some rows carry."""
    rng = np.random.default_rng(seed)
    out: list[dict[str, Any]] = []
    for i in range(n):
        if rng.random() < 0.3:
            row: dict[str, Any] = {"frame": i, "t_ns": 10 * i, "sensor": "lidar", "topic": "/l",
                                   "lidar_cond": float(rng.random()),
                                   "lidar_weak_vec": [1.0, 0.0, 0.0] if rng.random() < 0.5
                                   else None, "lidar_ok": bool(rng.random() < 0.5),
                                   "lidar_weak_axis": "x" if rng.random() < 0.1 else None}
        else:
            row = {"frame": i, "t_ns": 10 * i, "sensor": "camera", "topic": "/c",
                   "n_keypoints": int(rng.integers(0, 1000)),
                   "h_over_e": float("nan") if rng.random() < 0.3 else float(rng.random()),
                   "ref_frame": -1 if rng.random() < 0.5 else i - 1,
                   "keyframe_reason": str(rng.choice(["", "tracked_share", "parallax"])),
                   "status": "ok", "ms_total": float(rng.random())}
            if rng.random() < 0.2:
                row["rot_only_px"] = float(rng.random())
            if rng.random() < 0.1:
                row["span_dt_s"] = 0.33 if rng.random() < 0.5 else 1  # an int among floats
        out.append(row)
    return out


def _whole(rows: list[dict[str, Any]]) -> pd.DataFrame:
    return canonical_types(pd.DataFrame.from_records(rows))


@pytest.mark.parametrize("chunk", [1, 2, 3, 7, 64])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_packed_rows_give_the_table_of_the_rows_as_dicts(chunk: int, seed: int) -> None:
    """Whatever the chunks, the table of all the rows at once (a list column reads None where
    a row has no value, whether it said None or lacked the key)."""
    rows = _rows(150, seed)
    store = RowStore(chunk)
    for r in rows:
        store.append(dict(r))
        store.settled()
    assert len(store) == len(rows)
    pd.testing.assert_frame_equal(store.frame(), _whole(rows))
    assert len(store) == 0  # emptied as the table is built


def test_a_packed_row_is_completed_like_a_held_one() -> None:
    rows = _rows(40, 3)
    store = RowStore(4)
    for r in rows:
        store.append(dict(r))
        store.settled()
    # a time added, a reading set, a column no row had, a value of another type
    for pos, values in [(1, {"ms_total": 2.5, "rot_only_px": 0.7}),
                        (9, {"ms_diagnostic": 1.25, "h_over_e_2kf": 0.9}),
                        (17, {"n_keypoints": 3.5}), (39, {"ms_total": 1.0})]:
        store.update(pos, values)
        add_values(rows[pos], values)
    pd.testing.assert_frame_equal(store.frame(), _whole(rows))


def _store(rows: list[dict[str, Any]], chunk: int) -> RowStore:
    store = RowStore(chunk)
    for r in rows:
        store.append(dict(r))
    return store


def test_stores_join_and_cut_at_a_frame() -> None:
    rows = _rows(60, 4)
    a, b = _store(rows[:25], 5), _store(rows[25:], 5)
    a.compact()  # packed, then followed by rows still held
    b.settled()
    a.extend(b)
    a.extend(_store(_rows(3, 5), 5))
    pd.testing.assert_frame_equal(
        a.frame(), _whole(rows + _rows(3, 5)))
    c = _store(rows, 8)
    c.compact()
    c.extend(_store(rows[:5], 8))
    want = [r for r in rows + rows[:5] if r["frame"] > 30]
    pd.testing.assert_frame_equal(c.after_frame(30).frame(), _whole(want))


def _spy(monkeypatch: pytest.MonkeyPatch, chunk: int) -> dict[str, int]:
    """Pack every ``chunk`` rows, and count the packs and the completions of packed rows."""
    seen = {"packs": 0, "late": 0}
    monkeypatch.setattr(rowstore, "CHUNK_ROWS", chunk)
    compact, update = RowStore.compact, RowStore.update

    def counted_compact(self: RowStore) -> None:
        seen["packs"] += bool(self._tail)
        compact(self)

    def counted_update(self: RowStore, pos: int, values: dict[str, Any]) -> None:
        seen["late"] += pos < self._packed
        update(self, pos, values)

    monkeypatch.setattr(RowStore, "compact", counted_compact)
    monkeypatch.setattr(RowStore, "update", counted_update)
    return seen


def _same(a: pd.DataFrame, b: pd.DataFrame) -> None:
    cols = [c for c in a.columns if not c.startswith("ms_")]
    assert list(a.columns) == list(b.columns)
    pd.testing.assert_frame_equal(a[cols], b[cols])


@pytest.mark.parametrize("log", ["parked_panning", "planar_approach.mcap",
                                 "dock_corridor.mcap"])
def test_a_pass_packed_in_small_chunks_gives_the_same_table(
        monkeypatch: pytest.MonkeyPatch, log: str) -> None:
    """The pass packs rows only where the frontend can no longer complete them: no packed row
    is ever completed (a rotation scene, a planar one with its deferred readings, camera and
    LiDAR), and the table equals the one built from the rows held as dicts."""
    whole = run_analysis(SAMPLES / log, AnalysisOptions(rules=False)).table
    seen = _spy(monkeypatch, 3)
    packed = run_analysis(SAMPLES / log, AnalysisOptions(rules=False)).table
    assert seen["packs"] >= 5 and seen["late"] == 0
    _same(whole, packed)


@pytest.mark.parametrize("still_to", [0, 125], ids=["moving", "still-then-moving"])
def test_windows_packed_in_small_chunks_stitch_into_the_serial_table(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, still_to: int) -> None:
    """The windows of a split run, each packed as a worker packs it, stitched in order. Still,
    then moving: the second window's warm-up, still, does not meet the first window's state,
    so it is continued from it; the two meet once the camera moves (frame 139), and the rows
    of the window's own run are cut there, inside a packed chunk. (Run in this process: a
    worker process would not see the small chunks.)"""
    import recording_factory

    from frontdiag.api import _table, calibration_for_images
    from frontdiag.camera.frontend import CameraParams
    from frontdiag.io.readers import open_recording
    from frontdiag.io.topics import choose_topics
    from frontdiag.parallel import _stitch, _task, plan_windows, window_overlap

    moving = recording_factory.frame
    monkeypatch.setattr(recording_factory, "frame", lambda i, *a, **k: moving(
        max(0, i - still_to), *a, **k))
    path = write_recording(tmp_path / "run.mcap", "mcap", n=200)
    serial = run_analysis(path, AnalysisOptions(rules=False)).table
    opts = AnalysisOptions(jobs=2, rules=False)
    with open_recording(path) as rec:
        choice = choose_topics(rec.topics)
        intr = calibration_for_images(rec, choice, opts, [])
    windows = plan_windows(200, 2, window_overlap(CameraParams()))
    seen = _spy(monkeypatch, 4)
    cut_at = RowStore.after_frame
    cuts: list[int] = []

    def counted_cut(self: RowStore, frame: int) -> RowStore:
        cuts.append(len(self._chunks))
        return cut_at(self, frame)

    monkeypatch.setattr(RowStore, "after_frame", counted_cut)
    runs: list[Any] = [_task(path, choice, opts, intr, w) for w in windows]
    rows, _, fault, cut, _ = _stitch(path, choice, opts, intr, windows, runs)
    assert fault is None and not cut and seen["packs"] >= 10 and seen["late"] == 0
    assert (len(cuts) == 1 and cuts[0] > 0) if still_to else not cuts, cuts
    _same(serial, _table(rows))
