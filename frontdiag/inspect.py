"""What a recording holds, and what analyze would make of it (``frontdiag info``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from frontdiag.errors import TopicError
from frontdiag.io import foxglove
from frontdiag.io.images import IMAGE_TYPES, is_keyframe, is_video_message, video_format
from frontdiag.io.readers import open_recording
from frontdiag.io.topics import LIDAR_TYPES, TopicChoice, choose_topics
from frontdiag.lidar.livox import LIVOX_TYPES, header_stamp, livox_point_count
from frontdiag.lidar.velodyne import VELODYNE_TYPES, read_scan

SENSOR_TYPES = (*IMAGE_TYPES, *LIDAR_TYPES)


@dataclass
class TopicReport:
    topic: str
    msgtype: str
    count: int | None
    rate_hz: float | None = None
    first_s: float | None = None
    last_s: float | None = None
    max_gap_s: float | None = None
    detail: str = ""  # e.g. "640x480 mono8" for images


@dataclass
class RecordingReport:
    path: Path
    backend: str
    duration_s: float | None
    start_ns: int | None
    end_ns: int | None
    topics: list[TopicReport]
    choice: TopicChoice | None
    choice_error: str | None
    oddities: list[str] = field(default_factory=list)
    fault: str | None = None
    """Damage met while reading (the counts cover what was readable before it)."""
    container: str = ""
    """What the recording was read as ("ros2 bag folder (mcap, zstd messages)", "ros1 split
    bags", "ros2 split parts (3 parts, no metadata.yaml)", ...)."""

    def to_dict(self) -> dict[str, Any]:
        return {
            "path": str(self.path), "container": self.container, "backend": self.backend,
            "duration_s": self.duration_s,
            "start_ns": self.start_ns, "end_ns": self.end_ns,
            "topics": [t.__dict__ for t in self.topics],
            "analyze_would_use": None if self.choice is None else {
                "camera": self.choice.camera, "camera_info": self.choice.camera_info,
                "lidar": self.choice.lidar, "odometry": self.choice.odometry},
            "choice_error": self.choice_error, "oddities": self.oddities,
            "fault": self.fault,
        }


def inspect_recording(path: Path | str, gap_factor: float = 3.0) -> RecordingReport:
    """One pass over the log times of every topic (header stamps for sensor topics)."""
    path = Path(path)
    with open_recording(path) as rec:
        infos = rec.topics
        start, end = rec.start_ns, rec.end_ns
        times: dict[str, list[int]] = {t.topic: [] for t in infos}
        sensor_topics = {t.topic for t in infos if t.msgtype in SENSOR_TYPES}
        stamps: dict[str, list[int]] = {t: [] for t in sensor_topics}
        detail: dict[str, str] = {}
        encodings = {t.topic: t.encoding for t in infos}
        keys: dict[str, list[bool | None]] = {}  # video topics: keyframe or not, per message
        for raw in rec.messages([t.topic for t in infos]):
            times[raw.topic].append(raw.log_ns)
            if raw.topic in sensor_topics:
                try:
                    if raw.msgtype in LIVOX_TYPES:  # its header, without 10^4 point objects
                        enc = encodings.get(raw.topic) or "cdr"
                        msg = header_stamp(raw.data, enc)
                        if raw.topic not in detail:
                            detail[raw.topic] = f"Livox, {livox_point_count(raw.data, enc)} pts"
                    elif raw.msgtype in VELODYNE_TYPES:  # 1206-byte packets, not objects
                        msg = read_scan(raw.data, encodings.get(raw.topic) or "cdr", raw.topic)
                        if raw.topic not in detail:
                            detail[raw.topic] = _velodyne_detail(raw.topic, msg)
                    else:
                        msg = rec.deserialize(raw)
                    st = msg.header.stamp
                    stamps[raw.topic].append(int(st.sec) * 1_000_000_000 + int(st.nanosec))
                    if raw.topic not in detail:
                        detail[raw.topic] = _detail(msg, raw.msgtype)
                    if is_video_message(msg, raw.msgtype):
                        key = is_keyframe(msg.data, video_format(msg, raw.msgtype))
                        keys.setdefault(raw.topic, []).append(key)
                except Exception:
                    stamps[raw.topic].append(-1)
        fault = rec.fault
        backend = rec.backend
        calibration = _calibration_notes(rec, infos)
    oddities: list[str] = []
    if fault is not None:
        oddities.append(f"damaged: {fault.message}")
    for topic, flags in keys.items():
        words, odd = _keyframe_words(topic, flags)
        detail[topic] = f"{detail.get(topic, '')}, {words}" if words else detail.get(topic, "")
        oddities.extend(odd)
    reports = []
    origin = start or 0
    for info in sorted(infos, key=lambda t: t.topic):
        ts = np.asarray(times[info.topic], dtype=np.int64)
        rep = TopicReport(info.topic, info.msgtype, info.count if info.count is not None
                          else len(ts), detail=detail.get(info.topic, ""))
        if ts.size:
            rep.first_s = (int(ts.min()) - origin) / 1e9
            rep.last_s = (int(ts.max()) - origin) / 1e9
        if ts.size >= 2:
            d = np.diff(np.sort(ts)).astype(np.float64) / 1e9
            span = (ts.max() - ts.min()) / 1e9
            rep.rate_hz = (ts.size - 1) / span if span > 0 else None
            rep.max_gap_s = float(d.max())
            med = float(np.median(d))
            if info.topic in sensor_topics and med > 0 and d.max() > gap_factor * med:
                n_gaps = int(np.sum(d > gap_factor * med))
                oddities.append(f"{info.topic}: {n_gaps} gap(s) in log time, longest "
                                f"{d.max():.3f} s (median period {med:.3f} s)")
        if info.topic in stamps:
            st = np.asarray(stamps[info.topic], dtype=np.int64)
            if np.any(st == 0):
                oddities.append(f"{info.topic}: {int(np.sum(st == 0))} zero header stamps "
                                "(analyze uses log time for those)")
            good = st[st > 0]
            step = np.diff(good) if good.size >= 2 else np.zeros(0, np.int64)
            if np.any(step == 0):
                oddities.append(f"{info.topic}: {int(np.sum(step == 0))} message(s) repeat the "
                                "header stamp of the one before them (a topic recorded twice, "
                                "or relayed back; analyze skips those whose picture repeats too)")
            if np.any(step < 0):
                oddities.append(f"{info.topic}: {int(np.sum(step < 0))} non-monotonic "
                                "header stamps")
        reports.append(rep)
    choice = None
    choice_error = None
    try:
        choice = choose_topics(infos)
        oddities.extend(f"missing CameraInfo: {n}" if n.startswith("no CameraInfo") else n
                        for n in choice.notes)
    except TopicError as exc:
        choice_error = str(exc)
    oddities.extend(calibration)
    duration = (end - start) / 1e9 if start is not None and end is not None else None
    from frontdiag.io.readers import plan

    return RecordingReport(path, backend, duration, start, end, reports, choice, choice_error,
                           oddities, None if fault is None else fault.message,
                           container=plan(path).container)


def _velodyne_detail(topic: str, msg: Any) -> str:
    """The sensor model the packets name (their factory bytes), the return mode and the
    packet count of one scan."""
    from frontdiag.lidar.velodyne import VelodyneDecoder

    dec = VelodyneDecoder(topic)
    try:
        dec(msg, index=0, log_ns=0, t_ns=0)
    except Exception:  # the run reports what the decoder refuses
        return f"Velodyne, {len(msg.packets)} packets (not decodable)"
    return f"Velodyne {dec.model}, {dec.return_mode}, {len(msg.packets)} packets"


def _keyframe_words(topic: str, flags: list[bool | None]) -> tuple[str, list[str]]:
    """A video topic's keyframe spacing for its detail, and what analyze will skip: the
    messages before the first keyframe cannot be decoded."""
    if not flags or any(f is None for f in flags):
        return "", []
    at = [i for i, f in enumerate(flags) if f]
    if not at:
        return "no keyframe", [f"{topic}: no keyframe in {len(flags)} messages: no picture can "
                                "be decoded"]
    spacing = np.diff(at)
    words = (f"keyframe every {int(np.median(spacing))} msgs" if spacing.size
             else "one keyframe")
    odd = [f"{topic}: the first keyframe is message {at[0]}: the {at[0]} before it cannot be "
           "decoded and are skipped"] if at[0] else []
    return words, odd


def _detail(msg: Any, msgtype: str) -> str:
    msgtype = foxglove.ros_type(msgtype)
    if is_video_message(msg, msgtype):
        return f"video {video_format(msg, msgtype)}"
    if msgtype.endswith("/Image"):
        return f"{msg.width}x{msg.height} {msg.encoding}"
    if msgtype.endswith("CompressedImage"):
        return f"compressed {msg.format}"
    if msgtype.endswith("PointCloud2"):
        names = ",".join(f.name for f in msg.fields)
        return f"{msg.width * msg.height} pts ({names})"
    if msgtype.endswith("LaserScan"):
        return f"{len(msg.ranges)} ranges"
    return ""


def _calibration_notes(rec: Any, infos: list[Any]) -> list[str]:
    """What analyze would say of the camera's CameraInfo: K unset, or made for another image
    size (scaled, or unusable for a crop); nothing when there is no camera or no CameraInfo."""
    from frontdiag.api import AnalysisOptions, calibration_for_images
    from frontdiag.errors import FrontdiagError

    try:
        choice = choose_topics(infos)
    except TopicError:
        return []
    if not choice.camera or not choice.camera_info:
        return []
    notes: list[str] = []
    try:
        calibration_for_images(rec, choice, AnalysisOptions(), notes)
    except FrontdiagError as exc:  # a calibration no model can use: analyze stops on it
        return [str(exc)]
    return notes
