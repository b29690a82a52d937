"""Drive a scenario and write the recording plus its ``.labels.csv``.

Topics written (ROS frames in brackets):

``/camera/image_raw`` (or ``/camera/image_raw/compressed``) mono8 [camera_optical]
``/camera/camera_info``  the true pinhole K, no distortion [camera_optical]
``/lidar/points``        PointCloud2 x y z intensity ring time, 10 Hz [lidar]
``/odom``                wheel odometry, 50 Hz, 1 % scale error and a small yaw-rate bias [odom]
``/ground_truth``        true base pose, 50 Hz [map]
``/imu/data``            gyro and accelerometer with noise, 100 Hz [imu]
``/tf`` and ``/tf_static``

Header stamps and log times are equal. Determinism: every random draw comes from a generator
seeded with ``(seed, stream, index)``, so a seed gives the same bytes whatever the machine.
"""

from __future__ import annotations

import bisect
import csv
import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from frontdiag.conditions import CONDITION_SENSORS, HEALTHY, LABELS
from frontdiag.errors import ConfigError
from frontdiag.io.writer import (
    RecordingWriter,
    camera_info_msg,
    compressed_image_msg,
    image_msg,
)
from frontdiag.sim import messages as M
from frontdiag.sim.lidar import LidarSpec, sweep
from frontdiag.sim.render import AutoExposure, Intrinsics, expose, render
from frontdiag.sim.scenarios import MARGIN_S, SCENARIOS, Part, Segment
from frontdiag.sim.scenes import Builder
from frontdiag.sim.world import World

log = logging.getLogger(__name__)

T0_NS = 1_700_000_000_000_000_000
CAM_XYZ = (0.25, 0.0, 1.1)
LIDAR_XYZ = (0.0, 0.0, 1.5)
ODOM_HZ = 50.0
IMU_HZ = 100.0
R_LINK_OPT = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])

FORMATS = {"mcap": "mcap", "bag": "bag", "db3": "ros2-db3", "mcap-ros1": "mcap-ros1",
           "ros2-mcap": "ros2-mcap"}


@dataclass(frozen=True)
class SimOptions:
    seconds: float | None = None
    seed: int = 0
    width: int = 640
    height: int = 480
    rate_hz: float = 15.0
    hfov_deg: float = 70.0
    lidar: LidarSpec | None = field(default_factory=LidarSpec)
    compressed: str | None = None  # "jpeg" or "png"
    jpeg_quality: int = 90
    blur_ms: float = 0.0
    auto_exposure: bool = True


@dataclass
class SimResult:
    path: Path
    labels_path: Path
    frames: int
    scans: int
    seconds: float
    labels: list[tuple[int, int, str]]
    exposure_steps: list[int]


def labels_path_for(recording: Path | str) -> Path:
    """``run.mcap`` -> ``run.mcap.labels.csv`` (beside the recording)."""
    p = Path(recording)
    return p.with_name(p.name + ".labels.csv")


def _rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _T(R: np.ndarray, t: tuple[float, float, float] | np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = R
    out[:3, 3] = t
    return out


CUT_PAUSE_S = 1.0
"""A cut between parts (another area of the warehouse) is a pause of the recording: it stops in
one place and resumes in the other this much later, as two recordings joined end to end do.
Without it the sensors would teleport between two consecutive messages, which no recording
can show; with it a frontend sees the gap (see frontdiag.timing.GapDetector) and starts
afresh."""


class Timeline:
    """Maps global time (s from the start) to part, segment and pose."""

    def __init__(self, parts: list[Part]) -> None:
        self.parts = parts
        self.seg_start: list[float] = []
        self.seg_part: list[int] = []
        self.segs: list[Segment] = []
        self.part_start: list[float] = []
        t = 0.0
        for i, p in enumerate(parts):
            self.part_start.append(t)
            for s in p.segments:
                self.seg_start.append(t)
                self.seg_part.append(i)
                self.segs.append(s)
                t += s.duration
        self.duration = t

    def stamp_s(self, t: float) -> float:
        """Recording time of scene time ``t``: each cut before ``t`` adds CUT_PAUSE_S."""
        cuts = bisect.bisect_right(self.part_start, t) - 1  # part starts after the first
        return t + CUT_PAUSE_S * max(cuts, 0)

    def seg_index(self, t: float) -> int:
        return max(0, min(len(self.segs) - 1, bisect.bisect_right(self.seg_start, t) - 1))

    def part_index(self, t: float) -> int:
        return self.seg_part[self.seg_index(t)]

    def pose(self, t: float, part: int | None = None) -> tuple[float, float, float, float]:
        """(x, y, yaw, pan) at ``t``; with ``part`` the time is clamped into that part."""
        if part is not None:
            p0 = self.part_start[part]
            p1 = p0 + self.parts[part].duration
            t = min(max(t, p0), p1 - 1e-9)
        i = self.seg_index(t)
        return self.segs[i].motion(t - self.seg_start[i])

    def lights(self, t: float) -> float:
        i = self.seg_index(t)
        seg = self.segs[i]
        a = (t - self.seg_start[i]) / max(seg.duration, 1e-9)
        a = min(max(a, 0.0), 1.0)
        return float(seg.lights[0] + (seg.lights[1] - seg.lights[0]) * a)

    def label(self, t: float, sensor: str) -> str | None:
        """The constructed label of ``sensor`` at ``t`` (None near a change of label)."""
        i = self.seg_index(t)
        lab = getattr(self.segs[i], sensor)
        if lab is None:
            return None
        # unlabelled within MARGIN_S of a change of this sensor's label or of a cut
        for j in (i - 1, i + 1):
            if not 0 <= j < len(self.segs):
                continue
            other = getattr(self.segs[j], sensor)
            cut = self.seg_part[j] != self.seg_part[i]
            if other != lab or cut:
                edge = self.seg_start[i] if j < i else self.seg_start[j]
                if abs(t - edge) <= MARGIN_S:
                    return None
        return lab

    def velocity(self, t: float) -> tuple[float, float, np.ndarray]:
        """Body-frame forward speed, yaw rate and world acceleration (central differences)."""
        part = self.part_index(t)
        h = 0.005
        a = np.array(self.pose(t - h, part)[:3])
        b = np.array(self.pose(t, part)[:3])
        c = np.array(self.pose(t + h, part)[:3])
        d1 = (c - a) / (2 * h)
        d2 = (c - 2 * b + a) / (h * h)
        yaw = b[2]
        v = float(d1[0] * np.cos(yaw) + d1[1] * np.sin(yaw))
        return v, float(d1[2]), d2


def base_T(x: float, y: float, yaw: float) -> np.ndarray:
    return _T(_rot_z(yaw), (x, y, 0.0))


def camera_T(pose: tuple[float, float, float, float]) -> np.ndarray:
    """Optical frame -> world for a base pose with the camera head panned by ``pan``."""
    x, y, yaw, pan_ = pose
    return base_T(x, y, yaw) @ _T(_rot_z(pan_), CAM_XYZ) @ _T(R_LINK_OPT, (0, 0, 0))


def simulate(scenario: str, out: Path | str, fmt: str = "mcap",
             options: SimOptions | None = None,
             progress: Callable[[int, int], None] | None = None,
             overwrite: bool = False) -> SimResult:
    """Write ``out`` (and ``out.labels.csv``) for ``scenario``; returns what was written.

    An existing ``out`` is an error unless ``overwrite`` (then it is replaced).
    """
    opt = options or SimOptions()
    if scenario not in SCENARIOS:
        raise ConfigError(f"unknown scenario {scenario!r}",
                          hint=f"choose one of: {', '.join(SCENARIOS)}")
    if fmt not in FORMATS:
        raise ConfigError(f"unknown format {fmt!r}", hint=f"choose one of: {', '.join(FORMATS)}")
    if opt.width < 32 or opt.height < 24 or opt.rate_hz <= 0:
        raise ConfigError(f"bad image size or rate: {opt.width}x{opt.height} at {opt.rate_hz} Hz")
    out = Path(out)
    if out.exists():
        if not overwrite:
            raise ConfigError(f"{out} exists", hint="pick a new path, or --force to replace it")
        if out.is_dir():
            import shutil

            shutil.rmtree(out)
        else:
            out.unlink()
    sc = SCENARIOS[scenario]
    seconds = float(opt.seconds if opt.seconds is not None else sc.default_seconds)
    if seconds <= 0:
        raise ConfigError(f"--seconds must be positive, got {seconds}")
    parts = sc.make(seconds)
    tl = Timeline(parts)
    intr = Intrinsics.from_hfov(opt.width, opt.height, opt.hfov_deg)
    detail = opt.width / 640.0
    worlds: dict[int, World] = {}

    def world_for(i: int) -> World:
        if i not in worlds:
            worlds.clear()  # hold one world at a time
            w = World()
            parts[i].build(Builder(w, np.random.default_rng([opt.seed, 1, i]), detail))
            worlds[i] = w
        return worlds[i]

    n_frames = int(np.floor(tl.duration * opt.rate_hz + 1e-9))
    lidar = opt.lidar
    n_scans = int(np.floor(tl.duration * lidar.rate_hz + 1e-9)) if lidar else 0
    events: list[tuple[float, int, int]] = []  # (t, kind, index); kinds below
    events += [(k / opt.rate_hz, 0, k) for k in range(n_frames)]
    events += [(j / lidar.rate_hz, 1, j) for j in range(n_scans)] if lidar else []
    events += [(k / ODOM_HZ, 2, k) for k in range(int(tl.duration * ODOM_HZ))]
    events += [(k / IMU_HZ, 3, k) for k in range(int(tl.duration * IMU_HZ))]
    events.sort()

    cam_topic = "/camera/image_raw" + ("/compressed" if opt.compressed else "")
    ae = AutoExposure(enabled=opt.auto_exposure)
    ae_part = -1
    cam_rows: list[tuple[int, str | None]] = []
    lidar_rows: list[tuple[int, str | None]] = []
    steps: list[int] = []
    prev_gain: float | None = None
    odo = np.zeros(3)  # wheel-odometry x, y, yaw
    odo_t: float | None = None
    imu_rng = np.random.default_rng([opt.seed, 4])
    odo_rng = np.random.default_rng([opt.seed, 5])
    done = 0
    K = intr.K

    def radiance_at(t: float, part: int) -> np.ndarray:
        w = world_for(part)
        light = tl.lights(t)
        if opt.blur_ms <= 0:
            return render(w, intr, camera_T(tl.pose(t, part)), lights=light)[0]
        acc = np.zeros((intr.height, intr.width), np.float32)
        n_sub = 4
        for s in range(n_sub):
            ts = t - opt.blur_ms * 1e-3 * (1 - s / (n_sub - 1))
            acc += render(w, intr, camera_T(tl.pose(ts, part)), lights=light)[0]
        return acc / n_sub

    with RecordingWriter(out, FORMATS[fmt]) as wr:
        M.ensure_types(wr.ts)
        static = [
            M.transform(T0_NS, "base_link", "camera_optical",
                        _T(np.eye(3), CAM_XYZ) @ _T(R_LINK_OPT, (0, 0, 0))),
            M.transform(T0_NS, "base_link", "lidar", _T(np.eye(3), LIDAR_XYZ)),
            M.transform(T0_NS, "base_link", "imu", np.eye(4)),
        ]
        wr.write("/tf_static", "tf2_msgs/msg/TFMessage", M.tf_msg(static), T0_NS)
        for t, kind, idx in events:
            t_ns = T0_NS + round(tl.stamp_s(t) * 1e9)
            part = tl.part_index(t)
            if kind == 0:
                if part != ae_part:  # a new area: the exposure arrives converged on target
                    ae_part = part
                    if ae.enabled:
                        rad = radiance_at(t, part)
                        for _ in range(8):  # the mean of a clipped image: iterate to target
                            level = float(np.clip(rad * (ae.gain * 200.0), 0, 255).mean())
                            if level <= 0:
                                break
                            ae.gain = float(np.clip(ae.gain * ae.target / level, ae.min_gain,
                                                    ae.max_gain))
                    prev_gain = None
                rad = radiance_at(t, part)
                frng = np.random.default_rng([opt.seed, 2, idx])
                img = expose(rad, ae.gain, frng)
                stepped = prev_gain is not None and ae.gain != prev_gain
                prev_gain = ae.gain
                if ae.enabled and parts[part].auto_exposure:
                    ae.update(float(img.mean()))
                lab = tl.label(t, "camera")
                if stepped:
                    steps.append(t_ns)
                    lab = "exposure_step" if lab in (HEALTHY, None) else f"{lab};exposure_step"
                elif cam_rows and cam_rows[-1][1] is not None and \
                        "exposure_step" in cam_rows[-1][1]:
                    lab = None  # the frame after a step: recovery, left unlabelled
                cam_rows.append((t_ns, lab))
                if opt.compressed:
                    ext = ".jpg" if opt.compressed == "jpeg" else ".png"
                    params = [cv2.IMWRITE_JPEG_QUALITY, opt.jpeg_quality] if ext == ".jpg" else []
                    _ok, buf = cv2.imencode(ext, img, params)
                    wr.write(cam_topic, "sensor_msgs/msg/CompressedImage",
                             compressed_image_msg(buf.tobytes(), opt.compressed, t_ns,
                                                  "camera_optical"), t_ns)
                else:
                    wr.write(cam_topic, "sensor_msgs/msg/Image",
                             image_msg(img, "mono8", t_ns, "camera_optical"), t_ns)
                wr.write("/camera/camera_info", "sensor_msgs/msg/CameraInfo",
                         camera_info_msg(K, intr.width, intr.height, t_ns,
                                         frame_id="camera_optical"), t_ns)
                done += 1
                if progress:
                    progress(done, n_frames)
            elif kind == 1 and lidar is not None:
                lrng = np.random.default_rng([opt.seed, 3, idx])

                def lidar_pose(dt: float, t=t, part=part) -> np.ndarray:
                    x, y, yaw, _ = tl.pose(t + dt, part)
                    return base_T(x, y, yaw) @ _T(np.eye(3), LIDAR_XYZ)

                pts = sweep(world_for(part), lidar, lidar_pose, lrng)
                wr.write("/lidar/points", "sensor_msgs/msg/PointCloud2",
                         M.pointcloud2_msg(pts, t_ns, "lidar"), t_ns)
                # a sweep is labelled only if its whole 100 ms carries one label
                a = tl.label(t, "lidar")
                b = tl.label(min(t + 1.0 / lidar.rate_hz, tl.duration - 1e-9), "lidar")
                same = tl.part_index(min(t + 1.0 / lidar.rate_hz, tl.duration - 1e-9)) == part
                lidar_rows.append((t_ns, a if (a == b and same) else None))
            elif kind == 2:
                x, y, yaw, _ = tl.pose(t, part)
                v, w, _ = tl.velocity(t)
                v_m = v * 1.01 + 0.002 * odo_rng.standard_normal()
                w_m = w + 0.002 + 0.002 * odo_rng.standard_normal()
                if odo_t is not None:
                    dt = t - odo_t
                    odo[0] += v_m * dt * np.cos(odo[2])
                    odo[1] += v_m * dt * np.sin(odo[2])
                    odo[2] += w_m * dt
                odo_t = t
                wr.write("/odom", "nav_msgs/msg/Odometry",
                         M.odometry_msg(t_ns, odo[0], odo[1], odo[2], v_m, w_m), t_ns)
                wr.write("/ground_truth", "nav_msgs/msg/Odometry",
                         M.odometry_msg(t_ns, x, y, yaw, v, w, frame_id="map",
                                        pos_sd=0.001, yaw_sd=0.001), t_ns)
                pan_ = tl.pose(t, part)[3]
                tfs = [M.transform(t_ns, "odom", "base_link", base_T(odo[0], odo[1], odo[2])),
                       M.transform(t_ns, "base_link", "camera_link",
                                   _T(_rot_z(pan_), CAM_XYZ))]
                wr.write("/tf", "tf2_msgs/msg/TFMessage", M.tf_msg(tfs), t_ns)
            elif kind == 3:
                x, y, yaw, _ = tl.pose(t, part)
                v, w, acc_w = tl.velocity(t)
                c, s = np.cos(yaw), np.sin(yaw)
                acc_b = np.array([c * acc_w[0] + s * acc_w[1], -s * acc_w[0] + c * acc_w[1],
                                  9.81])
                gyro = np.array([0.0, 0.0, w]) + 0.003 * imu_rng.standard_normal(3)
                acc_b = acc_b + 0.02 * imu_rng.standard_normal(3)
                wr.write("/imu/data", "sensor_msgs/msg/Imu",
                         M.imu_msg(t_ns, yaw, gyro, acc_b), t_ns)

    labels = build_labels(cam_rows, lidar_rows)
    lp = labels_path_for(out)
    write_labels(lp, labels)
    return SimResult(out, lp, n_frames, n_scans, tl.stamp_s(tl.duration), labels, steps)


def _runs(rows: list[tuple[int, str | None]], cond: str) -> list[tuple[int, int]]:
    out: list[tuple[int, int]] = []
    start: int | None = None
    last = 0
    for t, lab in rows:
        has = lab is not None and cond in lab.split(";")
        if has and start is None:
            start = t
        if not has and start is not None:
            out.append((start, last))
            start = None
        last = t
    if start is not None:
        out.append((start, last))
    return out


def build_labels(cam_rows: list[tuple[int, str | None]],
                 lidar_rows: list[tuple[int, str | None]]) -> list[tuple[int, int, str]]:
    """Label intervals from per-sensor rows.

    A condition's intervals are runs of its own sensor's rows. ``healthy`` intervals cover runs
    of rows (both sensors, in time order) where every row is labelled and the sensors together
    are not all in a condition; a condition overrides ``healthy`` on the sensors that can show
    it (see :mod:`frontdiag.scoring`), so "camera healthy, LiDAR degenerate" is both intervals.
    """
    out: list[tuple[int, int, str]] = []
    for cond in LABELS:
        if cond == HEALTHY:
            continue
        sensors = CONDITION_SENSORS[cond]
        rows = cam_rows if "camera" in sensors else lidar_rows
        out += [(a, b, cond) for a, b in _runs(rows, cond)]
    merged = sorted([(t, "camera", lab) for t, lab in cam_rows]
                    + [(t, "lidar", lab) for t, lab in lidar_rows])
    # the latest label of each sensor as we sweep through time
    state: dict[str, str | None] = {"camera": None, "lidar": None}
    have = {"camera": bool(cam_rows), "lidar": bool(lidar_rows)}
    start: int | None = None
    last = 0
    for t, sensor, lab in merged:
        state[sensor] = lab
        known = [state[s] for s in state if have[s]]
        ok = lab is not None and all(v is not None for v in known) and \
            any(v == HEALTHY for v in known)
        if ok and start is None:
            start = t
        if not ok and start is not None:
            out.append((start, last, HEALTHY))
            start = None
        last = t
    if start is not None:
        out.append((start, last, HEALTHY))
    return sorted(out)


def write_labels(path: Path, labels: list[tuple[int, int, str]]) -> None:
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_start_ns", "t_end_ns", "condition"])
        for a, b, c in labels:
            w.writerow([a, b, c])
