"""Fault injection: damaged and odd recordings of every container meet one contract.

Exit 0/1 with every readable frame, or exit 2 with one line naming the file and the damage, the
frames before it kept in --out; never exit 3, a traceback, a hang or a changed input. The
hand-made cases pin what "every readable frame" means for the damage recorders really produce;
the hypothesis run throws cut points, bit flips, zero runs and bad lengths at every container on
a bounded, derandomised budget (``benchmarks/fuzz_inputs.py`` runs the long campaign).
"""

from __future__ import annotations

import contextlib
import io
import os
import struct
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from damage import (
    DAMAGE,
    FRAMES,
    GOOD,
    SOURCES,
    Outcome,
    copy_recording,
    damaged_copy,
    fingerprint,
    make_source,
    odd_copies,
    one_error_line,
    storage_file,
)
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from recording_factory import T0, write_recording

from frontdiag.cli import main
from frontdiag.io.bag_scan import read_layout


def analyze(rec: Path, out: Path, *extra: str) -> Outcome:
    """Run `frontdiag analyze` in-process; rows are those written to --out."""
    before = fingerprint(rec)
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main(["analyze", str(rec), "--out", str(out), "--fail-on", "never", "-q",
                     "--no-rules", *extra])
    frames = out / "frames.parquet"
    rows = len(pd.read_parquet(frames)) if frames.exists() else 0
    return Outcome(code, rows, err.getvalue(), fingerprint(rec) != before, str(rec))


@pytest.fixture(scope="module")
def sources(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("sources")
    return {c: make_source(root / c, c) for c in SOURCES}


# -- hand-made damage, with the frames that must survive it -------------------------------------

def _camera_counts(bag: Path) -> list[int]:
    """Camera messages per chunk, from the bag's chunk-info records."""
    lay = read_layout(bag)
    conns = {cid: info[0] for cid, info in lay.connections}
    cam = [cid for cid, t in conns.items() if t == "/cam/image_raw"]
    return [sum(c.counts.get(cid, 0) for cid in cam) for c in lay.chunks]


def test_a_bag_cut_at_a_chunk_boundary_keeps_the_chunks_before_it(
        sources: dict[str, Path], tmp_path: Path) -> None:
    src = sources["bag"]
    lay = read_layout(src)
    assert len(lay.chunks) >= 3
    keep = sum(_camera_counts(src)[:2])
    cut = tmp_path / "cut.bag"
    cut.write_bytes(src.read_bytes()[:lay.chunks[2].pos])  # cleanly between records
    o = analyze(cut, tmp_path / "o")
    assert o.code == 2 and o.rows == keep
    assert "index" in (one_error_line(o.err) or "")
    info_err = io.StringIO()
    with contextlib.redirect_stderr(info_err), contextlib.redirect_stdout(io.StringIO()):
        assert main(["info", str(cut)]) == 2  # info shows the damage and does not pass it


@pytest.mark.parametrize("container", ["bag", "mcap", "mcap-ros1"])
def test_half_a_gigabyte_of_zeros_after_the_cut_is_damage_found_at_once(
        sources: dict[str, Path], tmp_path: Path, container: str) -> None:
    rec = copy_recording(sources[container], tmp_path / ("z_" + sources[container].name))
    f = storage_file(rec)
    data = f.read_bytes()
    with open(f, "wb") as fh:  # sparse: 512 MiB of zeros that take no disk space
        fh.write(data[:len(data) * 2 // 3])
        fh.truncate(len(data) * 2 // 3 + (512 << 20))
    o = analyze(rec, tmp_path / "o")
    assert o.code == 2 and o.rows > 0, o.err
    assert "zeros" in (one_error_line(o.err) or ""), o.err


def test_zero_padding_after_an_intact_bag_is_reported_with_every_frame(
        sources: dict[str, Path], tmp_path: Path) -> None:
    rec = tmp_path / "padded.bag"
    rec.write_bytes(sources["bag"].read_bytes() + bytes(100_000))
    o = analyze(rec, tmp_path / "o")
    assert o.code == 2 and o.rows == FRAMES and "zeros" in o.err


def test_an_unknown_chunk_op_is_damage_not_an_empty_pass(sources: dict[str, Path],
                                                         tmp_path: Path) -> None:
    data = bytearray(sources["bag"].read_bytes())
    pos = read_layout(sources["bag"]).chunks[1].pos
    i = data.index(b"op=\x05", pos)
    data[i + 3] = 0x09
    rec = tmp_path / "badop.bag"
    rec.write_bytes(bytes(data))
    o = analyze(rec, tmp_path / "o")
    assert o.code == 2 and o.rows == _camera_counts(sources["bag"])[0]
    assert "0x09" in o.err


def test_a_db3_missing_its_last_byte_is_reported(sources: dict[str, Path], tmp_path: Path) -> None:
    rec = copy_recording(sources["ros2-db3"], tmp_path / "short_db3")
    f = storage_file(rec)
    f.write_bytes(f.read_bytes()[:-1])
    o = analyze(rec, tmp_path / "o")
    assert o.code == 2 and o.rows > 0 and one_error_line(o.err)


def _split_bags(tmp_path: Path, parts: int, cut: int, n: int = 8) -> Path:
    """A folder of ``parts`` split ROS 1 bags of ``n`` frames each (run_0.bag, ...), part
    ``cut`` cut in half."""
    folder = tmp_path / "split"
    folder.mkdir()
    for k in range(parts):
        bag = write_recording(tmp_path / f"run_{k}.bag", "bag", n=n,
                              stamps=[T0 + (k * n + i) * 50_000_000 for i in range(n)])
        data = bag.read_bytes()
        (folder / bag.name).write_bytes(data[:len(data) // 2] if k == cut else data)
    return folder


def test_a_split_bag_folder_with_a_cut_last_part_keeps_the_earlier_parts(
        tmp_path: Path) -> None:
    o = analyze(_split_bags(tmp_path, 2, cut=1), tmp_path / "o")
    assert o.code == 2 and o.rows >= 8
    assert "run_1.bag" in (one_error_line(o.err) or "")


def test_a_damaged_middle_part_costs_only_its_own_messages(tmp_path: Path) -> None:
    """Three split ROS 1 parts, the middle one cut in half: the parts before and after it are
    analysed, the error line names the middle part and says reading went on."""
    o = analyze(_split_bags(tmp_path, 3, cut=1), tmp_path / "o")
    line = one_error_line(o.err) or ""
    assert o.code == 2 and "run_1.bag" in line and "reading went on with the 1 part(s)" in line
    assert "frames, before it and in the parts after it, were analysed" in o.err
    t = pd.read_parquet(tmp_path / "o" / "frames.parquet")
    stamps = set(t["t_ns"].tolist())
    assert {T0 + i * 50_000_000 for i in range(8)} <= stamps  # the first part, whole
    assert {T0 + (16 + i) * 50_000_000 for i in range(8)} <= stamps  # the last part, whole
    assert len(stamps) < 24  # the cut part lost its tail


def _mcap_records(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, length) of the top-level records of an MCAP file."""
    out, pos = [], 8
    while pos + 9 <= len(data):
        op, length = data[pos], struct.unpack_from("<Q", data, pos + 1)[0]
        out.append((pos, op, length))
        if op == 0x02:  # footer
            break
        pos += 9 + length
    return out


def test_an_unchunked_mcap_with_one_bad_length_keeps_the_frames_before_it(
        tmp_path: Path) -> None:
    rec = write_recording(tmp_path / "flat.mcap", "mcap", n=40, chunk_bytes=0)
    data = bytearray(rec.read_bytes())
    messages = [r for r in _mcap_records(bytes(data)) if r[1] == 0x05]
    pos, _, length = messages[60]  # image + CameraInfo per frame: the 31st image
    struct.pack_into("<Q", data, pos + 1, length + 10_000_000)
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    o = analyze(bad, tmp_path / "o")
    assert o.code == 2 and o.rows == 30, o.err


def test_a_bag_whose_index_data_lies_is_read_by_its_chunk_info(sources: dict[str, Path],
                                                               tmp_path: Path) -> None:
    data = bytearray(sources["bag"].read_bytes())
    i = data.index(b"op=\x04")  # the first index-data record, after chunk 0
    j = data.index(b"count=", i)
    (count,) = struct.unpack_from("<I", data, j + 6)
    struct.pack_into("<I", data, j + 6, count + 5)
    rec = tmp_path / "liar.bag"
    rec.write_bytes(bytes(data))
    o = analyze(rec, tmp_path / "o")
    assert o.code == 0 and o.rows == FRAMES, o.err


def test_a_bag_whose_index_connection_is_damaged_is_read_record_by_record(
        sources: dict[str, Path], tmp_path: Path) -> None:
    """Zeros over the data of the index's first connection record (found by a fault-injection
    campaign: it ended in an internal error). The index cannot be used, so the bag is read
    from the start: every frame, then the damage named, exit 2."""
    data = bytearray(sources["bag"].read_bytes())
    at = read_layout(sources["bag"]).index_pos
    (hlen,) = struct.unpack_from("<I", data, at)
    d0 = at + 4 + hlen
    (dlen,) = struct.unpack_from("<I", data, d0)
    data[d0 + 4:d0 + 4 + dlen] = bytes(dlen)
    rec = tmp_path / "badconn.bag"
    rec.write_bytes(bytes(data))
    o = analyze(rec, tmp_path / "o")
    assert o.code == 2 and o.rows == FRAMES, o.err
    assert "index damaged" in (one_error_line(o.err) or "")


@pytest.mark.parametrize("container", list(SOURCES))
def test_damage_early_in_the_file_is_named_not_no_topics(
        sources: dict[str, Path], tmp_path: Path, container: str) -> None:
    rec = damaged_copy(sources[container], tmp_path / ("early_" + sources[container].name),
                       "cut", 0.0, 0.0)
    storage = storage_file(rec)
    storage.write_bytes(storage_file(sources[container]).read_bytes()[:300])
    o = analyze(rec, tmp_path / "o")
    line = one_error_line(o.err)
    assert o.code == 2 and line is not None, o.err
    assert str(rec) in line and "no usable sensor topics" not in line, line


@pytest.mark.parametrize("container", list(SOURCES))
def test_valid_recordings_are_read_whatever_their_name(
        sources: dict[str, Path], tmp_path: Path, container: str) -> None:
    for rec in odd_copies(sources[container], tmp_path, container):
        o = analyze(rec, tmp_path / ("o_" + rec.parent.name))
        assert o.code == 0 and o.rows == FRAMES, (rec, o.err)


# -- nothing analysed must not pass -------------------------------------------------------------

def _planar_clouds(path: Path, n: int = 10, rays: int = 541) -> Path:
    from frontdiag.io.writer import RecordingWriter
    from frontdiag.lidar.synth import hall_scene, planar_scan, pointcloud2_dict

    scene = hall_scene()
    with RecordingWriter(path, "mcap") as w:
        for i in range(n):
            pose = np.eye(4)
            pose[0, 3] = 0.05 * i
            scan = planar_scan(scene, n_rays=rays, pose0=pose, seed=i)
            r = np.asarray(scan["ranges"], dtype=np.float64)
            ang = scan["angle_min"] + scan["angle_increment"] * np.arange(len(r))
            ok = np.isfinite(r)
            cols = {"x": (r * np.cos(ang))[ok].astype(np.float32),
                    "y": (r * np.sin(ang))[ok].astype(np.float32),
                    "z": np.zeros(int(ok.sum()), np.float32)}
            t = T0 + i * 100_000_000
            w.write("/scan_cloud", "sensor_msgs/msg/PointCloud2",
                    pointcloud2_dict(cols, t_ns=t), t)
    return path


def test_a_planar_pointcloud2_is_registered_as_a_2d_scan(tmp_path: Path) -> None:
    rec = _planar_clouds(tmp_path / "planar.mcap")
    o = analyze(rec, tmp_path / "o")
    assert o.code == 0, o.err
    df = pd.read_parquet(tmp_path / "o" / "frames.parquet")
    assert (df["status"] != "too_few_points").all()
    assert df["icp_fitness"].notna().sum() == len(df) - 1
    import json

    cov = json.loads((tmp_path / "o" / "manifest.json").read_text())["coverage"]["/scan_cloud"]
    assert cov["frames_present"] == 10 and cov["frames_analysed"] == 10


def test_an_analysis_that_measured_nothing_is_exit_2_naming_the_topic(tmp_path: Path) -> None:
    rec = _planar_clouds(tmp_path / "sparse.mcap", rays=5)  # 5 points: nothing to register
    o = analyze(rec, tmp_path / "o")
    line = one_error_line(o.err) or ""
    assert o.code == 2 and "/scan_cloud" in line and "too_few_points" in line, o.err
    assert o.rows == 10  # the rows are still written: they show why


def test_a_topic_without_messages_is_exit_2_naming_it(tmp_path: Path) -> None:
    from rosbags.rosbag2 import Writer

    from frontdiag.io.writer import typestore

    folder = tmp_path / "empty_db3"
    with Writer(folder, version=9) as w:
        w.add_connection("/cam/image_raw", "sensor_msgs/msg/Image", typestore=typestore(2))
    o = analyze(folder, tmp_path / "o")
    line = one_error_line(o.err) or ""
    assert o.code == 2 and "/cam/image_raw" in line and "no messages" in line, o.err


# -- the bounded random campaign ------------------------------------------------------------------

CASES = int(os.environ.get("FD_FUZZ_CASES", "150"))  # ~0.2 s of CPU each


@settings(max_examples=CASES, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(container=st.sampled_from(sorted(SOURCES)), kind=st.sampled_from(sorted(DAMAGE)),
       a=st.floats(0.0, 0.999), b=st.floats(0.0, 0.999))
def test_random_damage_meets_the_contract(sources: dict[str, Path], tmp_path: Path,
                                          container: str, kind: str, a: float, b: float) -> None:
    import shutil
    import uuid

    case = tmp_path / uuid.uuid4().hex[:8]
    try:
        rec = damaged_copy(sources[container], case / sources[container].name, kind, a, b)
        o = analyze(rec, case / "out")
        assert o.klass in GOOD, (o.klass, o.err)
    finally:
        shutil.rmtree(case, ignore_errors=True)



# -- damage inside intact containers: the decoders' payloads --------------------------------------

@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("source", ["video", "json-image", "pb-image", "velo-mcap"])
def test_damaged_payloads_meet_the_contract(tmp_path: Path, source: str, seed: int) -> None:
    """H.264 pictures, Foxglove image fields and Velodyne packets damaged inside valid MCAP
    files (``benchmarks/fuzz_payloads.py`` runs the long campaign). Seeds whose damage the
    writer refuses are skipped, not counted as passes."""
    import random

    from payload_damage import NOT_WRITABLE_ERRORS, PAYLOAD_SOURCES

    suffix, make = PAYLOAD_SOURCES[source]
    rec = tmp_path / f"{source}{suffix}"
    try:
        make(rec, random.Random(f"1-{source}-{seed}"))
    except NOT_WRITABLE_ERRORS:
        pytest.skip("the writer refuses this damage")
    o = analyze(rec, tmp_path / "out")
    assert o.klass in GOOD, (o.klass, o.err)
    if source == "video":  # decoding starts at the keyframe before --start, past damage
        o = analyze(rec, tmp_path / "late", "--start", "0.4")
        assert o.klass in GOOD, (o.klass, o.err)
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["info", str(rec)]) == 0  # keyframe spacing, Velodyne model: read anyway
