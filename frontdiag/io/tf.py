"""The LiDAR's motion prior from ``/tf`` where a recording has no ``nav_msgs/Odometry`` topic.

Mobile robots publish their wheel or visual odometry as the transform of an odometry frame
(``odom``, REP 105) to the robot's base frame on ``/tf``, and where each sensor sits on the
robot on ``/tf_static``. Many recordings keep those and drop the ``Odometry`` topic itself.
:class:`TfOdometry` collects both and, once the LiDAR's own frame (its messages'
``header.frame_id``) is known, chains it to the odometry frame:

    T_odom_lidar(t) = T_odom_X(t) · T_X_lidar

where ``X`` is the frame whose transform from an odometry frame ``/tf`` carries (usually
``base_link`` or ``base_footprint``) and ``T_X_lidar`` is composed from ``/tf_static`` along the
frames between them. The prior is then the motion of the LiDAR itself, lever arm included.
Where an ``Odometry`` topic is recorded, ``/tf_static`` alone places the LiDAR in the frame its
poses are of (:meth:`TfOdometry.static_chain`, used by ``LidarFrontend.set_mount``).

Only transforms whose parent is an odometry frame are kept from ``/tf`` (a frame named ``odom``,
or ending in ``/odom`` or ``_odom``): until the LiDAR's frame is chained (its first scan), at
most :data:`MAX_POSES` a child for :data:`MAX_FRAMES` children; after, only the chained child's,
each handed to the prior once and dropped. Memory stays bounded however long the recording.
The map → odom transform of a localiser jumps at every correction and is not odometry.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from typing import Any

import numpy as np

from frontdiag.io.decode import pose_matrix, stamp_ns

TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
MAX_POSES = 100_000  # per child frame, until the LiDAR's frame is chained: 17 min at 100 Hz
MAX_FRAMES = 8  # child frames of an odometry frame followed until one is chained


def frame(name: str) -> str:
    """A frame id as tf2 compares them (ROS 1 names may carry a leading slash)."""
    return name.lstrip("/")


def is_odometry_frame(name: str) -> bool:
    n = frame(name)
    return n == "odom" or n.endswith("/odom") or n.endswith("_odom")


def transform_matrix(tf: Any) -> np.ndarray:
    """4x4 of a ``geometry_msgs/Transform``."""
    p, q = tf.translation, tf.rotation
    return pose_matrix((p.x, p.y, p.z), (q.x, q.y, q.z, q.w))


class TfOdometry:
    """Poses of one sensor frame in an odometry frame, from ``/tf`` and ``/tf_static``."""

    def __init__(self) -> None:
        self.static: dict[str, tuple[str, np.ndarray]] = {}  # child -> (parent, T_parent_child)
        self.dynamic: dict[str, deque[tuple[int, np.ndarray]]] = {}  # child of an odom frame
        self.parent: dict[str, str] = {}  # the odometry frame of each such child
        self.last_t: dict[str, int] = {}  # the latest stamp of each such child
        self.base: str | None = None  # X: the child chained to the sensor
        self.T_base_sensor: np.ndarray | None = None
        self.chain: list[str] = []  # sensor frame up to X, for the notes

    def add(self, msg: Any, static: bool, log_ns: int = 0) -> None:
        """One ``TFMessage``: every transform in it (a transform unstamped takes ``log_ns``)."""
        for tr in getattr(msg, "transforms", ()) or ():
            child, parent = frame(tr.child_frame_id), frame(tr.header.frame_id)
            if not child or not parent:
                continue
            T = transform_matrix(tr.transform)
            if static:
                self.static[child] = (parent, T)
            elif is_odometry_frame(parent) and (self.base is None or child == self.base):
                poses = self.dynamic.get(child)
                if poses is None:
                    if len(self.dynamic) >= MAX_FRAMES:
                        continue
                    poses = self.dynamic[child] = deque(maxlen=MAX_POSES)
                    self.parent[child] = parent
                t = stamp_ns(tr, log_ns)
                if t > self.last_t.get(child, 0):
                    poses.append((t, T))
                    self.last_t[child] = t

    @property
    def resolved(self) -> bool:
        return self.base is not None

    def _up(self, sensor_frame: str) -> Iterator[tuple[str, np.ndarray, list[str]]]:
        """Up the static tree from ``sensor_frame``: each frame reached, ``frame ← sensor``
        composed so far, and the frames passed (at most 32: deeper is a loop in the tree)."""
        s = frame(sensor_frame)
        T = np.eye(4)
        path = [s]
        for _ in range(32):
            yield s, T, path
            up = self.static.get(s)
            if up is None:
                return
            s, T = up[0], up[1] @ T
            path = [*path, s]

    def resolve(self, sensor_frame: str) -> bool:
        """Chain ``sensor_frame`` to a child of an odometry frame through static transforms
        (the sensor frame itself may be that child); whether it could."""
        if self.base is not None:
            return True
        for s, T, path in self._up(sensor_frame):
            if s in self.dynamic:
                self.base, self.T_base_sensor, self.chain = s, T, path
                for other in self.dynamic:  # only the chained frame is followed from here
                    if other != s:
                        self.dynamic[other].clear()
                return True
        return False

    def static_chain(self, sensor_frame: str, base_frame: str) -> np.ndarray | None:
        """``base ← sensor`` composed from the static transforms along the frames between them
        (the identity when they are one frame); None when the static tree does not join them."""
        base = frame(base_frame)
        return next((T for s, T, _ in self._up(sensor_frame) if s == base), None)

    def poses(self) -> list[tuple[int, np.ndarray]]:
        """The sensor's poses in the odometry frame not handed out yet, in time order (handed
        out once: nothing is kept after)."""
        if self.base is None or self.T_base_sensor is None:
            return []
        q = self.dynamic[self.base]
        new = [(t, T @ self.T_base_sensor) for t, T in q]
        q.clear()
        return new

    def describe(self) -> str:
        """The chain for the notes: ``odom → base_link → … → lidar``."""
        if self.base is None:
            return ""
        return " → ".join([self.parent[self.base], *reversed(self.chain)])
