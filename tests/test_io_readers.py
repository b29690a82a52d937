"""Every container and every image encoding reads back to the same grey frames."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from recording_factory import CONTAINERS, DT, T0, K, cut_recording, frame, write_recording

from frontdiag.api import AnalysisOptions, iter_camera_frames
from frontdiag.errors import DecodeError, RecordingError, TopicError
from frontdiag.io.images import IMAGE_TYPES, GrayConverter
from frontdiag.io.readers import open_recording
from frontdiag.io.topics import choose_topics
from frontdiag.io.writer import build_message, image_msg, typestore


@pytest.mark.parametrize("container", list(CONTAINERS))
def test_every_container_reads_back(tmp_path: Path, container: str) -> None:
    fmt, name = CONTAINERS[container]
    path = write_recording(tmp_path / name, fmt, n=4)
    with open_recording(path) as rec:
        topics = {t.topic: t for t in rec.topics}
        assert topics["/cam/image_raw"].msgtype == "sensor_msgs/msg/Image"
        assert topics["/cam/image_raw"].count == 4
        assert topics["/cam/camera_info"].count == 4
        assert rec.start_ns == T0 and rec.end_ns == T0 + 3 * DT
        frames = list(iter_camera_frames(rec, "/cam/image_raw", "sensor_msgs/msg/Image"))
    assert [f.t_ns for f in frames] == [T0 + i * DT for i in range(4)]
    for i, f in enumerate(frames):
        np.testing.assert_array_equal(f.gray, frame(i))


@pytest.mark.parametrize(("fmt", "compression"), [
    ("bag", "bz2"), ("bag", "lz4"), ("ros2-db3", "file"), ("ros2-db3", "message"),
    ("ros2-mcap", "file"), ("ros2-mcap", "message")])
def test_compressed_recordings_read_as_the_plain_one(tmp_path: Path, fmt: str,
                                                     compression: str) -> None:
    """Compressed bag chunks (ROS 1) and zstd bags (ROS 2, the whole file or each message:
    ``ros2 bag record --compression-mode``) give the messages of the uncompressed recording.
    A message-compressed MCAP bag holds compressed payloads in an MCAP file, so it is read
    through the bag's metadata, not as a plain MCAP file."""
    from frontdiag.inspect import inspect_recording

    plain = write_recording(tmp_path / "plain", fmt, n=4)
    packed = write_recording(tmp_path / "packed", fmt, n=4, compression=compression)
    if (fmt, compression) == ("ros2-mcap", "message"):
        assert "zstd messages" in inspect_recording(packed).container
    topics = ["/cam/image_raw", "/cam/camera_info"]
    with open_recording(plain) as a, open_recording(packed) as b:
        assert b.fault is None
        ma, mb = list(a.messages(topics)), list(b.messages(topics))
        assert len(mb) == 8
        for x, y in zip(ma, mb, strict=True):
            assert (x.topic, x.log_ns) == (y.topic, y.log_ns)
            assert repr(a.deserialize(x)) == repr(b.deserialize(y))


@pytest.mark.parametrize(("fmt", "n"), [("ros2-db3", 150), ("ros2-mcap", 600)])
def test_a_message_compressed_bag_cut_short_keeps_the_messages_before_the_damage(
        tmp_path: Path, fmt: str, n: int) -> None:
    """A recorder killed mid-write with --compression-mode message: the messages before the
    damage are read and decompressed, as from an uncompressed bag (the MCAP bag needs more
    frames: its compressed messages fill fewer chunks)."""
    folder = write_recording(tmp_path / "bag", fmt, n=n, compression="message")
    (storage,) = [p for p in folder.iterdir() if p.name != "metadata.yaml"]
    data = storage.read_bytes()
    storage.write_bytes(data[: int(len(data) * 0.6)])
    with open_recording(folder) as rec:
        got = list(rec.messages(["/cam/image_raw"]))
        assert rec.fault is not None and 20 <= len(got) < n
        assert [m.log_ns for m in got] == [T0 + i * DT for i in range(len(got))]
        last = len(got) - 1
        gray = np.asarray(rec.deserialize(got[last]).data).reshape(120, 160)
        np.testing.assert_array_equal(gray, frame(last))


def test_a_file_compressed_part_without_its_bag_is_named_for_what_it_is(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A ROS 2 bag compressed per file whose metadata.yaml is missing (a killed recorder), or
    one of its parts passed alone: exit 2 with one line that says it is zstd-compressed and
    what to do, not "unknown container" or "several recordings need --out"."""
    from frontdiag.cli import main

    folder = write_recording(tmp_path / "bag", "ros2-db3", n=3, compression="file")
    (folder / "metadata.yaml").unlink()
    (part,) = folder.iterdir()
    with pytest.raises(RecordingError, match="zstd-compressed file") as exc:
        open_recording(part)
    assert "zstd -d" in (exc.value.hint or "")
    with pytest.raises(RecordingError, match=r"zstd-compressed parts .* but no metadata\.yaml"):
        open_recording(folder)
    assert main(["analyze", str(folder)]) == 2
    err = capsys.readouterr().err
    assert "zstd-compressed parts" in err and "--out" not in err and "Traceback" not in err


def _split_without_metadata(tmp: Path, fmt: str, n: int, per_part: int) -> Path:
    """The parts of one ROS 2 bag split every ``per_part`` frames, as a recorder killed
    before it wrote metadata.yaml leaves them: NAME_0.db3, NAME_1.db3, ... (or .mcap)."""
    from frontdiag.io.writer import RecordingWriter, image_msg

    folder = tmp / "killed"
    folder.mkdir()
    for k, first in enumerate(range(0, n, per_part)):
        part = tmp / f"part{k}"
        with RecordingWriter(part, fmt) as w:
            for i in range(first, min(first + per_part, n)):
                t = T0 + i * DT
                w.write("/cam/image_raw", "sensor_msgs/msg/Image",
                        image_msg(frame(i), "mono8", t), t)
        (storage,) = [p for p in part.iterdir() if p.name != "metadata.yaml"]
        storage.rename(folder / f"rosbag2_2026_11_28-06_00_00_{k}{storage.suffix}")
    return folder


@pytest.mark.parametrize("fmt", ["ros2-db3", "ros2-mcap"])
def test_split_ros2_parts_without_metadata_read_as_one_recording(tmp_path: Path,
                                                                 fmt: str) -> None:
    """A recorder killed mid-recording leaves its split parts without metadata.yaml: they are
    read in order as one recording; a part cut short costs only its own messages after the
    damage (a middle one: the parts after it are read too)."""
    from frontdiag.fleet import discover
    from frontdiag.inspect import inspect_recording
    from frontdiag.io.readers import plan

    folder = _split_without_metadata(tmp_path, fmt, 12, 5)
    # info says what it read it as (and, when the last part is cut below, where the damage is)
    assert inspect_recording(folder).container == "ros2 split parts (3 parts, no metadata.yaml)"
    ext = "db3" if fmt == "ros2-db3" else "mcap"
    assert [p.name.rsplit("_", 1)[1] for p in plan(folder).files] == [f"{k}.{ext}"
                                                                       for k in range(3)]
    assert discover([folder]) == [folder.resolve()]  # one recording, also in a fleet
    with open_recording(folder) as rec:
        got = list(rec.messages(["/cam/image_raw"]))
        assert [m.log_ns for m in got] == [T0 + i * DT for i in range(12)]
        assert rec.fault is None
        np.testing.assert_array_equal(
            np.asarray(rec.deserialize(got[7]).data).reshape(120, 160), frame(7))
    middle = sorted(folder.iterdir())[1]
    whole = middle.read_bytes()
    middle.write_bytes(whole[:300])  # cannot even be opened: its frames 5-9 are lost
    with open_recording(folder) as rec:
        got = list(rec.messages(["/cam/image_raw"]))
        assert [m.log_ns for m in got] == [T0 + i * DT for i in (*range(5), 10, 11)]
        assert rec.fault is not None and rec.fault.resumed
        assert middle.name in rec.fault.message and "after it" in rec.fault.message
    middle.write_bytes(whole)
    first = sorted(folder.iterdir())[0]
    whole = first.read_bytes()
    first.write_bytes(whole[:300])  # the first part too: the later parts are still read
    with open_recording(folder) as rec:
        got = list(rec.messages(["/cam/image_raw"]))
        assert [m.log_ns for m in got] == [T0 + i * DT for i in range(5, 12)]
        assert rec.fault is not None and rec.fault.resumed and first.name in rec.fault.message
    first.write_bytes(whole)
    last = sorted(folder.iterdir())[-1]
    last.write_bytes(last.read_bytes()[:300])
    with open_recording(folder) as rec:
        got = list(rec.messages(["/cam/image_raw"]))
        assert [m.log_ns for m in got] == [T0 + i * DT for i in range(10)]
        assert rec.fault is not None and last.name in rec.fault.message
        assert not rec.fault.resumed and "after it" not in rec.fault.message


def test_standalone_db3_without_metadata(tmp_path: Path) -> None:
    folder = write_recording(tmp_path / "bagdir", "ros2-db3", n=3)
    db3 = next(folder.glob("*.db3"))
    alone = tmp_path / "alone.db3"
    shutil.copy(db3, alone)
    with open_recording(alone) as rec:
        assert {t.topic for t in rec.topics} == {"/cam/image_raw", "/cam/camera_info"}
        assert len(list(rec.messages(["/cam/image_raw"]))) == 3


def test_standalone_mcap_from_ros2_folder(tmp_path: Path) -> None:
    folder = write_recording(tmp_path / "bagdir", "ros2-mcap", n=3)
    mc = next(folder.glob("*.mcap"))
    with open_recording(mc) as rec:
        assert len(list(rec.messages(["/cam/image_raw"]))) == 3


def test_folder_of_split_ros1_bags(tmp_path: Path) -> None:
    folder = tmp_path / "split"
    folder.mkdir()
    write_recording(folder / "a_0.bag", "bag", n=3)
    write_recording(folder / "a_1.bag", "bag", n=2,
                    stamps=[T0 + (3 + i) * DT for i in range(2)])
    with open_recording(folder) as rec:
        counts = {t.topic: t.count for t in rec.topics}
        assert counts["/cam/image_raw"] == 5


@pytest.mark.parametrize("encoding", ["mono8", "mono16", "rgb8", "bgr8", "rgba8", "bgra8",
                                      "rgb16", "bgra16", "jpeg", "png"])
def test_every_encoding_becomes_the_same_grey(tmp_path: Path, encoding: str) -> None:
    path = write_recording(tmp_path / "run.mcap", "mcap", n=2, encoding=encoding)
    with open_recording(path) as rec:
        img_topic = next(t for t in rec.topics if t.msgtype in IMAGE_TYPES)
        frames = list(iter_camera_frames(rec, img_topic.topic, img_topic.msgtype))
    assert len(frames) == 2
    tol = 3 if encoding == "jpeg" else 0
    diff = np.abs(frames[1].gray.astype(int) - frame(1).astype(int))
    assert np.mean(diff) <= tol


@pytest.mark.parametrize("encoding", ["bayer_rggb8", "bayer_bggr8", "bayer_gbrg8",
                                      "bayer_grbg8"])
def test_bayer_is_demosaiced(encoding: str) -> None:
    # A Bayer mosaic of a uniform grey patch demosaics to that grey.
    ts = typestore(2)
    mosaic = np.full((8, 8), 100, np.uint8)
    msg = build_message(ts, "sensor_msgs/msg/Image", image_msg(mosaic, encoding, 1))
    gray, enc = GrayConverter("/cam")(msg, "sensor_msgs/msg/Image")
    assert enc == encoding
    assert gray.shape == (8, 8)
    assert np.all(np.abs(gray.astype(int) - 100) <= 1)


@pytest.mark.parametrize("encoding,luma_at", [("yuv422", 1), ("uyvy", 1),
                                              ("yuv422_yuy2", 0), ("yuyv", 0)])
def test_packed_yuv422_gives_its_luma(encoding: str, luma_at: int) -> None:
    """UYVY ("yuv422") holds luma in the odd bytes, YUYV ("yuv422_yuy2") in the even ones; the
    chroma bytes (set far from the luma here) must not leak into the grey image."""
    ts = typestore(2)
    luma = np.arange(48, dtype=np.uint8).reshape(6, 8) * 5
    packed = np.full((6, 8, 2), 17, np.uint8)  # chroma 17
    packed[:, :, luma_at] = luma
    msg = build_message(ts, "sensor_msgs/msg/Image", image_msg(packed, encoding, 1))
    gray, enc = GrayConverter("/cam")(msg, "sensor_msgs/msg/Image")
    assert enc == encoding and gray.shape == (6, 8)
    assert np.array_equal(gray, luma)


@pytest.mark.parametrize("encoding,order", [("rgb16", "RGB"), ("bgr16", "BGR"),
                                            ("16uc3", "BGR"), ("rgba16", "RGBA"),
                                            ("bgra16", "BGRA"), ("16uc4", "BGRA")])
@pytest.mark.parametrize("bigendian", [0, 1])
def test_16_bit_colour_gives_the_grey_of_its_8_bit_twin(encoding: str, order: str,
                                                        bigendian: int) -> None:
    """A 12-bit colour picture (16 bits a channel, as machine-vision cameras send) is converted
    to grey at 16 bits and mapped by the run's fixed shift: the grey of the same picture at 8
    bits, to a grey level (OpenCV rounds the weighted sum at each depth)."""
    ts = typestore(2)
    rng = np.random.default_rng(7)
    c8 = rng.integers(0, 256, (6, 8, len(order)), dtype=np.uint8)
    c8[0, 0, :3] = 255  # the peak sets the shift: 12 bits -> 4
    code = getattr(cv2, f"COLOR_{order}2GRAY")
    want = cv2.cvtColor(np.ascontiguousarray(c8), code)
    c16 = c8.astype(np.uint16) << 4
    vals = image_msg(c16.astype(">u2" if bigendian else "<u2"), encoding, 1)
    vals["is_bigendian"] = bigendian
    msg = build_message(ts, "sensor_msgs/msg/Image", vals)
    conv = GrayConverter("/cam")
    gray, enc = conv(msg, "sensor_msgs/msg/Image")
    assert enc == encoding and gray.shape == (6, 8) and gray.dtype == np.uint8
    assert np.abs(gray.astype(int) - want.astype(int)).max() <= 1
    assert conv.mono16 is not None and conv.mono16["shift"] == 4


@pytest.mark.parametrize("encoding", ["bayer_rggb16", "bayer_bggr16", "bayer_gbrg16",
                                      "bayer_grbg16"])
def test_16_bit_bayer_is_demosaiced_like_its_8_bit_twin(encoding: str) -> None:
    """The same mosaic at 8 bits and scaled to 12 bits demosaics to the same grey: the
    pattern names map to OpenCV's codes as the 8-bit ones do."""
    ts = typestore(2)
    rng = np.random.default_rng(11)
    m8 = rng.integers(0, 256, (10, 12), dtype=np.uint8)
    m8[0, 0] = 255
    twin = encoding.replace("16", "8")
    g8, _ = GrayConverter("/cam")(build_message(ts, "sensor_msgs/msg/Image",
                                               image_msg(m8, twin, 1)), "sensor_msgs/msg/Image")
    m16 = m8.astype(np.uint16) << 4
    g16, enc = GrayConverter("/cam")(build_message(ts, "sensor_msgs/msg/Image",
                                                  image_msg(m16, encoding, 1)),
                                     "sensor_msgs/msg/Image")
    assert enc == encoding and g16.shape == (10, 12)
    # demosaicing interpolates at 16 bits, then the shift drops 4 of them: within a level
    assert np.abs(g16.astype(int) - g8.astype(int)).max() <= 1


@pytest.mark.parametrize("encoding", ["nv12", "nv21"])
@pytest.mark.parametrize("h", [6, 7])
def test_semi_planar_yuv420_gives_its_luma_plane(encoding: str, h: int) -> None:
    """NV12 / NV21 hold ``height`` rows of luma, then ceil(height / 2) rows of interleaved
    chroma: grey is the luma plane, whatever the chroma holds; a message cut inside the chroma
    plane is damaged, named by its field."""
    ts = typestore(2)
    w, step = 8, 10  # rows padded beyond the width
    luma = (np.arange(h * w, dtype=np.uint8).reshape(h, w) * 3) + 7
    buf = np.full((h + (h + 1) // 2, step), 201, np.uint8)  # chroma and padding far from luma
    buf[:h, :w] = luma
    vals = image_msg(buf, encoding, 1)
    vals.update(height=h, width=w, step=step)
    msg = build_message(ts, "sensor_msgs/msg/Image", vals)
    gray, enc = GrayConverter("/cam")(msg, "sensor_msgs/msg/Image")
    assert enc == encoding and np.array_equal(gray, luma)
    vals["data"] = vals["data"][: step * h + step]  # the chroma plane cut after one row
    msg = build_message(ts, "sensor_msgs/msg/Image", vals)
    with pytest.raises(DecodeError, match=r"topic /cam: field data.*step\*height\*1.5"):
        GrayConverter("/cam")(msg, "sensor_msgs/msg/Image")


def test_bayer_pattern_mapping_matches_colour_conversion() -> None:
    # RGGB: red at (0,0). A pure-red scene must come out as the grey of pure red.
    ts = typestore(2)
    mosaic = np.zeros((8, 8), np.uint8)
    mosaic[0::2, 0::2] = 200  # R sites of an RGGB pattern
    msg = build_message(ts, "sensor_msgs/msg/Image", image_msg(mosaic, "bayer_rggb8", 1))
    gray, _ = GrayConverter("/cam")(msg, "sensor_msgs/msg/Image")
    red_grey = cv2.cvtColor(np.array([[[0, 0, 200]]], np.uint8), cv2.COLOR_BGR2GRAY)[0, 0]
    assert abs(int(np.median(gray[2:-2, 2:-2])) - int(red_grey)) <= 2


def test_step_mismatch_names_topic_and_field() -> None:
    ts = typestore(2)
    vals = image_msg(np.zeros((4, 6), np.uint8), "mono8", 1)
    vals["step"] = 3
    msg = build_message(ts, "sensor_msgs/msg/Image", vals)
    with pytest.raises(DecodeError, match=r"topic /cam: field step"):
        GrayConverter("/cam")(msg, "sensor_msgs/msg/Image")


def test_unknown_encoding_names_it() -> None:
    ts = typestore(2)
    vals = image_msg(np.zeros((4, 6), np.uint8), "yuv422", 1)
    msg = build_message(ts, "sensor_msgs/msg/Image", vals)
    with pytest.raises(DecodeError, match="yuv422"):
        GrayConverter("/cam")(msg, "sensor_msgs/msg/Image")


def test_mono16_shift_is_fixed_from_first_frame() -> None:
    ts = typestore(2)
    conv = GrayConverter("/cam")
    a = np.full((4, 4), 4000, np.uint16)  # a 12-bit sensor
    b = np.full((4, 4), 2000, np.uint16)
    ga, _ = conv(build_message(ts, "sensor_msgs/msg/Image", image_msg(a, "mono16", 1)),
                 "sensor_msgs/msg/Image")
    gb, _ = conv(build_message(ts, "sensor_msgs/msg/Image", image_msg(b, "mono16", 2)),
                 "sensor_msgs/msg/Image")
    assert conv.mono16_map is not None and conv.mono16_map.shift == 4
    assert int(ga[0, 0]) == 4000 >> 4 and int(gb[0, 0]) == 2000 >> 4


def test_mono16_on_a_pedestal_is_mapped_from_its_own_range() -> None:
    """A thermal camera's counts: a scene spanning ~600 counts around 7300-7900. Shifted to 8
    bits it would keep ~19 grey levels, under FAST's threshold of 20; the fixed window maps the
    first frame's 1st-99th percentiles to 64-192, with headroom for the scene warming."""
    from frontdiag.io.images import mono16_mapping

    ts = typestore(2)
    scene = frame(0, 0, shift=2).astype(np.uint16)  # 0-255
    first = (7300 + 2 * scene.astype(np.int64) + 40).astype(np.uint16)
    shift, window, note = mono16_mapping(first)
    assert shift == 5 and window is not None
    p1, p99 = np.percentile(first, [1, 99])
    lo, hi = window
    assert lo == pytest.approx(p1 - (p99 - p1) / 2, abs=1)
    assert hi == pytest.approx(p99 + (p99 - p1) / 2, abs=1)
    assert "pedestal" in note and f"{lo}-{hi}" in note
    conv = GrayConverter("/thermal")
    g1, _ = conv(build_message(ts, "sensor_msgs/msg/Image", image_msg(first, "mono16", 1)),
                 "sensor_msgs/msg/Image")
    q1, q99 = np.percentile(g1, [1, 99])
    assert 60 <= q1 <= 68 and 188 <= q99 <= 196  # 128 grey levels, not (p99 - p1) >> 5
    assert (int(first.max()) - int(first.min())) >> shift < 20
    # the scene warms by a third of its spread: the same mapping, nothing clipped
    warm = (first + (p99 - p1) // 3).astype(np.uint16)
    g2, _ = conv(build_message(ts, "sensor_msgs/msg/Image", image_msg(warm, "mono16", 2)),
                 "sensor_msgs/msg/Image")
    assert conv.mono16_map is not None and conv.mono16_map.window == window
    assert g2.max() < 255 and float(g2.mean() - g1.mean()) == pytest.approx(128 / 3, abs=2)
    # a visible camera's 12 bits from near zero: a shift, so a gain step keeps its ratio
    visible = (scene.astype(np.uint16) * 16 + 5).astype(np.uint16)
    assert mono16_mapping(visible)[1] is None
    # a narrow scene is never amplified beyond one grey level per count
    narrow = (9000 + scene // 8).astype(np.uint16)  # 32 counts
    lo, hi = mono16_mapping(narrow)[1] or (0, 0)
    assert hi - lo >= 256


def test_missing_file_is_recording_error(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="no such file"):
        open_recording(tmp_path / "nope.mcap")


def test_unknown_container(tmp_path: Path) -> None:
    p = tmp_path / "x.mcap"
    p.write_bytes(b"hello world, not a bag")
    with pytest.raises(RecordingError, match="unknown container"):
        open_recording(p)


def test_a_pose_graph_given_as_a_recording_points_to_the_loop_audit(tmp_path: Path) -> None:
    g = tmp_path / "run graph.g2o"
    g.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n"
                 "EDGE_SE2 0 1 1 0 0 100 0 0 100 0 1000\n")
    with pytest.raises(RecordingError, match="unknown container") as err:
        open_recording(g)
    assert f"frontdiag loops '{g}'" in (err.value.hint or "")
    notes = tmp_path / "notes.txt"
    notes.write_text("EDGES of the map, VERTEX_SE2 is mentioned only here\n")
    with pytest.raises(RecordingError) as err:
        open_recording(notes)
    assert "loops" not in (err.value.hint or "")


def test_ambiguous_camera_topics_list_the_exact_option(tmp_path: Path) -> None:
    def extra(w, i, t):  # type: ignore[no-untyped-def]
        w.write("/cam2/image_raw", "sensor_msgs/msg/Image", image_msg(frame(i), "mono8", t), t)

    path = write_recording(tmp_path / "two.mcap", "mcap", n=2, extra=extra)
    with open_recording(path) as rec, pytest.raises(TopicError) as err:
        choose_topics(rec.topics)
    assert "--camera-topic /cam/image_raw" in str(err.value)
    assert "--camera-topic /cam2/image_raw" in str(err.value)


def test_requested_topic_must_exist(tmp_path: Path) -> None:
    path = write_recording(tmp_path / "one.mcap", "mcap", n=2)
    with open_recording(path) as rec, pytest.raises(TopicError, match="/nope"):
        choose_topics(rec.topics, camera_topic="/nope")


def test_several_requested_topics_take_the_first_the_recording_holds(tmp_path: Path) -> None:
    """`--camera-topic A,B`: one fleet command over recordings that name the camera
    differently; the order decides where a recording holds both; none present is an error
    naming them all and what is available."""
    def extra(w, i, t):  # type: ignore[no-untyped-def]
        w.write("/cam2/image_raw", "sensor_msgs/msg/Image", image_msg(frame(i), "mono8", t), t)

    one = write_recording(tmp_path / "one.mcap", "mcap", n=2)
    two = write_recording(tmp_path / "two.mcap", "mcap", n=2, extra=extra)
    with open_recording(one) as rec:
        assert choose_topics(rec.topics, camera_topic="/left/image_raw, /cam/image_raw"
                             ).camera == "/cam/image_raw"
        with pytest.raises(TopicError, match="none of the topics /a, /b") as err:
            choose_topics(rec.topics, camera_topic="/a,/b")
        assert "--camera-topic /cam/image_raw" in (err.value.hint or "")
    with open_recording(two) as rec:
        assert choose_topics(rec.topics, camera_topic="/cam2/image_raw,/cam/image_raw"
                             ).camera == "/cam2/image_raw"
        assert choose_topics(rec.topics, camera_topic="/cam/image_raw,/cam2/image_raw"
                             ).camera == "/cam/image_raw"


def test_camera_info_paired_by_namespace(tmp_path: Path) -> None:
    path = write_recording(tmp_path / "one.mcap", "mcap", n=2)
    with open_recording(path) as rec:
        choice = choose_topics(rec.topics)
    assert choice.camera == "/cam/image_raw"
    assert choice.camera_info == "/cam/camera_info"


def test_selection_start_end_stride_max(tmp_path: Path) -> None:
    path = write_recording(tmp_path / "sel.mcap", "mcap", n=20)
    with open_recording(path) as rec:
        opts = AnalysisOptions(start_s=0.2, end_s=0.6, stride=2)
        got = [f.index for f in iter_camera_frames(rec, "/cam/image_raw", "", opts)]
        # messages at 0.20..0.60 s are indices 4..12; stride counts within the window
        assert got == [4, 6, 8, 10, 12]
        opts = AnalysisOptions(max_frames=3)
        assert len(list(iter_camera_frames(rec, "/cam/image_raw", "", opts))) == 3


def test_intrinsics_from_camera_info_in_ros1_and_ros2(tmp_path: Path) -> None:
    from frontdiag.io.camera_info import from_camera_info

    for fmt, name in (("bag", "a.bag"), ("mcap", "b.mcap"), ("mcap-ros1", "c.mcap")):
        path = write_recording(tmp_path / name, fmt, n=1)
        with open_recording(path) as rec:
            raw = next(iter(rec.messages(["/cam/camera_info"])))
            intr = from_camera_info(rec.deserialize(raw), "/cam/camera_info")
        assert intr is not None
        np.testing.assert_allclose(intr.K, K)


def test_recording_is_not_modified(tmp_path: Path) -> None:
    import hashlib

    path = write_recording(tmp_path / "ro.mcap", "mcap", n=3)
    before = hashlib.sha256(path.read_bytes()).hexdigest()
    with open_recording(path) as rec:
        list(iter_camera_frames(rec, "/cam/image_raw", "sensor_msgs/msg/Image"))
    assert hashlib.sha256(path.read_bytes()).hexdigest() == before


@pytest.mark.parametrize("fmt,name", [("mcap", "t.mcap"), ("bag", "t.bag"),
                                      ("mcap-ros1", "t1.mcap"),
                                      ("ros2-db3", "t_db3"),  # bag folder with metadata.yaml
                                      ("ros2-db3", "t.db3")])  # the sqlite file alone
def test_truncated_recording_yields_messages_before_the_damage(tmp_path: Path, fmt: str,
                                                               name: str) -> None:
    cut = cut_recording(tmp_path, fmt, name, n=150)
    before = _snapshot(cut)
    with open_recording(cut) as rec:
        got = list(rec.messages(["/cam/image_raw"]))
        assert rec.fault is not None and "damaged after" in rec.fault.message
        assert rec.fault.message.startswith(str(cut))
        assert 20 <= len(got) < 150
        # the survivors are the first frames written, in order, and decode to them
        assert [m.log_ns for m in got] == [T0 + i * DT for i in range(len(got))]
        first = rec.deserialize(got[0])
        assert first.encoding == "mono8"
        last_index = len(got) - 1
        gray = np.asarray(rec.deserialize(got[last_index]).data).reshape(120, 160)
        np.testing.assert_array_equal(gray, frame(last_index))
    # read-only: same bytes, and no -journal/-wal/-shm file beside the recording
    assert _snapshot(cut) == before


def _snapshot(path: Path) -> dict[str, str]:
    import hashlib

    folder = path if path.is_dir() else path.parent
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.iterdir()) if p.is_file()}


def test_truncated_db3_recovers_the_rows_before_the_damage(tmp_path: Path) -> None:
    """150 image + 150 camera_info rows cut at 60 %: every row before the missing pages."""
    cut = cut_recording(tmp_path, "ros2-db3", "t.db3", n=150)
    with open_recording(cut) as rec:
        assert rec.backend == "db3-scan"
        counts = {t.topic: t.count for t in rec.topics}
        assert counts == {"/cam/image_raw": 89, "/cam/camera_info": 89}
        assert rec.start_ns == T0 and rec.end_ns == T0 + 88 * DT
        infos = list(rec.messages(["/cam/camera_info"], start_ns=T0 + 10 * DT,
                                  end_ns=T0 + 20 * DT))
        assert len(infos) == 11
        np.testing.assert_allclose(np.asarray(rec.deserialize(infos[0]).k).reshape(3, 3), K)
        assert len(list(rec.messages(["/cam/image_raw", "/cam/camera_info"]))) == 178
        assert rec.fault is not None and rec.fault.after_messages == 178


def test_db3_row_reader_matches_rosbags_on_an_intact_file(tmp_path: Path) -> None:
    from frontdiag.io.db3_scan import ScannedDb3
    from frontdiag.io.readers import RosbagsRecording

    folder = write_recording(tmp_path / "bagdir", "ros2-db3", n=5)
    db3 = next(folder.glob("*.db3"))
    topics = ["/cam/image_raw", "/cam/camera_info"]
    with RosbagsRecording(db3, [db3]) as a, ScannedDb3(db3, [db3]) as b:
        assert b.fault is None
        assert sorted(a.topics, key=lambda t: t.topic) == sorted(b.topics, key=lambda t: t.topic)
        assert (a.start_ns, a.end_ns) == (b.start_ns, b.end_ns)
        ma, mb = list(a.messages(topics)), list(b.messages(topics))
        assert [(m.topic, m.log_ns, bytes(m.data)) for m in ma] == \
            [(m.topic, m.log_ns, bytes(m.data)) for m in mb]
        for x, y in zip(ma, mb, strict=True):
            assert repr(a.deserialize(x)) == repr(b.deserialize(y))


def test_db3_refused_for_another_reason_keeps_the_rosbags_error(tmp_path: Path) -> None:
    """An intact sqlite file is never read around what rosbags objected to."""
    folder = write_recording(tmp_path / "bagdir", "ros2-db3", n=3)
    meta = folder / "metadata.yaml"
    meta.write_text(meta.read_text().replace("compression_format: ''",
                                             "compression_format: 'lz4'")
                    .replace("compression_mode: ''", "compression_mode: 'MESSAGE'"))
    with pytest.raises(RecordingError, match="cannot open recording"):
        open_recording(folder)


def _with_depth(w, i, t):  # type: ignore[no-untyped-def]
    depth = (frame(i).astype(np.uint16) * 8).astype(np.uint16)
    w.write("/cam/depth/image_raw", "sensor_msgs/msg/Image", image_msg(depth, "16UC1", t), t)


def test_depth_image_topics_are_not_camera_candidates(tmp_path: Path) -> None:
    # an RGB-D recording: the intensity camera is taken, the depth stream named in a note
    path = write_recording(tmp_path / "rgbd.mcap", "mcap", n=2, extra=_with_depth)
    with open_recording(path) as rec:
        choice = choose_topics(rec.topics)
        forced = choose_topics(rec.topics, camera_topic="/cam/depth/image_raw")
    assert choice.camera == "/cam/image_raw"
    assert any("/cam/depth/image_raw" in n and "--camera-topic" in n for n in choice.notes)
    assert forced.camera == "/cam/depth/image_raw"


def test_depth_only_recording_says_so(tmp_path: Path) -> None:
    def only_depth(w, i, t):  # type: ignore[no-untyped-def]
        _with_depth(w, i, t)

    path = write_recording(tmp_path / "rgbd.mcap", "mcap", n=2, extra=only_depth)
    with open_recording(path) as rec:
        topics = [t for t in rec.topics if t.topic != "/cam/image_raw"]
    with pytest.raises(TopicError) as err:
        choose_topics(topics)
    assert "depth images" in str(err.value)
    assert "--camera-topic /cam/depth/image_raw" in (err.value.hint or "")
