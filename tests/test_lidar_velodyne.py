"""Velodyne raw packets (velodyne_msgs/VelodyneScan) read through velodyne-decoder."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree
from velodyne_factory import scan_msg, vlp16_scan

from frontdiag.errors import DecodeError
from frontdiag.io.writer import RecordingWriter
from frontdiag.lidar.velodyne import VelodyneDecoder

TYPE = "velodyne_msgs/msg/VelodyneScan"
T0_S = 1_700_000_000.0


def _pose(k: int) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, 3] = [2.0 + 0.1 * k, 0.3, 1.2]
    return pose


def _ns(msg: dict):
    from types import SimpleNamespace

    def conv(v):
        if isinstance(v, dict):
            return SimpleNamespace(**{k: conv(x) for k, x in v.items()})
        if isinstance(v, list):
            return [conv(x) for x in v]
        return v
    return conv(msg)


def test_packets_decode_to_the_points_and_times_the_sensor_measured() -> None:
    packets, truth, times = vlp16_scan(_pose(0), T0_S)
    msg = _ns(scan_msg(packets))
    t_ns = round(packets[-1][0] * 1e9)
    dec = VelodyneDecoder("/velodyne_packets")
    scan = dec(msg, index=0, log_ns=t_ns, t_ns=t_ns)
    assert dec.model == "VLP16"
    assert len(scan.xyz) == len(truth) > 20_000
    # the VLP-16's lasers sit up to 11.2 mm above or below the optical centre (its
    # calibration's vertical offsets), which the simulated rays leave out
    d, i = cKDTree(truth).query(scan.xyz)
    assert np.percentile(d, 99) < 0.015
    # each point's firing time, relative to the header stamp (the last packet's)
    want = T0_S + times[i] - packets[-1][0]
    assert np.abs(scan.time_rel_s - want).max() < 5e-6
    assert set(np.unique(scan.ring)) == set(range(16))
    assert scan.time_rel_s.min() < -0.09  # a revolution at 600 rpm lasts 0.1 s


def test_a_packet_of_the_wrong_size_names_the_field() -> None:
    from frontdiag.errors import DecodeError

    packets, _, _ = vlp16_scan(_pose(0), T0_S)
    packets[3] = (packets[3][0], packets[3][1][:1000])
    with pytest.raises(DecodeError, match=r"packets\.data.*1000 bytes"):
        VelodyneDecoder("/v")(_ns(scan_msg(packets)), index=0, log_ns=0, t_ns=1)


@pytest.mark.parametrize("fmt,suffix", [("bag", ".bag"), ("mcap", ".mcap"),
                                        ("ros2-db3", "_db3")])
def test_a_velodyne_recording_analyses_like_its_points_as_pointcloud2(
        tmp_path: Path, fmt: str, suffix: str) -> None:
    """Raw packets, and the points made from them written as PointCloud2 (x, y, z,
    intensity, ring, t): the same table, in a ROS 1 bag, plain MCAP and a ROS 2 bag."""
    from frontdiag.api import analyze
    from frontdiag.lidar.synth import pointcloud2_dict

    raw = tmp_path / f"packets{suffix}"
    cloud = tmp_path / f"cloud{suffix}"
    dec = VelodyneDecoder("/velodyne_packets")
    with RecordingWriter(raw, fmt) as w, RecordingWriter(cloud, fmt) as wc:
        for k in range(6):
            packets, _, _ = vlp16_scan(_pose(k), T0_S + 0.1 * k, seed=k, noise_m=0.005)
            msg = scan_msg(packets)
            t = round(packets[-1][0] * 1e9)
            w.write("/velodyne_packets", TYPE, msg, t)
            s = dec(_ns(msg), index=k, log_ns=t, t_ns=t)
            xyz = s.xyz.astype(np.float32)
            assert s.time_rel_s is not None and s.intensity is not None and s.ring is not None
            wc.write("/velodyne_points", "sensor_msgs/msg/PointCloud2", pointcloud2_dict(
                {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "intensity": s.intensity,
                 "ring": s.ring.astype(np.uint16), "t": s.time_rel_s},
                t_ns=t, frame_id="velodyne"), t)
    a, b = analyze(raw), analyze(cloud)
    assert len(a) == len(b) == 6 and (a["sensor"] == "lidar").all()
    cols = ["t_ns", "n_points", "n_points_used", "deskew_m", "icp_fitness", "icp_rmse_m",
            "lidar_eig_min", "lidar_cond", "status"]
    assert a[cols].equals(b[cols])
    assert a["icp_fitness"].iloc[1:].gt(0.5).all()


def test_info_names_the_sensor(tmp_path: Path) -> None:
    from frontdiag.inspect import inspect_recording

    path = tmp_path / "v.mcap"
    with RecordingWriter(path, "mcap") as w:
        for k in range(2):
            packets, _, _ = vlp16_scan(_pose(k), T0_S + 0.1 * k)
            w.write("/velodyne_packets", TYPE, scan_msg(packets), int(packets[-1][0] * 1e9))
    rep = inspect_recording(path)
    (top,) = rep.topics
    assert top.msgtype == TYPE and top.detail == "Velodyne VLP16, strongest, 76 packets"
    assert rep.choice is not None and rep.choice.lidar == "/velodyne_packets"


@pytest.mark.parametrize("ros,big", [(1, False), (2, False), (2, True)],
                         ids=["ros1", "cdr-le", "cdr-be"])
def test_scans_read_from_the_bytes_as_rosbags_deserialises_them(ros: int, big: bool) -> None:
    from frontdiag.io.writer import build_message, typestore
    from frontdiag.lidar.velodyne import read_scan

    ts = typestore(ros)
    packets, _, _ = vlp16_scan(_pose(0), T0_S)
    msg = build_message(ts, TYPE, scan_msg(packets[:5], frame_id="velo_top"))
    if ros == 1:
        data = ts.serialize_ros1(msg, TYPE)
        ref = ts.deserialize_ros1(data, TYPE)
    else:
        data = ts.serialize_cdr(msg, TYPE, little_endian=not big)
        ref = ts.deserialize_cdr(data, TYPE)
    got = read_scan(bytes(data), "ros1" if ros == 1 else "cdr", "/v")
    assert got.header.frame_id == ref.header.frame_id == "velo_top"
    assert (got.header.stamp.sec, got.header.stamp.nanosec) == \
        (ref.header.stamp.sec, ref.header.stamp.nanosec)
    assert len(got.packets) == len(ref.packets) == 5
    for g, r in zip(got.packets, ref.packets, strict=True):
        assert (g.stamp.sec, g.stamp.nanosec) == (r.stamp.sec, r.stamp.nanosec)
        assert g.data == bytes(np.asarray(r.data, np.uint8))
    with pytest.raises(DecodeError, match="packets"):
        read_scan(bytes(data)[:-100], "ros1" if ros == 1 else "cdr", "/v")
