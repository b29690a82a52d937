"""Recordings in Foxglove's schemas (Protobuf, JSON, ROS 2) and H.264 video."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
from foxglove_factory import (
    camera_items,
    encode_video,
    h264_packets,
    write_json,
    write_protobuf,
)
from recording_factory import DT, T0, K, frame, write_recording

from frontdiag.api import AnalysisOptions, analyze, run_analysis

TIMING = ["ms_decode", "ms_detect", "ms_match", "ms_geometry", "ms_photometric",
          "ms_diagnostic", "ms_total", "topic"]


def _metrics(df: pd.DataFrame) -> pd.DataFrame:
    """The table without its timing and topic columns."""
    return df.drop(columns=[c for c in TIMING if c in df.columns]).reset_index(drop=True)


@pytest.mark.parametrize("writer", [write_protobuf, write_json], ids=["protobuf", "json"])
@pytest.mark.parametrize("kind", ["CompressedImage", "RawImage"])
def test_foxglove_camera_messages_analyse_like_sensor_msgs(tmp_path: Path, writer, kind: str
                                                          ) -> None:
    """The same frames and calibration as Foxglove messages and as sensor_msgs: one table."""
    n = 12
    frames = [frame(i) for i in range(n)]
    fox = writer(tmp_path / "fox.mcap", camera_items(frames, K, T0, DT, kind=kind))
    ros = write_recording(tmp_path / "ros.mcap", "mcap", n=n, encoding="png")
    a, b = analyze(fox), analyze(ros)
    assert len(a) == n and set(a["topic"]) == {"/cam/image"}
    assert a.attrs["manifest"]["topics"]["camera_info"] == "/cam/calibration"
    assert a["h_over_e"].notna().sum() >= n - 2  # K was read: geometry ran
    assert _metrics(a).equals(_metrics(b))


def test_info_names_the_foxglove_schemas(tmp_path: Path) -> None:
    from frontdiag.inspect import inspect_recording

    frames = [frame(i) for i in range(4)]
    path = write_protobuf(tmp_path / "fox.mcap", camera_items(frames, K, T0, DT))
    rep = inspect_recording(path)
    types = {t.topic: t.msgtype for t in rep.topics}
    assert types == {"/cam/image": "foxglove.CompressedImage",
                     "/cam/calibration": "foxglove.CameraCalibration"}
    assert rep.choice is not None and rep.choice.camera == "/cam/image"
    assert next(t for t in rep.topics if t.topic == "/cam/image").detail == "compressed png"


def _video_frames(n: int) -> list[np.ndarray]:
    """Frames whose mean brightness names them (a ramp of 1.5 grey levels a frame over the
    sliding texture), so a picture shown out of order is seen."""
    out = []
    for i in range(n):
        f = frame(i).astype(np.float32) * 0.7 + 30 + 1.5 * (i % 40)
        out.append(np.clip(f, 0, 255).astype(np.uint8))
    return out


def _video_recording(path: Path, frames: list[np.ndarray], keyint: int, drop: int = 0,
                     damage: int | None = None) -> Path:
    packets = h264_packets(frames, keyint)
    items: list[tuple[str, str, int, dict[str, Any]]] = []
    for i, pkt in enumerate(packets):
        if i < drop:
            continue  # the recorder started after this keyframe
        if i == damage:
            pkt = pkt[:8] + bytes(len(pkt) - 8)
        t = T0 + i * DT
        items.append(("/cam/video", "CompressedVideo", t,
                      {"frame_id": "cam", "data": pkt, "format": "h264"}))
        items.append(("/cam/calibration", "CameraCalibration", t,
                      {"frame_id": "cam", "width": 160, "height": 120,
                       "distortion_model": "plumb_bob", "D": [0.0] * 5,
                       "K": [float(v) for v in K.ravel()]}))
    return write_protobuf(path, iter(items))


def test_h264_pictures_are_the_frames_in_order_from_the_first_keyframe(tmp_path: Path) -> None:
    frames = _video_frames(30)
    path = _video_recording(tmp_path / "v.mcap", frames, keyint=10, drop=3)
    res = run_analysis(path, AnalysisOptions())
    df = res.table
    # messages 0-6 are the P-frames after the keyframe the recording missed
    assert df["frame"].tolist() == list(range(7, 27))
    want = np.array([frames[3 + f].mean() for f in df["frame"]])
    assert np.abs(df["mean_intensity"].to_numpy() - want).max() < 1.0
    cam = res.manifest["counts"]["/cam/video"]
    assert cam["skipped_undecodable"] == 7 and "no keyframe yet" in cam["first_error"]
    assert df["h_over_e"].notna().sum() > 10


def test_a_video_split_into_windows_gives_the_serial_table(tmp_path: Path) -> None:
    """--jobs 2: each window's decoder is fed every message before it, so its pictures are the
    serial run's and so is the table (timing columns aside). Keyframes 100 frames apart: the
    second window (from frame 105, warm-up from 45) has none within its warm-up."""
    frames = _video_frames(150)
    path = _video_recording(tmp_path / "v.mcap", frames, keyint=100)
    one = run_analysis(path, AnalysisOptions(jobs=1))
    two = run_analysis(path, AnalysisOptions(jobs=2))
    assert two.windows == 2
    assert _metrics(one.table).equals(_metrics(two.table))
    assert len(one.table) == 150
    assert one.manifest["counts"] == two.manifest["counts"]


def test_stride_and_start_still_decode_the_pictures_they_skip(tmp_path: Path) -> None:
    """--start 1.3 s (frame 26 at 20 Hz) decodes from the keyframe at frame 20; --stride 3
    still feeds the frames it skips to the decoder."""
    from frontdiag.io.readers import open_recording
    from frontdiag.runner import video_feed_start

    frames = _video_frames(60)
    path = _video_recording(tmp_path / "v.mcap", frames, keyint=20)
    full = analyze(path).set_index("frame")["mean_intensity"]
    strided = analyze(path, stride=3, start_s=1.3).set_index("frame")["mean_intensity"]
    assert strided.index.min() == 26 and len(strided) == 12
    assert strided.equals(full.loc[strided.index])
    with open_recording(path) as rec:
        start = rec.start_ns
        assert start is not None
        assert video_feed_start(rec, "/cam/video", 0, start + 1_300_000_000) == 20
        assert video_feed_start(rec, "/cam/video", 45, None) == 40
        assert video_feed_start(rec, "/cam/video", 19, None) == 0


@pytest.mark.parametrize("codec", ["h264", "h265"])
def test_keyframes_are_told_from_the_bitstream(codec: str) -> None:


    from frontdiag.io.images import is_keyframe

    packets = encode_video(_video_frames(20), 8,
                           encoder="libx264" if codec == "h264" else "libx265")
    assert [i for i, p in enumerate(packets) if is_keyframe(p, codec)] == [0, 8, 16]
    assert is_keyframe(packets[0], "vp9") is None


def test_a_damaged_picture_is_skipped_and_the_run_goes_on(tmp_path: Path) -> None:
    frames = _video_frames(30)
    path = _video_recording(tmp_path / "v.mcap", frames, keyint=10, damage=14)
    res = run_analysis(path, AnalysisOptions())
    assert res.fault is None
    assert 20 <= len(res.table) <= 30
    assert res.table["frame"].max() == 29  # the keyframe at 20 resynchronises


def test_a_stream_restarted_with_another_codec_is_decoded_from_its_first_keyframe(
        tmp_path: Path) -> None:
    """An encoder restarted mid-recording with H.265 instead of H.264 (keyframes every 6): the
    H.265 pictures are decoded from their first keyframe, in order. A first message naming the
    wrong codec delays decoding to the next keyframe of the right one, and no further."""
    frames = _video_frames(24)
    packets = encode_video(frames[:12], 6) + encode_video(frames[12:], 6, encoder="libx265")
    fmts = ["h264"] * 12 + ["h265"] * 12

    def write(path: Path, fmts: list[str]) -> Path:
        return write_protobuf(path, iter(
            ("/cam/video", "CompressedVideo", T0 + i * DT,
             {"frame_id": "cam", "data": p, "format": f})
            for i, (p, f) in enumerate(zip(packets, fmts, strict=True))))

    df = run_analysis(write(tmp_path / "switch.mcap", fmts), AnalysisOptions()).table
    assert df["frame"].tolist() == list(range(24))
    want = np.array([frames[f].mean() for f in df["frame"]])
    assert np.abs(df["mean_intensity"].to_numpy() - want).max() < 1.0
    res = run_analysis(write(tmp_path / "mislabelled.mcap", ["h265", *fmts[1:]]),
                       AnalysisOptions())
    assert res.table["frame"].tolist() == list(range(6, 24))
    cam = res.manifest["counts"]["/cam/video"]
    assert cam["skipped_undecodable"] == 6
    assert "decoding starts again at the first h264 keyframe" in cam["last_error"]


def test_the_report_rereads_a_video_picture_from_its_keyframe(tmp_path: Path) -> None:
    from frontdiag.report.frame_image import read_pixels

    frames = _video_frames(30)
    path = _video_recording(tmp_path / "v.mcap", frames, keyint=10)
    res = run_analysis(path, AnalysisOptions())
    manifest = res.manifest
    for f in (0, 17, 29):
        got = read_pixels(manifest, "/cam/video", T0 + f * DT)
        assert got is not None and got.shape == (120, 160)
        assert abs(float(got.mean()) - float(frames[f].mean())) < 1.0


def test_ros2_foxglove_msgs_video(tmp_path: Path) -> None:
    """foxglove_msgs/msg/CompressedVideo in a ROS 2 MCAP (its definition in the schema)."""
    from mcap_ros2.writer import Writer

    frames = _video_frames(12)
    packets = h264_packets(frames, keyint=6)
    path = tmp_path / "ros2_video.mcap"
    with open(path, "wb") as fh:
        w = Writer(fh)
        schema = w.register_msgdef("foxglove_msgs/msg/CompressedVideo",
                                   "builtin_interfaces/Time timestamp\nstring frame_id\n"
                                   "uint8[] data\nstring format\n"
                                   "================================================================================\n"
                                   "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n")
        for i, pkt in enumerate(packets):
            t = T0 + i * DT
            w.write_message("/cam/video", schema,
                            {"timestamp": {"sec": t // 10**9, "nanosec": t % 10**9},
                             "frame_id": "cam", "data": pkt, "format": "h264"}, log_time=t,
                            publish_time=t)
        w.finish()
    df = analyze(path, intrinsics="120,120,80,60")
    assert len(df) == 12
    assert (df["t_ns"].diff().dropna() == DT).all()  # stamps from the message's timestamp
    assert np.abs(df["mean_intensity"].to_numpy()
                  - np.array([f.mean() for f in frames])).max() < 1.0


def _cloud_items(scans: list[tuple[int, np.ndarray]]) -> Iterator[tuple[str, str, int, dict]]:
    """float32 x, y, z as Foxglove PointCloud messages."""
    for t, xyz in scans:
        data = np.ascontiguousarray(xyz.astype("<f4")).tobytes()
        fields = [{"name": a, "offset": 4 * i, "type": 7} for i, a in enumerate("xyz")]
        yield "/lidar/points", "PointCloud", t, {"frame_id": "lidar", "point_stride": 12,
                                                 "fields": fields, "data": data}


def _hall_scans(n: int) -> list[tuple[int, np.ndarray]]:
    from frontdiag.lidar.synth import hall_scene, spinning_scan

    out = []
    for k in range(n):
        pose = np.eye(4)
        pose[:3, 3] = [2.0 + 0.1 * k, 0.3, 1.2]
        xyz, _ = spinning_scan(hall_scene(), beams=16, columns=360, pose0=pose, seed=k)
        out.append((T0 + k * 100_000_000, xyz.reshape(-1, 3).astype(np.float32)))
    return out


def test_a_foxglove_point_cloud_with_a_pose_is_read_in_its_frame(tmp_path: Path) -> None:
    """The cloud's pose (where its origin sits in frame_id) is applied: a cloud posed by a
    half turn about z and a shift gives the table of a PointCloud2 holding the points turned
    and shifted (float64, so that both hold the same numbers)."""
    from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
    from foxglove_schemas_protobuf.Pose_pb2 import Pose
    from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
    from foxglove_schemas_protobuf.Vector3_pb2 import Vector3

    from frontdiag.io.writer import RecordingWriter
    from frontdiag.lidar.synth import pointcloud2_dict

    scans = _hall_scans(5)
    pose = Pose(position=Vector3(x=1.0, y=-2.0, z=0.5),
                orientation=Quaternion(x=0.0, y=0.0, z=1.0, w=0.0))
    items = [(topic, schema, t, dict(body, pose=pose,
                                     fields=[PackedElementField(**f) for f in body["fields"]]))
             for topic, schema, t, body in _cloud_items(scans)]
    fox = write_protobuf(tmp_path / "fox.mcap", iter(items))
    R = np.diag([-1.0, -1.0, 1.0])
    ros = tmp_path / "ros.mcap"
    with RecordingWriter(ros, "mcap") as w:
        for t, xyz in scans:
            moved = xyz.astype(np.float64) @ R.T + np.array([1.0, -2.0, 0.5])
            w.write("/lidar/points", "sensor_msgs/msg/PointCloud2",
                    pointcloud2_dict({"x": moved[:, 0], "y": moved[:, 1], "z": moved[:, 2]},
                                     t_ns=t, frame_id="lidar"), t)
    a, b = analyze(fox), analyze(ros)
    assert len(a) == len(b) == 5
    cols = ["t_ns", "n_points", "n_points_used", "icp_fitness", "icp_rmse_m", "lidar_eig_min",
            "lidar_cond", "lidar_weak_dir", "status"]
    assert a[cols].equals(b[cols])
    assert a["icp_fitness"].iloc[1:].gt(0.5).all()
    # without the pose the points are elsewhere: the same scans unposed read differently
    plain = analyze(write_protobuf(tmp_path / "plain.mcap", iter(
        (topic, schema, t, dict(body, fields=[PackedElementField(**f) for f in body["fields"]]))
        for topic, schema, t, body in _cloud_items(scans))))
    assert not plain[cols].equals(a[cols])


def test_a_foxglove_laser_scan_reads_like_sensor_msgs(tmp_path: Path) -> None:
    from frontdiag.io.writer import RecordingWriter

    rng = np.random.default_rng(3)
    n = 360
    ang = np.linspace(-np.pi, np.pi, n, endpoint=False)
    room = 4.0 + 0.5 * np.cos(3 * ang) + 0.3 * np.sin(7 * ang)
    scans = []
    for k in range(6):
        r = room + 0.02 * k * np.cos(ang) + rng.normal(0, 0.002, n)
        scans.append((T0 + k * 100_000_000, r))
    fox = write_json(tmp_path / "fox.mcap", iter([
        ("/scan", "LaserScan", t, {"frame_id": "laser", "start_angle": float(ang[0]),
                                   "end_angle": float(ang[-1]),
                                   "ranges": [float(v) for v in r.astype(np.float32)],
                                   "intensities": []})
        for t, r in scans]))
    ros = tmp_path / "ros.mcap"
    with RecordingWriter(ros, "mcap") as w:
        for t, r in scans:
            w.write("/scan", "sensor_msgs/msg/LaserScan",
                    {"header": {"stamp": {"sec": t // 10**9, "nanosec": t % 10**9},
                                "frame_id": "laser"},
                     "angle_min": float(ang[0]), "angle_max": float(ang[-1]),
                     "angle_increment": float(ang[1] - ang[0]), "time_increment": 0.0,
                     "scan_time": 0.0, "range_min": 0.05, "range_max": 30.0,
                     "ranges": r.astype(np.float32), "intensities": np.zeros(0, np.float32)},
                    t)
    a, b = analyze(fox), analyze(ros)
    assert len(a) == len(b) == 6 and (a["sensor"] == "lidar").all()
    assert (a["n_points"] == b["n_points"]).all()
    for c in ("icp_fitness", "icp_rmse_m"):
        assert np.allclose(a[c], b[c], rtol=1e-3, atol=1e-6, equal_nan=True), c


@pytest.mark.parametrize("pix_fmt", ["yuv420p", "yuvj420p", "yuv444p", "yuv420p10le"])
def test_luma_is_ffmpegs_grey_conversion(pix_fmt: str) -> None:
    """The Y plane, stretched from video range where the format is in it, equals swscale's
    conversion to grey; a format with no 8-bit Y plane goes through swscale itself."""
    import av

    from frontdiag.io.images import luma

    img = frame(3, size=(160, 120))
    ramp = np.tile(np.linspace(0, 255, 160).astype(np.uint8), (120, 1))
    for src in (img, ramp):
        f = av.VideoFrame.from_ndarray(src, format="gray").reformat(format=pix_fmt)
        want = f.to_ndarray(format="gray")
        got = luma(f)
        assert got.shape == (120, 160) and got.dtype == np.uint8 and got.flags.c_contiguous
        assert np.array_equal(got, want)


def test_a_video_with_b_frames_is_refused_not_misread(tmp_path: Path) -> None:
    """B-frames make pictures come out after later messages, each message's stamp then not its
    picture's: refused with the reason."""


    packets = encode_video(_video_frames(20), 10, bframes=2)
    path = write_protobuf(tmp_path / "b.mcap", iter(
        ("/cam/video", "CompressedVideo", T0 + i * DT,
         {"frame_id": "cam", "data": p, "format": "h264"}) for i, p in enumerate(packets)))
    res = run_analysis(path, AnalysisOptions(intrinsics="120,120,80,60"))
    assert len(res.table) <= 2  # at most the pictures that came out in their own message
    assert res.fault is not None and "B-frames" in str(res.fault)


def test_ffmpeg_image_transport_packets(tmp_path: Path) -> None:
    """ffmpeg_image_transport_msgs/msg/FFMPEGPacket (ROS 2): the codec from the encoder's
    name, the stamp from the header."""
    from mcap_ros2.writer import Writer

    frames = _video_frames(12)
    packets = h264_packets(frames, keyint=6)
    path = tmp_path / "ffmpeg.mcap"
    with open(path, "wb") as fh:
        w = Writer(fh)
        schema = w.register_msgdef(
            "ffmpeg_image_transport_msgs/msg/FFMPEGPacket",
            "std_msgs/Header header\nint32 width\nint32 height\nstring encoding\nuint64 pts\n"
            "uint8 flags\nbool is_bigendian\nuint8[] data\n"
            "================================================================================\n"
            "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
            "================================================================================\n"
            "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n")
        for i, pkt in enumerate(packets):
            t = T0 + i * DT
            w.write_message("/cam/image_raw/ffmpeg", schema, {
                "header": {"stamp": {"sec": t // 10**9, "nanosec": t % 10**9},
                           "frame_id": "cam"},
                "width": 160, "height": 120, "encoding": "h264_nvenc", "pts": i,
                "flags": int(i % 6 == 0), "is_bigendian": False, "data": pkt},
                log_time=t, publish_time=t)
        w.finish()
    from frontdiag.inspect import inspect_recording

    assert inspect_recording(path).topics[0].detail == "video h264, keyframe every 6 msgs"
    df = analyze(path, intrinsics="120,120,80,60")
    assert len(df) == 12 and (df["t_ns"].diff().dropna() == DT).all()
    assert np.abs(df["mean_intensity"].to_numpy()
                  - np.array([f.mean() for f in frames])).max() < 1.0


def test_info_gives_a_videos_keyframe_spacing_and_what_cannot_be_decoded(tmp_path: Path
                                                                         ) -> None:
    from frontdiag.inspect import inspect_recording

    path = _video_recording(tmp_path / "v.mcap", _video_frames(40), keyint=10, drop=3)
    rep = inspect_recording(path)
    video = next(t for t in rep.topics if t.topic == "/cam/video")
    assert video.detail == "video h264, keyframe every 10 msgs"
    assert any("first keyframe is message 7" in o and "7 before it" in o for o in rep.oddities)


@pytest.mark.parametrize("fmt", ["mcap", "bag"])
def test_h264_in_a_compressed_image_topic(tmp_path: Path, fmt: str) -> None:
    """sensor_msgs/CompressedImage whose format is a video codec (FFmpeg-based image_transport
    plugins publish H.264 that way): decoded as video, --start included."""
    from frontdiag.inspect import inspect_recording
    from frontdiag.io.writer import RecordingWriter, camera_info_msg, compressed_image_msg

    frames = _video_frames(40)
    packets = h264_packets(frames, keyint=10)
    path = tmp_path / f"ci.{fmt}"
    with RecordingWriter(path, fmt) as w:
        for i, pkt in enumerate(packets):
            t = T0 + i * DT
            w.write("/cam/image/ffmpeg", "sensor_msgs/msg/CompressedImage",
                    compressed_image_msg(pkt, "h264", t), t)
            w.write("/cam/camera_info", "sensor_msgs/msg/CameraInfo",
                    camera_info_msg(K, 160, 120, t), t)
    df = analyze(path)
    assert len(df) == 40
    assert np.abs(df["mean_intensity"].to_numpy()
                  - np.array([f.mean() for f in frames])).max() < 1.0
    late = analyze(path, start_s=1.3).set_index("frame")["mean_intensity"]
    assert late.index.min() == 26
    assert late.equals(df.set_index("frame")["mean_intensity"].loc[late.index])
    video = next(t for t in inspect_recording(path).topics if t.topic == "/cam/image/ffmpeg")
    assert video.detail == "video h264, keyframe every 10 msgs"


def test_a_picture_and_a_calibration_giving_no_size_are_passed_over(tmp_path: Path) -> None:
    """A damaged first picture whose header says height 0, and a calibration message saying the
    same, are not the camera's size: the size comes from the next picture, the calibration
    from a message that gives one (this raised ZeroDivisionError, exit 3)."""
    n = 9
    frames = [frame(i) for i in range(n)]

    def items() -> Iterator[tuple[str, str, int, dict[str, Any]]]:
        for k, (topic, schema, t, fields) in enumerate(
                camera_items(frames, K, T0, DT, kind="RawImage")):
            if k in (0, 9):  # the first picture, the fifth calibration
                fields = {**fields, "height": 0}
            yield topic, schema, t, fields

    path = write_json(tmp_path / "zero.mcap", items())
    res = run_analysis(path, AnalysisOptions())
    assert res.fault is None
    assert len(res.table) == n - 1  # the picture of height 0 cannot be decoded
    assert res.table["h_over_e"].notna().sum() >= n - 3  # K was read: geometry ran
    notes = " ".join(res.table.attrs["manifest"].get("notes", []))
    assert "scaled" not in notes  # nothing was fitted to a size of 0
