"""PointCloud2 and LaserScan decoding across the field layouts drivers publish.

Messages are built with the recording writer, serialised and deserialised by rosbags (ROS 1 and
ROS 2 typestores), so the decoder sees exactly the objects a reader hands it.
"""

from __future__ import annotations

import numpy as np
import pytest

from frontdiag.errors import DecodeError
from frontdiag.io.writer import build_message, typestore
from frontdiag.lidar.decode import decode_laserscan, decode_pointcloud2, detect_time_rel_s
from frontdiag.lidar.synth import pointcloud2_dict

T_NS = 1_700_000_000_123_456_789
N = 12


def roundtrip(values: dict, msgtype: str = "sensor_msgs/msg/PointCloud2", ros: int = 2):
    ts = typestore(ros)
    msg = build_message(ts, msgtype, values)
    if ros == 1:
        return ts.deserialize_ros1(ts.serialize_ros1(msg, msgtype), msgtype)
    return ts.deserialize_cdr(ts.serialize_cdr(msg, msgtype), msgtype)


def cloud(n: int = N, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(-20, 20, size=(n, 3))


def decode(values: dict, ros: int = 2):
    return decode_pointcloud2(roundtrip(values, ros=ros), topic="/points", index=3, log_ns=42)


@pytest.mark.parametrize("ros", [1, 2])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("bigendian", [False, True])
def test_xyz_any_precision_and_byte_order(ros: int, dtype: type, bigendian: bool) -> None:
    xyz = cloud().astype(dtype)
    msg = pointcloud2_dict({"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]}, t_ns=T_NS,
                           bigendian=bigendian)
    scan = decode(msg, ros)
    np.testing.assert_allclose(scan.xyz, xyz.astype(np.float64))
    assert scan.xyz.dtype == np.float64
    assert scan.t_ns == T_NS and scan.index == 3 and scan.log_ns == 42
    assert scan.time_rel_s is None and not scan.planar
    assert scan.n_raw == N


def test_organised_cloud_with_point_and_row_padding() -> None:
    xyz = cloud(24).astype(np.float32)
    ring = np.repeat(np.arange(4, dtype=np.uint16), 6)
    inten = np.arange(24, dtype=np.float32)
    msg = pointcloud2_dict({"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "intensity": inten,
                            "ring": ring}, t_ns=T_NS, height=4, pad_to=32, row_pad=16)
    assert msg["row_step"] > msg["width"] * msg["point_step"]
    scan = decode(msg)
    np.testing.assert_allclose(scan.xyz, xyz)
    np.testing.assert_array_equal(scan.ring, ring)
    np.testing.assert_array_equal(scan.intensity, inten)


def test_nan_inf_and_zero_rows_are_dropped_with_their_times() -> None:
    xyz = cloud().astype(np.float32)
    t = np.linspace(0.0, 0.099, N).astype(np.float32)
    xyz[2, 0] = np.nan
    xyz[5, 2] = np.inf
    xyz[7] = 0.0  # "no return" in organised clouds
    msg = pointcloud2_dict({"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "time": t},
                           t_ns=T_NS)
    scan = decode(msg)
    keep = np.ones(N, bool)
    keep[[2, 5, 7]] = False
    np.testing.assert_allclose(scan.xyz, xyz[keep])
    np.testing.assert_allclose(scan.time_rel_s, t[keep].astype(np.float64), atol=1e-7)
    assert scan.n_raw == N and len(scan.xyz) == N - 3


def test_all_nan_cloud_decodes_to_an_empty_scan() -> None:
    xyz = np.full((N, 3), np.nan, np.float32)
    scan = decode(pointcloud2_dict({"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]}, t_ns=T_NS))
    assert scan.xyz.shape == (0, 3) and scan.n_raw == N


REL = np.linspace(0.0, 0.0999, N)  # seconds after the stamp


@pytest.mark.parametrize(("name", "values"), [
    ("time", REL.astype(np.float32)),                                    # Velodyne: rel. s
    ("time", (REL - 0.1).astype(np.float32)),                            # stamp at sweep end
    ("t", (REL * 1e9).astype(np.uint32)),                                # Ouster: rel. ns
    ("offset_time", (REL * 1e9).astype(np.uint32)),                      # Livox: rel. ns
    ("timestamp", T_NS * 1e-9 + REL),                                    # Hesai: abs. s, f64
    ("timestamp", T_NS + REL * 1e9),                                     # abs. ns, f64
    ("time", (REL * 1e9).astype(np.float64)),                            # rel. ns as float
])
def test_per_point_time_unit_and_reference_detected(name: str, values: np.ndarray) -> None:
    xyz = cloud().astype(np.float32)
    msg = pointcloud2_dict({"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], name: values},
                           t_ns=T_NS)
    scan = decode(msg)
    expect = (REL - 0.1) if values.dtype == np.float32 and values.min() < 0 else REL
    assert scan.time_rel_s is not None
    np.testing.assert_allclose(scan.time_rel_s, expect, atol=2e-6)


def test_small_stamps_of_a_simulated_log_still_read_relative_times() -> None:
    # stamps near zero: 0.05 s could be "absolute" too; the smaller offset wins
    rel, rule = detect_time_rel_s(REL.astype(np.float32), 2_000_000_000)
    assert rule == "relative_s"
    np.testing.assert_allclose(rel, REL, atol=1e-7)
    rel, rule = detect_time_rel_s(2.0 + REL, 2_000_000_000)
    assert rule == "absolute_s"
    np.testing.assert_allclose(rel, REL, atol=1e-9)


def test_absolute_times_on_another_clock_are_taken_from_the_first_point() -> None:
    rel, rule = detect_time_rel_s(1000.0 + REL, T_NS)
    assert rule == "other_clock_s"
    np.testing.assert_allclose(rel, REL, atol=1e-9)


def test_zero_stamp_falls_back_to_log_time() -> None:
    xyz = cloud().astype(np.float32)
    msg = pointcloud2_dict({"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]}, t_ns=0)
    assert decode(msg).t_ns == 42


def test_missing_coordinate_is_a_decode_error() -> None:
    xyz = cloud().astype(np.float32)
    msg = pointcloud2_dict({"x": xyz[:, 0], "y": xyz[:, 1]}, t_ns=T_NS)
    with pytest.raises(DecodeError, match="field z"):
        decode(msg)


def test_short_data_is_a_decode_error() -> None:
    xyz = cloud().astype(np.float32)
    msg = pointcloud2_dict({"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]}, t_ns=T_NS)
    msg["data"] = msg["data"][:-5]
    with pytest.raises(DecodeError, match="field data"):
        decode(msg)


def test_field_beyond_the_point_is_a_decode_error() -> None:
    xyz = cloud().astype(np.float32)
    msg = pointcloud2_dict({"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]}, t_ns=T_NS)
    msg["fields"][2]["offset"] = msg["point_step"]
    with pytest.raises(DecodeError, match="exceeds point_step"):
        decode(msg)


@pytest.mark.parametrize("ros", [1, 2])
def test_laserscan_to_planar_cloud(ros: int) -> None:
    ranges = np.array([1.0, np.inf, 0.01, 2.0, 50.0, np.nan, 3.0], dtype=np.float32)
    values = {"header": {"stamp": {"sec": 5, "nanosec": 0}, "frame_id": "laser"},
              "angle_min": -np.pi / 2, "angle_max": np.pi / 2, "angle_increment": np.pi / 6,
              "time_increment": 0.001, "scan_time": 0.1, "range_min": 0.05, "range_max": 30.0,
              "ranges": ranges, "intensities": np.arange(7, dtype=np.float32)}
    msg = roundtrip(values, "sensor_msgs/msg/LaserScan", ros)
    scan = decode_laserscan(msg, topic="/scan", index=0, log_ns=1)
    keep = np.array([0, 3, 6])
    ang = -np.pi / 2 + np.pi / 6 * keep
    r = ranges[keep].astype(np.float64)
    np.testing.assert_allclose(scan.xyz, np.c_[r * np.cos(ang), r * np.sin(ang), 0 * r],
                               atol=1e-6)
    np.testing.assert_allclose(scan.time_rel_s, 0.001 * keep, atol=1e-9)
    np.testing.assert_array_equal(scan.intensity, keep.astype(np.float32))
    assert scan.planar and scan.n_raw == 7 and scan.t_ns == 5_000_000_000


def test_data_given_as_bytes_is_read_too() -> None:
    from types import SimpleNamespace

    xyz = cloud().astype(np.float32)
    d = pointcloud2_dict({"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]}, t_ns=T_NS)
    msg = SimpleNamespace(
        header=SimpleNamespace(stamp=SimpleNamespace(sec=1, nanosec=0), frame_id="lidar"),
        height=d["height"], width=d["width"], point_step=d["point_step"],
        row_step=d["row_step"], is_bigendian=False, data=bytes(d["data"]),
        fields=[SimpleNamespace(**f) for f in d["fields"]])
    scan = decode_pointcloud2(msg, topic="/p", index=0, log_ns=0)
    np.testing.assert_allclose(scan.xyz, xyz)
