"""``diagnostics.mcap``: the analysis on the recording's own clock, for Foxglove / Lichtblick.

Every message is logged at the log time of the recording message it describes and stamped with
that message's header stamp, so opening this file together with the recording lines everything
up (an image and its annotations share the stamp, which is how the Image panel pairs them).
ROS 2 (``cdr``) encoding with ``ros2msg`` schemas, written with the ``mcap`` package and
serialised by rosbags' typestore:

==================================  =====================================  =====================
topic                               type                                   written
==================================  =====================================  =====================
``/diagnostics``                    diagnostic_msgs/msg/DiagnosticArray    per analysed row
``/frontdiag/camera/metrics``       frontdiag_msgs/msg/CameraMetrics       per camera row
``/frontdiag/lidar/metrics``        frontdiag_msgs/msg/LidarMetrics        per LiDAR row
``/frontdiag/camera/annotations``   foxglove_msgs/msg/ImageAnnotations     per camera frame
``/frontdiag/lidar/used_points``    sensor_msgs/msg/PointCloud2            per LiDAR scan
``/frontdiag/lidar/weak_direction`` visualization_msgs/msg/MarkerArray     per registered scan
``/rosout``                         rcl_interfaces/msg/Log                 per episode
==================================  =====================================  =====================

The metrics messages carry every numeric column of the table for the sensor as a float64 field
(so a Plot panel draws ``/frontdiag/camera/metrics.entropy_norm``), the verdict, the rules that
fired, and a ``thresholds`` sub-message with each rule threshold as a constant field
(``.thresholds.fd_cam_001_entropy_norm``), which draws as a line beside the metric.

Annotations and points stream out as the frontend produces them (memory stays flat); the
per-row diagnostics follow once the rules have read the whole table (verdicts need neighbours).
MCAP does not require messages in time order; readers order them by the index.

With ``analyze --jobs N`` the frames are analysed in other processes: each window streams its
annotations (or the LiDAR task its points) into a part file of its own
(:meth:`DiagnosticsWriter.part`), and the writer of the result copies the parts in, in window
order (:meth:`DiagnosticsWriter.merge_part`), with the log times and frame ids the windows
read, so the file holds the same messages as a single-process run's.
"""

from __future__ import annotations

import logging
import math
import re
import struct
from array import array
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any

import numpy as np

from frontdiag.io.readers import DIAGNOSTICS_NAME
from frontdiag.io.writer import stamp as _stamp
from frontdiag.metrics import METRICS
from frontdiag.records import (
    KP_INLIER,
    KP_OUTLIER,
    KP_TRACKED,
    KP_UNTRACKED,
    CameraAnnotation,
    CameraFrame,
    LidarScan,
    ScanAnnotation,
)

if TYPE_CHECKING:  # pandas is only needed after the pass (a window worker never loads it)
    import pandas as pd

log = logging.getLogger(__name__)

DIAGNOSTICS_FILE = DIAGNOSTICS_NAME

TOPIC_DIAGNOSTICS = "/diagnostics"
TOPIC_METRICS = "/frontdiag/{sensor}/metrics"
TOPIC_ANNOTATIONS = "/frontdiag/camera/annotations"
TOPIC_USED_POINTS = "/frontdiag/lidar/used_points"
TOPIC_WEAK_DIR = "/frontdiag/lidar/weak_direction"
TOPIC_LOG = "/rosout"

T_ANNOTATIONS = "foxglove_msgs/msg/ImageAnnotations"
T_DIAG = "diagnostic_msgs/msg/DiagnosticArray"
T_CLOUD = "sensor_msgs/msg/PointCloud2"
T_MARKERS = "visualization_msgs/msg/MarkerArray"
T_LOG = "rcl_interfaces/msg/Log"

# Foxglove's ROS 2 image-annotation messages (foxglove_msgs), declared here so no ROS install
# is needed; field for field the published foxglove_msgs definitions.
_FOXGLOVE_MSGS = {
    "foxglove_msgs/msg/Point2": "float64 x\nfloat64 y\n",
    "foxglove_msgs/msg/Color": "float64 r\nfloat64 g\nfloat64 b\nfloat64 a\n",
    "foxglove_msgs/msg/CircleAnnotation":
        "builtin_interfaces/Time timestamp\nfoxglove_msgs/Point2 position\nfloat64 diameter\n"
        "float64 thickness\nfoxglove_msgs/Color fill_color\nfoxglove_msgs/Color outline_color\n",
    "foxglove_msgs/msg/PointsAnnotation":
        "builtin_interfaces/Time timestamp\nuint8 UNKNOWN=0\nuint8 POINTS=1\nuint8 LINE_LOOP=2\n"
        "uint8 LINE_STRIP=3\nuint8 LINE_LIST=4\nuint8 type\nfoxglove_msgs/Point2[] points\n"
        "foxglove_msgs/Color outline_color\nfoxglove_msgs/Color[] outline_colors\n"
        "foxglove_msgs/Color fill_color\nfloat64 thickness\n",
    "foxglove_msgs/msg/TextAnnotation":
        "builtin_interfaces/Time timestamp\nfoxglove_msgs/Point2 position\nstring text\n"
        "float64 font_size\nfoxglove_msgs/Color text_color\nfoxglove_msgs/Color background_color\n",
    "foxglove_msgs/msg/ImageAnnotations":
        "foxglove_msgs/CircleAnnotation[] circles\nfoxglove_msgs/PointsAnnotation[] points\n"
        "foxglove_msgs/TextAnnotation[] texts\n",
}

# colours shared with the PNG renderer (RGBA 0-1): inliers green, outliers red
COLORS: dict[str, tuple[float, float, float, float]] = {
    "inlier": (0.10, 0.85, 0.25, 1.0),
    "outlier": (0.95, 0.20, 0.15, 1.0),
    "tracked": (1.0, 0.80, 0.10, 1.0),
    "untracked": (0.80, 0.80, 0.80, 0.8),
    "grid": (1.0, 1.0, 1.0, 0.45),
    "flow": (0.0, 0.85, 1.0, 0.9),
    "text": (1.0, 1.0, 1.0, 1.0),
    "text_bg": (0.0, 0.0, 0.0, 0.55),
}
KP_CLASSES = ((KP_INLIER, "inlier"), (KP_OUTLIER, "outlier"), (KP_TRACKED, "tracked"),
              (KP_UNTRACKED, "untracked"))

LEVEL = {"ok": 0, "warn": 1, "fail": 2}
LOG_LEVEL = {"warn": 30, "fail": 40}
MAX_USED_POINTS = 8192
"""Used points written per scan at most (every k-th in order): the cloud is there to see which
structure the registration had, and 20k points x 1200 scans would make the file larger than the
recording's LiDAR stream."""


def _field(name: str) -> str:
    s = re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_")
    return s if s and s[0].isalpha() else f"m_{s}"


def _fmt(v: float) -> str:
    return "nan" if not math.isfinite(v) else f"{v:.6g}"


class LogTimes:
    """Every analysed frame's log time in the recording, per topic, in two growing int64
    arrays (16 bytes a frame; a dict keyed by (topic, frame) held some 200). A frame added
    twice reads as the last time added."""

    def __init__(self) -> None:
        self._cols: dict[str, tuple[array[int], array[int]]] = {}
        self._index: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # built on first lookup

    def add(self, topic: str, frame: int, log_ns: int) -> None:
        frames, times = self._cols.setdefault(topic, (array("q"), array("q")))
        frames.append(frame)
        times.append(log_ns)
        self._index.pop(topic, None)

    def update(self, other: LogTimes) -> None:
        """Add every time of ``other`` after this one's (they win where both hold a frame)."""
        for topic, (frames, times) in other._cols.items():
            mine = self._cols.setdefault(topic, (array("q"), array("q")))
            mine[0].extend(frames)
            mine[1].extend(times)
            self._index.pop(topic, None)

    def get(self, topic: str, frame: int, default: int) -> int:
        if topic not in self._cols:
            return default
        if topic not in self._index:
            frames, times = (np.frombuffer(a, dtype=np.int64) for a in self._cols[topic])
            order = np.argsort(frames, kind="stable")  # the last added of a frame sorts last
            self._index[topic] = (frames[order], times[order])
        frames, times = self._index[topic]
        i = int(np.searchsorted(frames, frame, side="right")) - 1
        return int(times[i]) if i >= 0 and frames[i] == frame else default

    def __len__(self) -> int:
        return sum(len(f) for f, _ in self._cols.values())

    def __getstate__(self) -> dict[str, tuple[array[int], array[int]]]:
        return self._cols

    def __setstate__(self, cols: dict[str, tuple[array[int], array[int]]]) -> None:
        self._cols, self._index = cols, {}


@dataclass(frozen=True)
class DiagnosticsPart:
    """A window's part of diagnostics.mcap (:meth:`DiagnosticsWriter.part`): the file its
    annotations went to, and the log times and frame ids of the frames it analysed."""

    path: str
    log_ns: LogTimes
    frame_ids: dict[str, str]


class DiagnosticsWriter:
    """Streams frames in (``__call__`` is an ``api.FrameSink``), then ``finish(result)``.

    >>> with DiagnosticsWriter(out / "diagnostics.mcap") as w:   # doctest: +SKIP
    ...     result = run_analysis(log, opts, sink=w)
    ...     w.finish(result.table, result.verdicts, result.ruleset)
    """

    def __init__(self, path: Path | str, *, part: bool = False) -> None:
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        self.path = Path(path)
        self.is_part = part
        """A window's part file (:meth:`part`): each annotation carries its frame index as the
        MCAP sequence number, so that a merge can take a frame range from it."""
        self.ts = get_typestore(Stores.ROS2_HUMBLE)
        for name, text in _FOXGLOVE_MSGS.items():
            self.ts.register(get_types_from_msg(text, name))
        self._rec: Any = None
        self._log_ns = LogTimes()
        self._frame_ids: dict[str, str] = {}
        self.counts: dict[str, int] = {}

    # -- file --------------------------------------------------------------------------------
    def __enter__(self) -> DiagnosticsWriter:
        self.open()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def open(self) -> None:
        from frontdiag.io.writer import RecordingWriter

        self._rec = RecordingWriter(self.path, "mcap")
        self._rec.ts = self.ts  # with the foxglove_msgs and frontdiag_msgs types
        self._rec.open()

    def close(self) -> None:
        if self._rec is not None:
            self._rec.close()
            self._rec = None

    def _write(self, topic: str, msgtype: str, msg: Any, log_ns: int) -> None:
        self._rec.write(topic, msgtype, msg, log_ns)
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def _msg(self, msgtype: str, values: dict[str, Any]) -> Any:
        from frontdiag.io.writer import build_message

        return build_message(self.ts, msgtype, values)

    # -- streaming: one call per analysed frame ------------------------------------------------
    def __call__(self, row: dict[str, Any], annotation: Any,
                 record: CameraFrame | LidarScan) -> None:
        self._log_ns.add(record.topic, int(record.index), int(record.log_ns))
        if record.frame_id:
            self._frame_ids.setdefault(record.topic, record.frame_id)
        if isinstance(annotation, CameraAnnotation):
            self._rec.write_raw(TOPIC_ANNOTATIONS, T_ANNOTATIONS,
                                image_annotations_cdr(annotation, record.t_ns), record.log_ns,
                                sequence=int(record.index) if self.is_part else 0)
            self.counts[TOPIC_ANNOTATIONS] = self.counts.get(TOPIC_ANNOTATIONS, 0) + 1
        elif isinstance(annotation, ScanAnnotation) and isinstance(record, LidarScan):
            frame_id = record.frame_id or "lidar"
            self._write(TOPIC_USED_POINTS, T_CLOUD,
                        self._cloud(annotation.points, record.t_ns, frame_id), record.log_ns)
            if annotation.weak_vec is not None:
                self._write(TOPIC_WEAK_DIR, T_MARKERS,
                            self._weak_markers(annotation, record.t_ns, frame_id), record.log_ns)

    def _cloud(self, pts: np.ndarray, t_ns: int, frame_id: str) -> Any:
        pts = np.asarray(pts, np.float32).reshape(-1, 3)
        if len(pts) > MAX_USED_POINTS:
            pts = pts[:: -(-len(pts) // MAX_USED_POINTS)]
        fields = [{"name": n, "offset": 4 * i, "datatype": 7, "count": 1}
                  for i, n in enumerate("xyz")]
        return self._msg(T_CLOUD, {
            "header": {"stamp": _stamp(t_ns), "frame_id": frame_id}, "height": 1,
            "width": len(pts), "fields": fields, "is_bigendian": False, "point_step": 12,
            "row_step": 12 * len(pts), "data": np.frombuffer(pts.tobytes(), np.uint8),
            "is_dense": True})

    def _weak_markers(self, ann: ScanAnnotation, t_ns: int, frame_id: str) -> Any:
        """An arrow along the weakest translation (or the axis of the weakest rotation), 3 m
        long from the sensor, and the words."""
        v = np.asarray(ann.weak_vec, dtype=np.float64)
        nrot = 1 if ann.planar else 3
        rot, trans = v[:nrot], v[nrot:]
        if ann.planar:
            rot = np.array([0.0, 0.0, rot[0]])
            trans = np.array([trans[0], trans[1], 0.0])
        d = trans if trans @ trans >= rot @ rot else rot
        d = d / (np.linalg.norm(d) or 1.0) * 3.0
        header = {"stamp": _stamp(t_ns), "frame_id": frame_id}
        color = {"r": 1.0, "g": 0.3, "b": 0.1, "a": 1.0}
        arrow = {"header": header, "ns": "weak_direction", "id": 0, "type": 0, "action": 0,
                 "pose": {"orientation": {"w": 1.0}},
                 "scale": {"x": 0.08, "y": 0.2, "z": 0.3}, "color": color,
                 "points": [{"x": 0.0, "y": 0.0, "z": 0.0},
                            {"x": float(d[0]), "y": float(d[1]), "z": float(d[2])}],
                 "frame_locked": True}
        text = {"header": header, "ns": "weak_direction", "id": 1, "type": 9, "action": 0,
                "pose": {"position": {"x": float(d[0]), "y": float(d[1]),
                                      "z": float(d[2]) + 0.5}, "orientation": {"w": 1.0}},
                "scale": {"z": 0.4}, "color": color, "text": f"weakest: {ann.weak_dir}",
                "frame_locked": True}
        return self._msg(T_MARKERS, {"markers": [arrow, text]})

    # -- windows analysed elsewhere: part files -------------------------------------------------
    def part(self) -> DiagnosticsPart:
        """What a closed part writer hands to the result's writer (picklable)."""
        return DiagnosticsPart(str(self.path), self._log_ns, dict(self._frame_ids))

    def merge_part(self, part: DiagnosticsPart, frames: tuple[int, int | None] | None = None
                   ) -> None:
        """Copy a part file's messages in, as they were written, and take its log times and
        frame ids; ``frames`` (first, last or None) keeps only the camera annotations of those
        frames (a window continued from its neighbour's state has its first frames from that
        run, the rest from its own)."""
        from frontdiag.io.readers import stream_mcap

        first, last = frames if frames is not None else (0, None)
        with open(part.path, "rb") as f:
            for schema, channel, msg in stream_mcap(f, None):  # record by record, as written
                if frames is not None and channel.topic == TOPIC_ANNOTATIONS and not (
                        first <= msg.sequence and (last is None or msg.sequence <= last)):
                    continue
                self._rec.write_raw(channel.topic, schema.name if schema else "", msg.data,
                                    msg.log_time)
                self.counts[channel.topic] = self.counts.get(channel.topic, 0) + 1
        self._log_ns.update(part.log_ns)
        for topic, frame_id in part.frame_ids.items():
            self._frame_ids.setdefault(topic, frame_id)

    # -- after the rules: per-row diagnostics and metrics, per-episode log ----------------------
    def log_ns(self, topic: str, frame: int, t_ns: int) -> int:
        """The recording's log time of an analysed row (its stamp if it was not streamed)."""
        return self._log_ns.get(topic, int(frame), int(t_ns))

    def finish(self, table: pd.DataFrame, verdicts: Any = None, ruleset: Any = None) -> None:
        """Write the per-row messages and the episode log, then close the file."""
        from frontdiag.report.thresholds import rule_thresholds

        thresholds = rule_thresholds(ruleset) if ruleset is not None else []
        from frontdiag.output import without_attrs

        table = without_attrs(table)  # none of the messages carries the manifest
        sensors = [s for s in ("camera", "lidar")
                   if "sensor" in table.columns and (table["sensor"] == s).any()]
        for sensor in sensors:
            rows = table[table["sensor"] == sensor]
            self._write_rows(sensor, rows, [t for t in thresholds if t.sensor == sensor])
        if verdicts is not None and not verdicts.episodes.empty:
            self._write_episodes(verdicts.episodes)
        self.close()

    def _metric_columns(self, rows: pd.DataFrame, sensor: str) -> list[str]:
        import pandas as pd

        skip = {"frame", "t_ns"}
        cols = []
        for name, m in METRICS.items():
            if name in skip or m.sensor not in (sensor, "any") or name not in rows.columns:
                continue
            if pd.api.types.is_numeric_dtype(rows[name]) and not pd.api.types.is_bool_dtype(
                    rows[name]):
                cols.append(name)
        return cols

    def _register_metrics_type(self, sensor: str, cols: list[str],
                               thr_fields: list[str]) -> str:
        from rosbags.typesys import get_types_from_msg

        cap = sensor.capitalize()
        tname = f"frontdiag_msgs/msg/{cap}Thresholds"
        mname = f"frontdiag_msgs/msg/{cap}Metrics"
        thr = "".join(f"float64 {f}\n" for f in thr_fields) or "uint8 none\n"
        body = ("std_msgs/Header header\nint64 frame\nstring topic\nuint8 level\nstring verdict\n"
                "string[] rules\nstring[] conditions\nstring status\n"
                + "".join(f"float64 {_field(c)}\n" for c in cols)
                + f"frontdiag_msgs/{cap}Thresholds thresholds\n")
        if mname not in self.ts.types:
            self.ts.register(get_types_from_msg(thr, tname))
            self.ts.register(get_types_from_msg(body, mname))
        return mname

    def _write_rows(self, sensor: str, rows: pd.DataFrame, thresholds: list[Any]) -> None:
        cols = self._metric_columns(rows, sensor)
        names: dict[str, float] = {}
        for t in thresholds:
            f = t.field
            k = 2
            while f in names:
                f, k = f"{t.field}_{k}", k + 1
            names[f] = t.value
        mtype = self._register_metrics_type(sensor, cols, list(names))
        thr_msg = self._msg(mtype.replace("Metrics", "Thresholds"), names)
        topic_metrics = TOPIC_METRICS.format(sensor=sensor)
        values = {c: rows[c].to_numpy(dtype=np.float64, na_value=np.nan) for c in cols}
        t_ns = rows["t_ns"].to_numpy(dtype=np.int64)
        frames = rows["frame"].to_numpy(dtype=np.int64)
        topics = rows["topic"].astype(str).to_numpy()
        verdict = rows["verdict"].astype(str).to_numpy() if "verdict" in rows.columns else None
        fired = rows["rules"].to_numpy() if "rules" in rows.columns else None
        conds = rows["conditions"].to_numpy() if "conditions" in rows.columns else None
        status = rows["status"].astype(str).to_numpy() if "status" in rows.columns else None
        units = {c: METRICS[c].unit for c in cols}
        fields = [_field(c) for c in cols]
        # the messages are built with the typestore's classes directly (every field given, in
        # order), not from nested dicts: 300 rows of ~85 metrics built through build_message
        # took 0.2 s, as long as serialising them
        T = self.ts.types
        Metrics, Header, Time = T[mtype], T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
        Array, Status, KV = (T[T_DIAG], T["diagnostic_msgs/msg/DiagnosticStatus"],
                             T["diagnostic_msgs/msg/KeyValue"])
        order = [name for name, _ in self.ts.fielddefs[mtype][1]]
        for i in range(len(rows)):
            stamp = int(t_ns[i])
            log_ns = self.log_ns(topics[i], int(frames[i]), stamp)
            v = str(verdict[i]) if verdict is not None else "ok"
            rules = [str(r) for r in (fired[i] if fired is not None else [])]
            cnd = [str(c) for c in (conds[i] if conds is not None else [])]
            st = "" if status is None else str(status[i])
            topic = str(topics[i])
            header = Header(Time(**_stamp(stamp)), self._frame_ids.get(topic, ""))
            given = {"header": header, "frame": int(frames[i]), "topic": topic,
                     "level": LEVEL.get(v, 0), "verdict": v, "rules": rules, "conditions": cnd,
                     "status": st, "thresholds": thr_msg}
            given.update(zip(fields, (float(values[c][i]) for c in cols), strict=True))
            self._write(topic_metrics, mtype, Metrics(**{k: given[k] for k in order}), log_ns)
            message = v if not rules else f"{v}: {', '.join(rules)} ({', '.join(cnd)})"
            kv = [KV("frame", str(int(frames[i]))), KV("status", st)]
            kv += [KV(c, f"{_fmt(values[c][i])} {units[c]}".strip()) for c in cols]
            self._write(TOPIC_DIAGNOSTICS, T_DIAG, Array(header, [Status(
                LEVEL.get(v, 0), f"frontdiag {sensor} {topic}", message, topic, kv)]), log_ns)

    def _write_episodes(self, episodes: pd.DataFrame) -> None:
        for _, e in episodes.sort_values("start_t_ns", kind="stable").iterrows():
            start = int(e["start_t_ns"])
            log_ns = self.log_ns(str(e["topic"]), int(e["start_frame"]), start)
            text = f"{e['rule']} {e['summary']}"  # condition, severity, span, frames, peaks
            self._write(TOPIC_LOG, T_LOG, self._msg(T_LOG, {
                "stamp": _stamp(start), "level": LOG_LEVEL.get(str(e["severity"]), 20),
                "name": f"frontdiag/{e['condition']}", "msg": text, "file": "", "function": str(e["rule"]),
                "line": 0}), log_ns)


# -- the camera annotations, encoded directly --------------------------------------------------

@dataclass(frozen=True)
class _Drawn:
    """What one frame's ImageAnnotations holds: point sets (type, (N, 2) float64 points,
    colour name, thickness; the outline and fill take the colour, except the line lists' fill)
    and the grid's count labels (x, y, text, font size)."""

    points: list[tuple[int, np.ndarray, str, float]]
    texts: list[tuple[float, float, str, float]]


def _drawn(ann: CameraAnnotation) -> _Drawn:
    """Keypoints by state, the 8x6 grid with its counts, the inliers' flow from the reference
    keyframe."""
    points: list[tuple[int, np.ndarray, str, float]] = []
    texts: list[tuple[float, float, str, float]] = []
    rows, cols = ann.grid_counts.shape if ann.grid_counts.ndim == 2 else (0, 0)
    w, h = float(ann.width), float(ann.height)
    grid = bool(rows and cols and w and h)
    if grid:
        seg: list[tuple[float, float]] = []
        for i in range(1, cols):
            x = w * i / cols
            seg += [(x, 0.0), (x, h)]
        for j in range(1, rows):
            y = h * j / rows
            seg += [(0.0, y), (w, y)]
        points.append((4, np.array(seg, np.float64).reshape(-1, 2), "grid", 1.0))
    if len(ann.flow_cur):
        flow = np.stack([np.asarray(ann.flow_ref, np.float64),
                         np.asarray(ann.flow_cur, np.float64)], axis=1).reshape(-1, 2)
        points.append((4, flow, "flow", 1.0))
    for state, name in KP_CLASSES:
        sel = ann.xy[ann.state == state]
        if len(sel):
            points.append((1, np.asarray(sel, np.float64).reshape(-1, 2), name, 4.0))
    if grid:
        size = max(10.0, min(w / cols, h / rows) / 4)
        for j in range(rows):
            for i in range(cols):
                texts.append((w * i / cols + 3, h * j / rows + size + 2,
                              str(int(ann.grid_counts[j, i])), size))
    return _Drawn(points, texts)


class _Cdr:
    """Little-endian CDR as ROS 2 writes it (the encapsulation header, then each field aligned
    to its size counted from after the header), for the one message frontdiag writes per
    camera frame. The keypoints go in as whole float64 arrays: serialising ~1 000 Point2
    message objects one by one through the typestore cost 3.7 ms a frame at 640x480, as much as
    a third of the frame's analysis. ``tests/test_visual_outputs.py`` checks the bytes against
    rosbags' serialiser of the same message."""

    def __init__(self) -> None:
        self.parts: list[bytes] = []
        self.n = 0

    def _raw(self, b: bytes) -> None:
        self.parts.append(b)
        self.n += len(b)

    def _align(self, size: int) -> None:
        pad = -self.n % size
        if pad:
            self._raw(bytes(pad))

    def u8(self, v: int) -> None:
        self._raw(struct.pack("<B", v))

    def u32(self, v: int) -> None:
        self._align(4)
        self._raw(struct.pack("<I", v))

    def time(self, t_ns: int) -> None:
        self._align(4)
        st = _stamp(t_ns)
        self._raw(struct.pack("<iI", st["sec"], st["nanosec"]))

    def f64(self, *v: float) -> None:
        self._align(8)
        self._raw(struct.pack(f"<{len(v)}d", *v))

    def f64_array(self, a: np.ndarray) -> None:
        if a.size:
            self._align(8)
            self._raw(np.ascontiguousarray(a, "<f8").tobytes())

    def string(self, text: str) -> None:
        b = text.encode() + b"\0"
        self.u32(len(b))
        self._raw(b)

    def data(self) -> bytes:
        return b"\x00\x01\x00\x00" + b"".join(self.parts)


def image_annotations_cdr(ann: CameraAnnotation, t_ns: int) -> bytes:
    """``foxglove_msgs/msg/ImageAnnotations`` of one frame (:func:`_drawn`), CDR-encoded."""
    d = _drawn(ann)
    c = _Cdr()
    clear = COLORS["text_bg"]
    c.u32(0)  # circles
    c.u32(len(d.points))
    for kind, pts, name, thickness in d.points:
        c.time(t_ns)
        c.u8(kind)
        c.u32(len(pts))
        c.f64_array(pts)
        c.f64(*COLORS[name])  # outline_color
        c.u32(0)  # outline_colors
        c.f64(*(clear if kind == 4 else COLORS[name]))  # fill_color
        c.f64(thickness)
    c.u32(len(d.texts))
    for x, y, text, size in d.texts:
        c.time(t_ns)
        c.f64(x, y)
        c.string(text)
        c.f64(size, *COLORS["text"], *COLORS["text_bg"])
    return c.data()
