"""Livox CustomMsg: decoded from the message bytes, checked against rosbags' deserialisation, and
analysed end to end like the same points published as PointCloud2."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from frontdiag.errors import DecodeError
from frontdiag.io.writer import RecordingWriter, build_message, typestore
from frontdiag.lidar.livox import LIVOX_TYPES, decode_livox
from frontdiag.lidar.synth import hall_scene, pointcloud2_dict, spinning_scan

T_NS = 1_700_000_000_123_456_789
TYPE = "livox_ros_driver2/msg/CustomMsg"


def _points(n: int, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    xyz = rng.uniform(-30, 30, (n, 3)).astype(np.float32)
    xyz[3] = 0.0  # no return
    xyz[5, 1] = np.nan
    return {"offset_time": np.arange(n, dtype=np.uint32) * 10_000, "x": xyz[:, 0],
            "y": xyz[:, 1], "z": xyz[:, 2],
            "reflectivity": rng.integers(0, 255, n).astype(np.uint8),
            "tag": np.zeros(n, np.uint8), "line": (np.arange(n) % 6).astype(np.uint8)}


def _msg(cols: dict[str, np.ndarray], t_ns: int, timebase: int, frame_id: str = "livox") -> dict:
    n = len(cols["x"])
    return {"header": {"stamp": {"sec": t_ns // 10**9, "nanosec": t_ns % 10**9},
                       "frame_id": frame_id},
            "timebase": timebase, "point_num": n, "lidar_id": 1,
            "points": [{k: v[i].item() for k, v in cols.items()} for i in range(n)]}


@pytest.mark.parametrize("ros,little", [(1, True), (2, True), (2, False)])
@pytest.mark.parametrize("frame_id", ["livox", "livox_frame_x"])  # both string paddings
@pytest.mark.parametrize("pkg", ["livox_ros_driver", "livox_ros_driver2", "livox_interfaces"])
def test_custom_msg_bytes_read_as_rosbags_deserialises_them(ros: int, little: bool,
                                                           frame_id: str, pkg: str) -> None:
    ts = typestore(ros)
    msgtype = f"{pkg}/msg/CustomMsg"
    assert msgtype in LIVOX_TYPES
    cols = _points(40)
    msg = build_message(ts, msgtype, _msg(cols, T_NS, T_NS - 2_000_000, frame_id))
    if ros == 1:
        data, enc = ts.serialize_ros1(msg, msgtype), "ros1"
        back = ts.deserialize_ros1(data, msgtype)
    else:
        data, enc = ts.serialize_cdr(msg, msgtype, little_endian=little), "cdr"
        back = ts.deserialize_cdr(data, msgtype)
    scan = decode_livox(memoryview(data), enc, topic="/livox/lidar", index=7, log_ns=42)
    ref = np.array([[p.x, p.y, p.z] for p in back.points], np.float64)
    keep = np.isfinite(ref).all(axis=1) & (ref != 0).any(axis=1)
    assert keep.sum() == 38 and scan.n_raw == 40
    np.testing.assert_array_equal(scan.xyz, ref[keep])
    t_ref = np.array([p.offset_time for p in back.points], np.float64)[keep] * 1e-9 - 0.002
    np.testing.assert_allclose(scan.time_rel_s, t_ref, atol=1e-12)
    np.testing.assert_array_equal(scan.intensity,
                                  np.array([p.reflectivity for p in back.points])[keep])
    np.testing.assert_array_equal(scan.ring, np.array([p.line for p in back.points])[keep])
    assert scan.t_ns == T_NS and scan.index == 7 and scan.frame_id == frame_id


def test_later_returns_of_a_multi_return_pulse_are_dropped() -> None:
    """tag bits 4-5: 0x00 and 0x10 kept (as FAST-LIO's preprocessing keeps), 0x20 and 0x30
    (the other returns of the same pulse) dropped; the low bits (noise flags) do not matter."""
    ts = typestore(2)
    cols = _points(8)
    cols["x"][:] = np.arange(1, 9)
    cols["y"][:] = 1.0
    cols["tag"] = np.array([0x00, 0x10, 0x20, 0x30, 0x01, 0x11, 0x21, 0x12], np.uint8)
    data = ts.serialize_cdr(build_message(ts, TYPE, _msg(cols, T_NS, T_NS)), TYPE)
    scan = decode_livox(data, "cdr", topic="/l", index=0, log_ns=0)
    np.testing.assert_array_equal(scan.xyz[:, 0], [1, 2, 5, 6, 8])


def test_a_truncated_custom_msg_names_the_field() -> None:
    ts = typestore(2)
    msg = build_message(ts, TYPE, _msg(_points(10), T_NS, T_NS))
    data = ts.serialize_cdr(msg, TYPE)
    with pytest.raises(DecodeError, match=r"topic /livox/lidar: field points"):
        decode_livox(data[:-30], "cdr", topic="/livox/lidar", index=0, log_ns=0)
    with pytest.raises(DecodeError, match=r"field header"):
        decode_livox(data[:10], "cdr", topic="/livox/lidar", index=0, log_ns=0)


def _scans(n: int) -> list[tuple[int, dict[str, np.ndarray]]]:
    """A 16-beam sensor walking through the hall at 1 m/s, 10 Hz: per scan its stamp and
    columns (float32 xyz, offset time in ns after the stamp, reflectivity, line)."""
    out = []
    for k in range(n):
        pose = np.eye(4)
        pose[:3, 3] = [2.0 + 0.1 * k, 0.3, 1.2]
        xyz, t = spinning_scan(hall_scene(), beams=16, columns=360, pose0=pose,
                               twist=[0, 0, 0, 1.0, 0, 0], seed=k)
        xyz = xyz.reshape(-1, 3).astype(np.float32)
        cols = {"offset_time": (t.reshape(-1) * 1e9).astype(np.uint32),
                "x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2],
                "reflectivity": np.full(len(xyz), 50, np.uint8),
                "tag": np.zeros(len(xyz), np.uint8),
                "line": np.repeat(np.arange(16), 360).astype(np.uint8)}
        out.append((T_NS + k * 100_000_000, cols))
    return out


@pytest.mark.parametrize("fmt,suffix", [("bag", ".bag"), ("mcap", ".mcap"),
                                        ("ros2-db3", "_db3"), ("ros2-mcap", "_mcap")])
def test_a_livox_recording_analyses_like_the_same_points_as_pointcloud2(
        tmp_path: Path, fmt: str, suffix: str) -> None:
    """ROS 1 bag, plain MCAP and ROS 2 bags (sqlite3, MCAP): the same table either way."""
    from frontdiag.api import analyze

    scans = _scans(6)
    livox = tmp_path / f"livox{suffix}"
    cloud = tmp_path / f"cloud{suffix}"
    with RecordingWriter(livox, fmt) as w:
        for t, cols in scans:
            w.write("/livox/lidar", TYPE, _msg(cols, t, t), t)
    with RecordingWriter(cloud, fmt) as w:
        for t, cols in scans:
            pc = {"x": cols["x"], "y": cols["y"], "z": cols["z"],
                  "reflectivity": cols["reflectivity"], "t": cols["offset_time"],
                  "ring": cols["line"]}
            w.write("/points", "sensor_msgs/msg/PointCloud2",
                    pointcloud2_dict(pc, t_ns=t, frame_id="livox"), t)
    a, b = analyze(livox, use_camera=False), analyze(cloud, use_camera=False)
    assert len(a) == len(b) == 6 and (a["sensor"] == "lidar").all()
    cols = ["t_ns", "n_points", "n_points_used", "deskew_m", "icp_fitness", "icp_rmse_m",
            "lidar_eig_min", "lidar_cond", "status"]
    assert a[cols].equals(b[cols])
    assert a["icp_fitness"].iloc[1:].gt(0.5).all()  # it tracked: not a table of failures
    # per-point times were read: deskewing moves the scene by the 0.1 m a 1 m/s sweep covers
    assert a["deskew_m"].iloc[2:].between(0.08, 0.12).all()
