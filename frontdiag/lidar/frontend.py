"""The LiDAR frontend: one metrics row per scan.

Per scan: range filter, deskew with the per-point time and a motion prior, voxel downsampling,
point-to-plane registration against a local map of recent keyframes (initial guess from the
prior), KISS-ICP-style adaptive correspondence threshold, then the degeneracy spectrum of J^T J at
the solution (:mod:`frontdiag.lidar.spectrum`).

Motion prior, in order of preference: odometry poses given with :meth:`LidarFrontend.add_odometry`
that cover both this scan and the previous one (the LiDAR is assumed to be mounted at the
odometry frame's origin, axes aligned: only relative motion is used, but a rotated mount would
rotate it); else constant velocity from the last two registrations; else none, and the scan is
registered from the previous pose (the only case where the initial guess is the identity motion).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import small_gicp

from frontdiag.lidar.backends import make_backend
from frontdiag.lidar.deskew import deskew, sweep_displacement
from frontdiag.lidar.localmap import LocalMap
from frontdiag.lidar.se3 import interpolate_pose, inv, se3_exp, se3_log
from frontdiag.lidar.spectrum import full_vector, spectrum, weak_axis
from frontdiag.records import LidarScan, ScanAnnotation
from frontdiag.timing import Clock, StageTimer

NAN = float("nan")
_log = logging.getLogger(__name__)

EXTRA_COLUMNS: tuple[str, ...] = ("icp_max_corr_m", "ms_lidar_map", "lidar_prior", "lidar_weak_axis",
                                  "lidar_weak_vec")
"""Columns this frontend adds beyond ``metrics.LIDAR_COLUMNS`` (declared in metrics.METRICS)."""


@dataclass(frozen=True)
class LidarParams:
    """Frontend settings. Distances in metres, angles in degrees."""

    voxel_size_m: float = 0.5
    """Voxel grid for the scan and the map (3D). 0.5 m keeps ~10-20k points of a warehouse scan,
    the size the reference 100 ms budget assumes (0.4 m -> ~15,000)."""
    planar_voxel_size_m: float = 0.05
    """Voxel grid for 2D scans (LaserScan), whose points are ~1-5 cm apart at short range."""
    min_range_m: float = 0.3
    """Drop returns closer than this (the robot's own body)."""
    max_range_m: float = 100.0
    map_keyframes: int = 20
    """Keyframes kept in the local map window."""
    keyframe_dist_m: float = 1.0
    keyframe_angle_deg: float = 10.0
    max_iterations: int = 30
    initial_threshold_m: float = 2.0
    """Correspondence threshold before any motion has been observed (KISS-ICP's default)."""
    min_motion_m: float = 0.1
    """Registrations whose prediction error is below this do not update the threshold model."""
    normal_neighbors: int = 10
    min_points: int = 100
    min_points_planar: int = 20
    min_fitness: float = 0.3
    """Below this share of matched points the registration is not trusted (status
    ``low_overlap``): the pose falls back to the prediction and the map is not updated."""
    backend: str = "auto"
    """``auto`` (= small_gicp), ``small_gicp`` or ``open3d``."""
    num_threads: int = 1


class LidarFrontend:
    """Stateful per-topic LiDAR frontend. ``process`` never raises on a hard scan."""

    def __init__(self, params: LidarParams | None = None,
                 clock: Clock = time.perf_counter) -> None:
        self.params = params if params is not None else LidarParams()
        self._clock = clock
        self._backend = make_backend(self.params.backend, self.params.num_threads)
        self.last_annotation: ScanAnnotation | None = None
        """The points the last ``process`` call used and its weakest direction, for drawing."""
        self._map: LocalMap | None = None
        # (mid-sweep time in ns, map <- sensor); the last two are kept
        self._poses: list[tuple[int, np.ndarray]] = []
        self._last_kf: np.ndarray | None = None
        self._first_raw: tuple[np.ndarray, np.ndarray] | None = None
        self._odom_t: list[int] = []
        self._odom_T: list[np.ndarray] = []
        self._mount: np.ndarray | None = None  # odometry's child frame <- sensor
        self._sse = 0.0
        self._n_dev = 0

    def reset(self) -> None:
        """Start a new local map with the next scan (after a gap in the recording): the motion
        prior and the map of the place before the gap no longer apply. Odometry is kept."""
        self._map = None
        self._poses = []
        self._last_kf = None
        self._first_raw = None
        self._sse = 0.0
        self._n_dev = 0

    # -- motion prior ------------------------------------------------------------------------
    def add_odometry(self, t_ns: int, pose: np.ndarray) -> None:
        """A 4x4 odometry pose (e.g. nav_msgs/Odometry), used as the motion prior when it covers
        the scan times. Poses must arrive in time order."""
        T = np.asarray(pose, dtype=np.float64).reshape(4, 4)
        if self._odom_t and t_ns <= self._odom_t[-1]:
            return
        self._odom_t.append(int(t_ns))
        self._odom_T.append(T)

    def set_mount(self, T: np.ndarray) -> None:
        """Where the sensor sits in the frame the odometry poses are of (``base ← sensor``, e.g.
        from ``/tf_static``): the prior is then the sensor's own motion, ``X⁻¹ Δ X``, not the
        base's. Applies to every odometry pose, before and after the call."""
        self._mount = np.asarray(T, dtype=np.float64).reshape(4, 4)

    def odometry_covers(self, t_ns: int) -> bool:
        """True when odometry up to ``t_ns`` has been added (the prior interpolates, it never
        extrapolates)."""
        return bool(self._odom_t) and self._odom_t[-1] >= t_ns

    @staticmethod
    def sweep_end_ns(scan: LidarScan) -> int:
        """The latest point time of a sweep: odometry up to here lets the prior cover the
        mid-sweep pose whatever points the range filter keeps."""
        times = scan.time_rel_s
        if times is None or not len(times):
            return scan.t_ns
        return scan.t_ns + round(max(float(np.nanmax(times)), 0.0) * 1e9)

    @property
    def pose(self) -> np.ndarray | None:
        """Latest map <- sensor pose, at the middle of the last registered sweep."""
        return self._poses[-1][1].copy() if self._poses else None

    @property
    def pose_t_ns(self) -> int | None:
        """Time of :attr:`pose` (the stamp plus half the sweep when points carry times)."""
        return self._poses[-1][0] if self._poses else None

    def _prior(self, t_ns: int) -> tuple[np.ndarray | None, np.ndarray | None, str]:
        """(relative motion since the last pose, body twist per second, source)."""
        if not self._poses:
            return None, None, "none"
        t_prev, _ = self._poses[-1]
        dt = (t_ns - t_prev) * 1e-9
        if self._odom_t and dt > 0:
            stamps = np.asarray(self._odom_t, dtype=np.int64)
            a = interpolate_pose(t_prev, stamps, np.asarray(self._odom_T))
            b = interpolate_pose(t_ns, stamps, np.asarray(self._odom_T))
            if a is not None and b is not None:
                delta = inv(a) @ b
                if self._mount is not None:
                    delta = inv(self._mount) @ delta @ self._mount
                return delta, se3_log(delta) / dt, "odometry"
        if len(self._poses) >= 2 and dt > 0:
            (t0, T0), (t1, T1) = self._poses[-2], self._poses[-1]
            span = (t1 - t0) * 1e-9
            if span > 0:
                twist = se3_log(inv(T0) @ T1) / span
                return se3_exp(twist * dt), twist, "constant_velocity"
        return None, None, "none"

    def _threshold(self, voxel: float) -> float:
        """KISS-ICP's adaptive threshold: three times the RMS error of past predictions (how far
        a point typically moved between prediction and registration), never below one voxel,
        the distance at which a correct map neighbour can sit after downsampling."""
        if self._n_dev == 0:
            return self.params.initial_threshold_m
        return max(3.0 * math.sqrt(self._sse / self._n_dev), voxel)

    # -- one scan ----------------------------------------------------------------------------
    def process(self, scan: LidarScan) -> dict[str, Any]:
        timer = StageTimer(self._clock)
        self.last_annotation = None
        row: dict[str, Any] = {
            "n_points": len(scan.xyz), "n_points_used": 0, "deskew_m": NAN,
            "icp_fitness": NAN, "icp_rmse_m": NAN, "icp_iters": 0, "lidar_eig_min": NAN,
            "lidar_cond": NAN, "lidar_weak_dir": "", "lidar_weak_axis": "",
            "lidar_weak_vec": None, "icp_max_corr_m": NAN,
            "lidar_prior": "none", "status": "ok",
        }
        try:
            status = self._process(scan, row, timer)
        except Exception as exc:  # never let one scan stop the run; the row says why
            _log.warning("LiDAR scan %d on %s failed", scan.index, scan.topic, exc_info=True)
            status = f"error: {type(exc).__name__}: {exc}"
        row["status"] = status
        row["ms_lidar_preprocess"] = timer.ms.get("preprocess", 0.0)
        row["ms_lidar_register"] = timer.ms.get("register", 0.0)
        row["ms_lidar_map"] = timer.ms.get("map", 0.0)
        row["ms_total"] = timer.total()
        return row

    def _process(self, scan: LidarScan, row: dict[str, Any], timer: StageTimer) -> str:
        p = self.params
        planar = bool(scan.planar)
        voxel = p.planar_voxel_size_m if planar else p.voxel_size_m
        with timer("preprocess"):
            xyz = np.asarray(scan.xyz, dtype=np.float64).reshape(-1, 3)
            times = scan.time_rel_s
            r2 = np.einsum("ij,ij->i", xyz, xyz)
            keep = (r2 >= p.min_range_m**2) & (r2 <= p.max_range_m**2)  # False for NaN too
            if not keep.all():
                xyz = xyz[keep]
                times = None if times is None else np.asarray(times)[keep]
            # the pose of a scan is taken at mid-sweep: deskewing to the middle makes an error in
            # the motion prior shift points both ways instead of all one way, so it does not
            # bias the registration (deskewing to the stamp at the sweep start feeds half the
            # velocity error back into the next velocity estimate, a loop that never settles)
            span, ref_s = 0.0, 0.0
            if times is not None and len(times):
                lo, hi = float(np.min(times)), float(np.max(times))
                span, ref_s = hi - lo, 0.5 * (lo + hi)
            t_ref = scan.t_ns + round(ref_s * 1e9)
            delta, twist, source = self._prior(t_ref)
            row["lidar_prior"] = source
            if times is not None and twist is not None and len(xyz):
                xyz, _ = deskew(xyz, times, twist, ref_s)
            if len(xyz):
                down = np.asarray(small_gicp.voxelgrid_sampling(
                    xyz, voxel, p.num_threads).points())[:, :3]
            else:
                down = np.zeros((0, 3))
            if planar:
                down[:, 2] = 0.0
            if times is not None and twist is not None:
                row["deskew_m"] = sweep_displacement(down, span, twist)
            elif times is not None and not self._poses:
                row["deskew_m"] = 0.0  # first scan: no motion known yet, nothing applied
        row["n_points_used"] = len(down)
        self.last_annotation = ScanAnnotation(down, None, "", planar)
        if len(down) < (p.min_points_planar if planar else p.min_points):
            return "too_few_points"
        reg_pts = _extrude(down, voxel) if planar else down

        if self._map is None:
            with timer("map"):
                self._map = LocalMap(voxel, p.map_keyframes, p.normal_neighbors, p.num_threads)
                self._map.insert(reg_pts, None if planar else reg_pts)
            self._poses.append((t_ref, np.eye(4)))
            self._last_kf = np.eye(4)
            if times is not None and not planar:
                self._first_raw = (xyz, np.asarray(times, dtype=np.float64) - ref_s)
            return "first_scan"

        with timer("register"):
            T_prev = self._poses[-1][1]
            init = T_prev @ delta if delta is not None else T_prev.copy()
            tau = self._threshold(voxel)
            row["icp_max_corr_m"] = tau
            res = self._backend.align(self._map, reg_pts, init, tau, p.max_iterations)
            T = _project_planar(res.T) if planar else res.T
            row["icp_iters"] = res.iterations
            row["icp_fitness"] = res.fitness
            scores = score_alignment(self._map, down, T, tau, planar)
            weak = scores.pop(WEAK_VEC_KEY, None)
            row.update(scores)
            self.last_annotation = ScanAnnotation(down, weak, str(row["lidar_weak_dir"]),
                                                  planar)
        if row["icp_fitness"] < p.min_fitness:
            self._push_pose(t_ref, init)
            return "low_overlap"

        dev = inv(init) @ T
        length = float(np.sqrt(np.mean(np.einsum("ij,ij->i", down, down))))
        ang = float(np.linalg.norm(se3_log(dev)[:3]))
        err = float(np.linalg.norm(dev[:3, 3])) + 2.0 * length * math.sin(ang / 2.0)
        if delta is None or float(np.linalg.norm(delta[:3, 3])) >= p.min_motion_m:
            self._sse += err * err
            self._n_dev += 1
        self._push_pose(t_ref, T)
        with timer("map"):
            assert self._last_kf is not None
            if self._first_raw is not None:
                self._redeskew_first_keyframe(voxel)
            kf = inv(self._last_kf) @ T
            moved = float(np.linalg.norm(kf[:3, 3]))
            turned = math.degrees(float(np.linalg.norm(se3_log(kf)[:3])))
            if moved >= p.keyframe_dist_m or turned >= p.keyframe_angle_deg:
                self._map.insert(reg_pts @ T[:3, :3].T + T[:3, 3], None if planar else reg_pts)
                self._last_kf = T.copy()
        return "ok"

    def _redeskew_first_keyframe(self, voxel: float) -> None:
        """The first scan entered the map before any motion was known, so its own sweep skew is
        baked into the map (7.5 cm on average at 1.5 m/s), and every later, properly deskewed
        scan would register against it with that bias. Once the first registration gives a
        velocity, the first keyframe is deskewed with it and the map rebuilt."""
        assert self._first_raw is not None and self._map is not None
        xyz, times = self._first_raw
        self._first_raw = None
        if len(self._map) != 1 or len(self._poses) < 2:
            return
        (t0, T0), (t1, T1) = self._poses[-2:]
        span = (t1 - t0) * 1e-9
        if span <= 0:
            return
        fixed, _ = deskew(xyz, times, se3_log(inv(T0) @ T1) / span)
        down = np.asarray(small_gicp.voxelgrid_sampling(fixed, voxel,
                                                        self.params.num_threads).points())[:, :3]
        fresh = LocalMap(voxel, self.params.map_keyframes, self.params.normal_neighbors,
                         self.params.num_threads)
        fresh.insert(down, down)  # the first keyframe defines the map frame (identity pose)
        self._map = fresh

    def _push_pose(self, t_ns: int, T: np.ndarray) -> None:
        self._poses.append((int(t_ns), T.copy()))
        del self._poses[:-2]
        # odometry older than the pose just before this one is never read again: keep memory
        # flat over a long recording
        keep_from = int(np.searchsorted(np.asarray(self._odom_t, dtype=np.int64),
                                        self._poses[0][0], side="right")) - 1
        if keep_from > 0:
            del self._odom_t[:keep_from]
            del self._odom_T[:keep_from]


WEAK_VEC_KEY = "weak_vec"
"""score_alignment's key for the weakest eigenvector (rotation..., translation...), not a column."""


def score_alignment(lmap: LocalMap, down: np.ndarray, T: np.ndarray, tau: float,
                    planar: bool = False) -> dict[str, Any]:
    """RMSE and the spectrum of a registration, from the correspondences at the solution ``T``
    (map <- sensor) of the downsampled scan ``down`` (sensor frame).

    Computed here rather than taken from a backend, so that every backend is scored by the same
    definition and the thresholds mean the same thing whichever one ran. (Fitness, the share of
    points with any map point within ``tau``, is the same definition in both backends and is
    taken from them.)
    """
    out: dict[str, Any] = {"icp_rmse_m": NAN, "lidar_eig_min": NAN, "lidar_cond": NAN,
                           "lidar_weak_dir": "", "lidar_weak_axis": "", "lidar_weak_vec": None}
    if len(down) == 0:
        return out
    R = T[:3, :3]
    world = down @ R.T + T[:3, 3]
    # RMSE and information only from correspondences on measured, well-defined planes
    idx, dist = lmap.nearest(world)
    nrm = lmap.score_normals[idx]
    use = (dist <= tau) & lmap.score_planar[idx] & (np.einsum("ij,ij->i", nrm, nrm) > 0.5)
    if use.any():
        resid = np.einsum("ij,ij->i", world[use] - lmap.score_points[idx[use]], nrm[use])
        out["icp_rmse_m"] = float(np.sqrt(np.mean(resid**2)))
        spec = spectrum(down[use], nrm[use] @ R, planar)
        if spec is not None:
            out["lidar_eig_min"] = spec.eig_min
            out["lidar_cond"] = spec.cond
            out["lidar_weak_dir"] = spec.weak_dir
            out["lidar_weak_axis"] = weak_axis(spec.weak_vec, planar)
            out["lidar_weak_vec"] = [round(float(x), 4) for x in full_vector(spec.weak_vec, planar)]
            out[WEAK_VEC_KEY] = spec.weak_vec
    return out


def _extrude(down: np.ndarray, voxel: float) -> np.ndarray:
    """A 2D scan as a thin vertical strip (three layers one voxel apart), so that its lines have
    well-defined surface normals for the 3D point-to-plane solver."""
    layers = [down + np.array([0.0, 0.0, dz]) for dz in (-voxel, 0.0, voxel)]
    return np.concatenate(layers, axis=0)


def _project_planar(T: np.ndarray) -> np.ndarray:
    """Keep x, y and yaw of a pose; z, roll and pitch are not observable from a 2D scan."""
    yaw = math.atan2(T[1, 0], T[0, 0])
    out = np.eye(4)
    out[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
    out[:2, 3] = T[:2, 3]
    return out
