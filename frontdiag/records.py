"""Frozen records that cross module boundaries. Timestamps are integer nanoseconds."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics plus distortion, from CameraInfo, the command line or a YAML file."""

    K: np.ndarray  # (3, 3) float64
    D: np.ndarray = field(default_factory=lambda: np.zeros(0))  # distortion coefficients
    model: str = "plumb_bob"  # plumb_bob | rational_polynomial | equidistant | none
    width: int = 0
    height: int = 0
    source: str = "unknown"  # camera_info topic, --intrinsics, --camera-info FILE

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def has_distortion(self) -> bool:
        return self.D.size > 0 and bool(np.any(np.abs(self.D) > 0))


@dataclass(frozen=True)
class CameraFrame:
    """One decoded camera image, already converted to 8-bit grey."""

    index: int  # position among the messages of this topic (before selection)
    t_ns: int  # header stamp, or log time when the stamp is zero
    log_ns: int  # time the recorder logged it
    topic: str
    gray: np.ndarray  # (H, W) uint8
    encoding: str
    ms_decode: float = 0.0
    frame_id: str = ""  # the image header's frame_id


@dataclass(frozen=True)
class LidarScan:
    """One decoded LiDAR sweep (PointCloud2, Livox CustomMsg, or LaserScan as a planar cloud)."""

    index: int
    t_ns: int
    log_ns: int
    topic: str
    xyz: np.ndarray  # (N, 3) float64, finite rows only
    time_rel_s: np.ndarray | None  # (N,) per-point time relative to t_ns, seconds
    intensity: np.ndarray | None = None
    ring: np.ndarray | None = None
    planar: bool = False  # True for LaserScan (2D scanner)
    frame_id: str = ""
    n_raw: int = 0  # points before NaN/inf rows were dropped
    ms_decode: float = 0.0


# keypoint states in CameraAnnotation.state
# status of the first camera row after the image size changed: the frontend started afresh
SIZE_STATUS = "size_changed"
# status of the first row after a gap in the recording: the frontend started afresh
GAP_STATUS = "after_gap"
# rows that start a new stretch of a topic: nothing before them was compared with them
RESTART_STATUSES = (GAP_STATUS, SIZE_STATUS)

KP_UNTRACKED = 0  # no correspondence with the reference keyframe
KP_INLIER = 1  # an essential-matrix inlier against the reference
KP_OUTLIER = 2  # a correspondence the essential matrix rejected
KP_TRACKED = 3  # a correspondence, not tested (no intrinsics, or too few for E)


@dataclass(frozen=True)
class CameraAnnotation:
    """What the camera frontend computed for one frame, for drawing it (not a metric).

    Coordinates are image pixels as detected (distorted). ``flow_ref``/``flow_cur`` pair the
    inlier keypoints with their positions in the reference keyframe ``ref_frame``.
    """

    width: int
    height: int
    xy: np.ndarray  # (N, 2) float32 keypoints
    state: np.ndarray  # (N,) uint8, KP_* above
    grid_counts: np.ndarray  # (rows, cols) int keypoints per entropy-grid cell (6 x 8)
    ref_frame: int = -1
    flow_ref: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.float32))
    flow_cur: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.float32))


@dataclass(frozen=True)
class ScanAnnotation:
    """What the LiDAR frontend used from one scan: the downsampled, deskewed points (sensor
    frame) and the weakest direction of the registration (rotation xyz, translation xyz)."""

    points: np.ndarray  # (N, 3) float64
    weak_vec: np.ndarray | None = None  # (6,) or (3,) for planar scans
    weak_dir: str = ""
    planar: bool = False
