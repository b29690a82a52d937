"""The library API: ``analyze(path, ...) -> DataFrame``, plus the richer :func:`run_analysis`.

One streaming pass: messages are read in log-time order, decoded one at a time and handed to the
camera and LiDAR frontends; only the per-frame rows are kept, never the pixels or points, so
memory does not grow with the length of the recording.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from frontdiag import __version__
from frontdiag.errors import DecodeError, FrontdiagError, RecordingError
from frontdiag.io.camera_info import (
    HOW_TO_PASS_K,
    from_camera_info,
    load_camera_info_yaml,
    parse_intrinsics,
)
from frontdiag.io.images import GrayConverter
from frontdiag.io.readers import RawMessage, Recording, open_recording
from frontdiag.io.topics import TopicChoice, choose_topics
from frontdiag.metrics import CAMERA_COLUMNS, LIDAR_COLUMNS
from frontdiag.records import CameraFrame, Intrinsics, LidarScan
from frontdiag.timing import GapDetector
from frontdiag.versions import versions

log = logging.getLogger(__name__)

GAP_STATUS = "after_gap"  # first row after a gap: the frontend started afresh (no reference)

ProgressFn = Callable[[int, int | None], None]
"""progress(frames_done, frames_expected_or_None)."""


@dataclass
class AnalysisOptions:
    """Everything that selects what analyze reads. Frontend parameters live in their own
    dataclasses (``CameraParams``, ``LidarParams``)."""

    camera_topic: str | None = None
    lidar_topic: str | None = None
    odom_topic: str | None = None
    use_camera: bool = True
    use_lidar: bool = True
    intrinsics: str | None = None  # "fx,fy,cx,cy"
    camera_info_file: str | None = None
    start_s: float | None = None  # seconds from the recording start (log time)
    end_s: float | None = None
    max_frames: int | None = None  # per sensor
    stride: int = 1
    camera_params: Any = None  # frontdiag.camera.frontend.CameraParams
    lidar_params: Any = None  # frontdiag.lidar.frontend.LidarParams
    rules: bool = True  # evaluate the failure taxonomy (rules/*.toml) over the table
    rules_dir: str | None = None
    rules_overrides: str | None = None
    select: list[str] | None = None
    ignore: list[str] | None = None


@dataclass
class TopicStats:
    messages: int = 0
    analysed: int = 0
    skipped_undecodable: int = 0
    first_error: str | None = None
    non_monotonic_stamps: int = 0
    zero_stamps: int = 0
    last_t_ns: int | None = None
    gaps: int = 0  # gaps in the recording after which the frontend started afresh


@dataclass
class Analysis:
    """The result of one pass: the per-frame table and everything needed to describe it."""

    table: pd.DataFrame
    manifest: dict[str, Any]
    choice: TopicChoice
    intrinsics: Intrinsics | None
    notes: list[str] = field(default_factory=list)
    fault: FrontdiagError | None = None  # damage or bad input met after some frames
    interrupted: bool = False
    verdicts: Any = None  # frontdiag.verdicts.Verdicts when rules were evaluated
    ruleset: Any = None


# --------------------------------------------------------------------------------------------
# decoding helpers
# --------------------------------------------------------------------------------------------

def header_stamp_ns(msg: Any) -> int:
    st = msg.header.stamp
    return int(st.sec) * 1_000_000_000 + int(st.nanosec)


def odometry_pose(msg: Any) -> np.ndarray:
    """4x4 pose from nav_msgs/Odometry."""
    p = msg.pose.pose.position
    q = msg.pose.pose.orientation
    x, y, z, w = float(q.x), float(q.y), float(q.z), float(q.w)
    n = x * x + y * y + z * z + w * w
    s = 2.0 / n if n > 0 else 0.0
    R = np.array([
        [1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
        [s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w)],
        [s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y)],
    ])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = [float(p.x), float(p.y), float(p.z)]
    return T


def resolve_intrinsics(rec: Recording, choice: TopicChoice, opts: AnalysisOptions,
                       notes: list[str]) -> Intrinsics | None:
    """Explicit options win over the recording's CameraInfo (and the note says so)."""
    from_rec: Intrinsics | None = None
    if choice.camera_info:
        for raw in rec.messages([choice.camera_info]):
            try:
                from_rec = from_camera_info(rec.deserialize(raw), choice.camera_info)
            except FrontdiagError:
                raise
            except Exception as exc:
                notes.append(f"CameraInfo on {choice.camera_info} undecodable ({exc})")
            if from_rec is None:
                notes.append(f"CameraInfo on {choice.camera_info} has no K (all zeros)")
            break
    explicit: Intrinsics | None = None
    if opts.intrinsics:
        explicit = parse_intrinsics(opts.intrinsics)
    elif opts.camera_info_file:
        explicit = load_camera_info_yaml(opts.camera_info_file)
    if explicit is not None:
        if from_rec is not None:
            notes.append(f"using {explicit.source} instead of {from_rec.source}")
        return explicit
    return from_rec


def _expected(count: int | None, opts: AnalysisOptions, rec: Recording) -> int | None:
    if count is None:
        return opts.max_frames
    if (opts.start_s is not None or opts.end_s is not None) and rec.start_ns and rec.end_ns:
        span = (rec.end_ns - rec.start_ns) / 1e9
        lo = max(opts.start_s or 0.0, 0.0)
        hi = min(opts.end_s if opts.end_s is not None else span, span)
        count = int(count * max(hi - lo, 0.0) / span) + 1 if span > 0 else count
    n = -(-count // max(opts.stride, 1))
    return min(n, opts.max_frames) if opts.max_frames else n


def _window(rec: Recording, opts: AnalysisOptions) -> tuple[int | None, int | None]:
    start = rec.start_ns
    s = e = None
    if opts.start_s is not None:
        if opts.start_s < 0:
            raise FrontdiagError(f"--start {opts.start_s}: must be >= 0 seconds")
        s = (start or 0) + round(opts.start_s * 1e9)
    if opts.end_s is not None:
        if opts.start_s is not None and opts.end_s <= opts.start_s:
            raise FrontdiagError(f"--end {opts.end_s} must be after --start {opts.start_s}")
        e = (start or 0) + round(opts.end_s * 1e9)
    return s, e


# --------------------------------------------------------------------------------------------
# the pass
# --------------------------------------------------------------------------------------------

class _SensorStream:
    """Selection (stride, max frames), stamps and skip counting for one topic."""

    def __init__(self, topic: str, opts: AnalysisOptions) -> None:
        self.topic = topic
        self.opts = opts
        self.stats = TopicStats()
        self.index = -1
        self.in_window = 0
        self.window_start: int | None = None
        self.gaps = GapDetector()

    def analyse(self, record: CameraFrame | LidarScan, frontend: Any, sensor: str,
                rec_start: int) -> dict[str, Any]:
        """One table row for a decoded record; the frontend starts afresh after a gap."""
        gap = self.gaps.observe(record.t_ns)
        if gap:
            frontend.reset()
            self.stats.gaps += 1
        row = _row(frontend.process(record), record, sensor, rec_start)
        if gap:
            row["status"] = GAP_STATUS
        self.stats.analysed += 1
        return row

    def admit(self, log_ns: int) -> bool:
        """Called for every message on the topic; True when it is selected for analysis.

        Messages before the --start window are counted but not decoded, so ``frame`` numbers
        are the same whatever window is analysed; the stride counts from the window start.
        """
        self.index += 1
        if self.window_start is not None and log_ns < self.window_start:
            return False
        self.in_window += 1
        self.stats.messages += 1
        if (self.in_window - 1) % max(self.opts.stride, 1):
            return False
        return not (self.opts.max_frames and self.stats.analysed >= self.opts.max_frames)

    @property
    def full(self) -> bool:
        return bool(self.opts.max_frames and self.stats.analysed >= self.opts.max_frames)

    def stamp(self, msg: Any, log_ns: int) -> int:
        try:
            t = header_stamp_ns(msg)
        except AttributeError:
            t = 0
        if t == 0:
            self.stats.zero_stamps += 1
            t = log_ns
        if self.stats.last_t_ns is not None and t <= self.stats.last_t_ns:
            self.stats.non_monotonic_stamps += 1
        self.stats.last_t_ns = t
        return t

    def skip(self, exc: Exception) -> None:
        self.stats.skipped_undecodable += 1
        if self.stats.first_error is None:
            self.stats.first_error = str(exc)


def iter_camera_frames(rec: Recording, topic: str, msgtype: str,
                       opts: AnalysisOptions | None = None,
                       stream: _SensorStream | None = None) -> Iterator[CameraFrame]:
    """Decode the selected frames of one image topic (used by the decode-only benchmark)."""
    opts = opts or AnalysisOptions()
    stream = stream or _SensorStream(topic, opts)
    conv = GrayConverter(topic)
    s, e = _window(rec, opts)
    stream.window_start = s
    for raw in rec.messages([topic], None, e):
        if stream.full:
            break
        if not stream.admit(raw.log_ns):
            continue
        frame = _decode_camera(rec, raw, stream, conv)
        if frame is not None:
            stream.stats.analysed += 1
            yield frame


def _decode_camera(rec: Recording, raw: RawMessage, stream: _SensorStream,
                   conv: GrayConverter) -> CameraFrame | None:
    t0 = time.perf_counter()
    try:
        msg = rec.deserialize(raw)
        t_ns = stream.stamp(msg, raw.log_ns)
        gray, encoding = conv(msg, raw.msgtype)
    except DecodeError as exc:
        stream.skip(exc)
        return None
    except Exception as exc:  # a message the deserialiser cannot parse
        stream.skip(DecodeError(raw.topic, "message", f"undecodable ({exc})"))
        return None
    ms = (time.perf_counter() - t0) * 1e3
    return CameraFrame(index=stream.index, t_ns=t_ns, log_ns=raw.log_ns, topic=raw.topic,
                       gray=gray, encoding=encoding, ms_decode=ms)


def _decode_lidar(rec: Recording, raw: RawMessage, stream: _SensorStream) -> LidarScan | None:
    from dataclasses import replace

    from frontdiag.lidar.decode import decode_laserscan, decode_pointcloud2

    t0 = time.perf_counter()
    try:
        msg = rec.deserialize(raw)
        t_ns = stream.stamp(msg, raw.log_ns)
        fn = decode_laserscan if raw.msgtype.endswith("LaserScan") else decode_pointcloud2
        scan = fn(msg, topic=raw.topic, index=stream.index, log_ns=raw.log_ns)
    except DecodeError as exc:
        stream.skip(exc)
        return None
    except Exception as exc:
        stream.skip(DecodeError(raw.topic, "message", f"undecodable ({exc})"))
        return None
    # one stamp rule for every sensor: header stamp, log time when the stamp is zero
    return replace(scan, t_ns=t_ns, ms_decode=(time.perf_counter() - t0) * 1e3)


def run_analysis(path: Path | str, options: AnalysisOptions | None = None,
                 progress: ProgressFn | None = None) -> Analysis:
    """Re-run the frontend on a recording and return the per-frame table with its manifest.

    Damage met part-way (a truncated file, an undecodable topic) does not lose the frames
    before it: they are returned with ``Analysis.fault`` set. Ctrl-C does the same with
    ``Analysis.interrupted``.
    """
    opts = options or AnalysisOptions()
    if opts.stride < 1:
        raise FrontdiagError(f"--stride {opts.stride}: must be >= 1")
    if opts.max_frames is not None and opts.max_frames < 1:
        raise FrontdiagError(f"--max-frames {opts.max_frames}: must be >= 1")
    path = Path(path)
    t_start = time.perf_counter()
    ruleset = None
    if opts.rules:  # load (and validate) the rules before spending time on the recording
        from frontdiag.verdicts import load_ruleset

        ruleset = load_ruleset(
            Path(opts.rules_dir) if opts.rules_dir else None,
            Path(opts.rules_overrides) if opts.rules_overrides else None,
            select=opts.select, ignore=opts.ignore)
    notes: list[str] = []
    rows: list[dict[str, Any]] = []
    fault: FrontdiagError | None = None
    interrupted = False
    with open_recording(path) as rec:
        topic_infos = rec.topics
        choice = choose_topics(topic_infos, camera_topic=opts.camera_topic,
                               lidar_topic=opts.lidar_topic, odom_topic=opts.odom_topic,
                               use_camera=opts.use_camera, use_lidar=opts.use_lidar)
        notes.extend(choice.notes)
        intr = resolve_intrinsics(rec, choice, opts, notes) if choice.camera else None
        if choice.camera and intr is None:
            notes.append(f"no intrinsics: E, parallax, rotation and pose information are not "
                         f"computed; {HOW_TO_PASS_K}")
        cam_front = lid_front = None
        cam_stream = lid_stream = None
        conv = None
        counts = {t.topic: t.count for t in topic_infos}
        expected = 0
        if choice.camera:
            from frontdiag.camera.frontend import CameraFrontend, CameraParams

            cparams = opts.camera_params or CameraParams()
            cam_front = CameraFrontend(cparams, intr)
            cam_stream = _SensorStream(choice.camera, opts)
            conv = GrayConverter(choice.camera)
            expected += _expected(counts.get(choice.camera), opts, rec) or 0
        if choice.lidar:
            from frontdiag.lidar.frontend import LidarFrontend, LidarParams

            lparams = opts.lidar_params or LidarParams()
            lid_front = LidarFrontend(lparams)
            lid_stream = _SensorStream(choice.lidar, opts)
            expected += _expected(counts.get(choice.lidar), opts, rec) or 0
        rec_start = rec.start_ns or 0
        s, e = _window(rec, opts)
        read_topics = [t for t in (choice.camera, choice.lidar, choice.odometry) if t]
        for stream in (cam_stream, lid_stream):
            if stream is not None:
                stream.window_start = s
        done = 0
        try:
            for raw in rec.messages(read_topics, None, e):
                if raw.topic == choice.odometry and lid_front is not None:
                    try:
                        msg = rec.deserialize(raw)
                        lid_front.add_odometry(header_stamp_ns(msg), odometry_pose(msg))
                    except Exception as exc:
                        log.debug("odometry message skipped: %s", exc)
                    continue
                if raw.topic == choice.camera and cam_stream and cam_front and conv:
                    if cam_stream.full and (lid_stream is None or lid_stream.full):
                        break
                    if not cam_stream.admit(raw.log_ns):
                        continue
                    frame = _decode_camera(rec, raw, cam_stream, conv)
                    if frame is None:
                        _check_all_failed(cam_stream)
                        continue
                    rows.append(cam_stream.analyse(frame, cam_front, "camera", rec_start))
                elif raw.topic == choice.lidar and lid_stream and lid_front:
                    if lid_stream.full and (cam_stream is None or cam_stream.full):
                        break
                    if not lid_stream.admit(raw.log_ns):
                        continue
                    scan = _decode_lidar(rec, raw, lid_stream)
                    if scan is None:
                        _check_all_failed(lid_stream)
                        continue
                    rows.append(lid_stream.analyse(scan, lid_front, "lidar", rec_start))
                else:
                    continue
                done += 1
                if progress:
                    progress(done, expected or None)
        except KeyboardInterrupt:
            interrupted = True
        except FrontdiagError as exc:
            fault = exc
        if rec.fault is not None and fault is None:
            fault = RecordingError(path, rec.fault.message.split(": ", 1)[-1],
                                   hint="the frames before the damage were analysed and kept")
        for stream in (cam_stream, lid_stream):
            if stream is None:
                continue
            st = stream.stats
            if st.analysed == 0 and st.skipped_undecodable and fault is None:
                fault = DecodeError(stream.topic, "message",
                                    f"no message could be decoded ({st.skipped_undecodable} "
                                    f"skipped; first: {st.first_error})")
            if st.non_monotonic_stamps:
                notes.append(f"{stream.topic}: {st.non_monotonic_stamps} non-monotonic header "
                             "stamps")
            if st.zero_stamps:
                notes.append(f"{stream.topic}: {st.zero_stamps} zero header stamps (log time "
                             "used)")
            if st.skipped_undecodable:
                notes.append(f"{stream.topic}: {st.skipped_undecodable} undecodable messages "
                             f"skipped (first: {st.first_error})")
            if st.gaps:
                notes.append(f"{stream.topic}: {st.gaps} gap(s) in the recording; the frontend "
                             f"started afresh after each (rows with status {GAP_STATUS})")
        table = _table(rows)
        manifest = _manifest(path, rec, choice, intr, opts, cam_stream, lid_stream, notes,
                             fault, interrupted, time.perf_counter() - t_start)
    table.attrs["manifest"] = manifest
    verdicts = None
    if ruleset is not None:
        from frontdiag.verdicts import evaluate

        verdicts = evaluate(table, ruleset)
        notes.extend(verdicts.notes)
        manifest["notes"] = list(notes)
        table = verdicts.table
        table.attrs["manifest"] = manifest
    return Analysis(table=table, manifest=manifest, choice=choice, intrinsics=intr, notes=notes,
                    fault=fault, interrupted=interrupted, verdicts=verdicts, ruleset=ruleset)


def _check_all_failed(stream: _SensorStream) -> None:
    """Stop early when a topic cannot be decoded at all (e.g. an unknown encoding)."""
    st = stream.stats
    if st.analysed == 0 and st.skipped_undecodable >= 10:
        raise DecodeError(stream.topic, "message",
                          f"the first {st.skipped_undecodable} messages could not be decoded "
                          f"({st.first_error})")


def _row(metrics: dict[str, Any], rec: CameraFrame | LidarScan, sensor: str,
         rec_start: int) -> dict[str, Any]:
    """The identifying columns, the frontend's metrics, and decode time added into ms_total."""
    row: dict[str, Any] = {"frame": rec.index, "t_ns": rec.t_ns,
                           "t_rel_s": (rec.log_ns - rec_start) / 1e9, "sensor": sensor,
                           "topic": rec.topic}
    row.update(metrics)
    row["ms_decode"] = rec.ms_decode
    row["ms_total"] = float(metrics.get("ms_total", 0.0)) + rec.ms_decode
    if isinstance(rec, CameraFrame):
        row["width"], row["height"] = int(rec.gray.shape[1]), int(rec.gray.shape[0])
    return row


def _table(rows: list[dict[str, Any]]) -> pd.DataFrame:
    """Rows in time order with the contract columns first."""
    lead = list(dict.fromkeys(["frame", "t_ns", "t_rel_s", "sensor", "topic",
                               *CAMERA_COLUMNS, *LIDAR_COLUMNS]))
    if not rows:
        return pd.DataFrame(columns=lead)
    df = pd.DataFrame.from_records(rows)
    for col in lead:
        if col not in df.columns:
            df[col] = np.nan
    rest = [c for c in df.columns if c not in lead]
    df = df[lead + rest]
    return df.sort_values(["t_ns", "sensor"], kind="stable").reset_index(drop=True)


def _manifest(path: Path, rec: Recording, choice: TopicChoice, intr: Intrinsics | None,
              opts: AnalysisOptions, cam: _SensorStream | None, lid: _SensorStream | None,
              notes: list[str], fault: FrontdiagError | None, interrupted: bool,
              seconds: float) -> dict[str, Any]:
    def params(p: Any) -> Any:
        try:
            return asdict(p)
        except TypeError:
            return None

    cam_params = lid_params = None
    if choice.camera:
        from frontdiag.camera.frontend import CameraParams

        cam_params = params(opts.camera_params or CameraParams())
    if choice.lidar:
        from frontdiag.lidar.frontend import LidarParams

        lid_params = params(opts.lidar_params or LidarParams())
    selection = {k: getattr(opts, k) for k in ("start_s", "end_s", "max_frames", "stride")}
    rules = None if not opts.rules else {
        "dir": opts.rules_dir, "overrides": opts.rules_overrides, "select": opts.select,
        "ignore": opts.ignore}
    return {
        "frontdiag_version": __version__,
        "versions": versions(),
        "created_unix_s": int(time.time()),
        "input": {"path": str(path.resolve()), "backend": rec.backend,
                  "size_bytes": _size(path), "start_ns": rec.start_ns, "end_ns": rec.end_ns},
        "topics": {"camera": choice.camera, "camera_type": choice.camera_type,
                   "camera_info": choice.camera_info, "lidar": choice.lidar,
                   "lidar_type": choice.lidar_type, "odometry": choice.odometry},
        "intrinsics": None if intr is None else {
            "K": intr.K.tolist(), "D": intr.D.tolist(), "model": intr.model,
            "source": intr.source, "width": intr.width, "height": intr.height},
        "selection": selection,
        "params": {"camera": cam_params, "lidar": lid_params},
        "rules": rules,
        "counts": {s.topic: asdict(s.stats) for s in (cam, lid) if s is not None},
        "notes": list(notes),
        "fault": None if fault is None else str(fault),
        "interrupted": interrupted,
        "seconds": round(seconds, 3),
    }


def _size(path: Path) -> int:
    if path.is_dir():
        return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
    return path.stat().st_size


def analyze(path: Path | str, **kwargs: Any) -> pd.DataFrame:
    """Re-run the frontend on ``path`` and return the per-frame table.

    Keyword arguments are the fields of :class:`AnalysisOptions` (``camera_topic``,
    ``intrinsics="fx,fy,cx,cy"``, ``max_frames``, ``stride``, ``start_s``, ``rules=False``, ...).
    With rules (the default) each row carries ``conditions``, ``rules`` and ``verdict``. The
    manifest is attached as ``df.attrs["manifest"]``. Damage part-way through the recording is logged
    and the frames before it are returned (``df.attrs["fault"]`` holds the message).
    """
    result = run_analysis(path, AnalysisOptions(**kwargs))
    df = result.table
    if result.fault is not None:
        log.warning("%s", result.fault)
        df.attrs["fault"] = str(result.fault)
    return df
