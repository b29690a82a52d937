"""Message dict builders for the simulator (see :mod:`frontdiag.io.writer` for the others).

PointCloud2 uses the Velodyne driver layout: ``x, y, z, intensity`` float32 at 0/4/8/12,
``ring`` uint16 at 16, ``time`` float32 at 18 (seconds after the header stamp), 22 bytes a point.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from frontdiag.io.writer import stamp

FLOAT32, UINT16 = 7, 4
CLOUD_DTYPE = np.dtype({"names": ["x", "y", "z", "intensity", "ring", "time"],
                        "formats": ["<f4", "<f4", "<f4", "<f4", "<u2", "<f4"],
                        "offsets": [0, 4, 8, 12, 16, 18], "itemsize": 22})


def header(t_ns: int, frame_id: str) -> dict:
    return {"stamp": stamp(t_ns), "frame_id": frame_id}


def pointcloud2_msg(points: dict[str, np.ndarray], t_ns: int, frame_id: str = "lidar") -> dict:
    """``sensor_msgs/PointCloud2`` dict, unorganised (height 1), from per-field arrays."""
    n = len(points["x"])
    arr = np.zeros(n, CLOUD_DTYPE)
    for name in CLOUD_DTYPE.names or ():
        arr[name] = points[name]
    offsets = {nm: spec[1] for nm, spec in (CLOUD_DTYPE.fields or {}).items()}
    fields = [{"name": nm, "offset": offsets[nm],
               "datatype": UINT16 if nm == "ring" else FLOAT32, "count": 1}
              for nm in CLOUD_DTYPE.names or ()]
    return {"header": header(t_ns, frame_id), "height": 1, "width": n, "fields": fields,
            "is_bigendian": False, "point_step": CLOUD_DTYPE.itemsize,
            "row_step": CLOUD_DTYPE.itemsize * n,
            "data": np.frombuffer(arr.tobytes(), np.uint8), "is_dense": True}


def quat_yaw(yaw: float) -> dict:
    return {"x": 0.0, "y": 0.0, "z": float(np.sin(yaw / 2)), "w": float(np.cos(yaw / 2))}


def quat_from_matrix(R: np.ndarray) -> dict:
    """Unit quaternion dict from a rotation matrix (Shepperd's method)."""
    m = R
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = np.sqrt(tr + 1.0) * 2
        q = ((m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s)
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        q = (0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s)
    elif m[1, 1] > m[2, 2]:
        s = np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        q = ((m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s)
    else:
        s = np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        q = ((m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s)
    return {"x": float(q[0]), "y": float(q[1]), "z": float(q[2]), "w": float(q[3])}


def odometry_msg(t_ns: int, x: float, y: float, yaw: float, v: float, w: float, *,
                 frame_id: str = "odom", child: str = "base_link",
                 pos_sd: float = 0.05, yaw_sd: float = 0.02) -> dict:
    """``nav_msgs/Odometry`` for a planar robot (body-frame twist)."""
    pc = np.zeros(36)
    pc[0] = pc[7] = pos_sd ** 2
    pc[14] = pc[21] = pc[28] = 1e6
    pc[35] = yaw_sd ** 2
    tc = np.zeros(36)
    tc[0] = tc[7] = 0.01 ** 2
    tc[14] = tc[21] = tc[28] = 1e6
    tc[35] = 0.01 ** 2
    return {"header": header(t_ns, frame_id), "child_frame_id": child,
            "pose": {"pose": {"position": {"x": x, "y": y, "z": 0.0}, "orientation": quat_yaw(yaw)},
                     "covariance": pc},
            "twist": {"twist": {"linear": {"x": v, "y": 0.0, "z": 0.0},
                                "angular": {"x": 0.0, "y": 0.0, "z": w}}, "covariance": tc}}


def imu_msg(t_ns: int, yaw: float, gyro: np.ndarray, accel: np.ndarray,
            frame_id: str = "imu") -> dict:
    """``sensor_msgs/Imu`` (orientation from the integrated yaw, rad/s, m/s²)."""
    cov = np.diag([1e-4, 1e-4, 1e-4]).reshape(-1)
    return {"header": header(t_ns, frame_id), "orientation": quat_yaw(yaw),
            "orientation_covariance": cov,
            "angular_velocity": {"x": float(gyro[0]), "y": float(gyro[1]), "z": float(gyro[2])},
            "angular_velocity_covariance": cov,
            "linear_acceleration": {"x": float(accel[0]), "y": float(accel[1]),
                                    "z": float(accel[2])},
            "linear_acceleration_covariance": cov * 100}


def transform(t_ns: int, parent: str, child: str, T: np.ndarray) -> dict:
    """One ``geometry_msgs/TransformStamped`` dict from a 4x4 matrix."""
    return {"header": header(t_ns, parent), "child_frame_id": child,
            "transform": {"translation": {"x": float(T[0, 3]), "y": float(T[1, 3]),
                                          "z": float(T[2, 3])},
                          "rotation": quat_from_matrix(T[:3, :3])}}


def tf_msg(transforms: list[dict]) -> dict:
    """``tf2_msgs/TFMessage`` dict."""
    return {"transforms": transforms}


_TF_MSG = "geometry_msgs/TransformStamped[] transforms\n"


def ensure_types(ts: Any) -> None:
    """Register ``tf2_msgs/msg/TFMessage`` in a typestore that lacks it (rosbags' ROS 1 store)."""
    if "tf2_msgs/msg/TFMessage" in ts.types:
        return
    from rosbags.typesys import get_types_from_msg

    ts.register(get_types_from_msg(_TF_MSG, "tf2_msgs/msg/TFMessage"))
