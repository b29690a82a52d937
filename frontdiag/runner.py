"""The streaming loop that feeds decoded frames to the frontends, one time window at a time.

:func:`run_stream` reads messages in log-time order, selects them (``--start``/``--end``,
stride, max frames), decodes one at a time and hands each record to its frontend; only the
per-frame rows are kept, never the pixels or points. It can be handed a window of camera frames
(:class:`FrameWindow`): the frontend starts at ``warm_from`` and runs through a warm-up whose rows
are dropped, and the rows and counts from ``own_from`` on belong to the window. Parallel windows
and fleets sit above this loop (:mod:`frontdiag.parallel`, :mod:`frontdiag.fleet`); a frontend
stays a pure, sequential function of its frames.
"""

from __future__ import annotations

import copy
import hashlib
import logging
from array import array
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from frontdiag.errors import ConfigError, DecodeError, FrontdiagError
from frontdiag.io.camera_info import CalibrationsBySize, is_rectified_topic
from frontdiag.io.decode import (
    decode_camera,
    decode_lidar,
    header_stamp_ns,
    odometry_pose,
    stamp_ns,
)
from frontdiag.io.images import GrayConverter, is_keyframe, is_video_topic, video_format
from frontdiag.io.readers import Recording
from frontdiag.io.tf import TfOdometry
from frontdiag.io.topics import TopicChoice
from frontdiag.records import GAP_STATUS, CameraFrame, Intrinsics, LidarScan
from frontdiag.rowstore import RowStore
from frontdiag.timing import GapDetector

log = logging.getLogger(__name__)


ProgressFn = Callable[[int, int | None], None]
FrameSink = Callable[[dict[str, Any], Any, CameraFrame | LidarScan], None]
"""sink(row, annotation, record) for every analysed (owned) frame, as it is analysed: the
frontend's ``last_annotation`` (keypoints, inliers, grid, flow; used points, weak direction)
passes through without being kept, so a writer can stream it (frontdiag.report.mcap_)."""
"""progress(frames_done, frames_expected_or_None)."""


@dataclass
class TopicStats:
    messages: int = 0
    analysed: int = 0
    skipped_undecodable: int = 0
    first_error: str | None = None
    last_error: str | None = None  # the latest reason (said where it differs from the first)
    non_monotonic_stamps: int = 0
    zero_stamps: int = 0
    last_t_ns: int | None = None
    gaps: int = 0  # gaps in the recording after which the frontend started afresh
    # where the image size changed (the frontend started afresh): "frame N: WxH -> W'xH': K ..."
    size_changes: list[str] = field(default_factory=list)
    # pictures that repeated the previous one exactly: with the same stamp (the message again,
    # not analysed) and with a later stamp (analysed), and the first frame of each
    repeated_messages: int = 0
    identical_pictures: int = 0
    first_repeat: int | None = None
    first_identical: int | None = None
    # how 16-bit pictures were mapped to 8 bits (GrayConverter.mono16): shift, window, note;
    # None for 8-bit pictures
    conversion: dict[str, Any] | None = None
    # where the LiDAR's motion prior came from when it was looked for on /tf (io/tf.py)
    prior_note: str | None = None


@dataclass(frozen=True)
class FrameWindow:
    """Camera frames (message indices on the topic) one run covers.

    The frontend starts at ``warm_from``; rows and counts start at ``own_from``; the run stops
    before ``own_to`` (None: the end of the selection).
    """

    warm_from: int
    own_from: int
    own_to: int | None = None


class SensorStream:
    """Selection (stride, max frames, frame window), stamps and skip counting for one topic."""

    def __init__(self, topic: str, opts: Any, frames: FrameWindow | None = None) -> None:
        self.topic = topic
        self.opts = opts
        self.frames = frames
        self.stats = TopicStats()
        self.index = -1
        self.in_window = 0
        self.window_start: int | None = None
        self.gaps = GapDetector()
        self.owned = True  # the current message counts (not warm-up)
        self.draining = False  # past the window: frames only complete rows already made
        self.sink: FrameSink | None = None
        # the last picture decoded and its stamp (``repeats``)
        self._picture: tuple[np.ndarray | None, int] = (None, 0)
        self._scan: LidarScan | None = None  # the last LiDAR sweep decoded (``repeats_scan``)
        self._stamp_counted = False  # the last stamp read was counted as not advancing
        self.decoders: dict[str, Any] = {}  # per-topic decoder state (Velodyne's sensor model)

    def analyse(self, record: CameraFrame | LidarScan, frontend: Any, sensor: str,
                rec_start: int) -> dict[str, Any]:
        """One table row for a decoded record; the frontend starts afresh after a gap."""
        gap = self.gaps.observe(record.t_ns)
        if gap:
            frontend.reset()
            if self.owned:
                self.stats.gaps += 1
        row = make_row(frontend.process(record), record, sensor, rec_start)
        if gap:
            row["status"] = GAP_STATUS
        if self.owned:
            self.stats.analysed += 1
            resized = getattr(frontend, "resized", None)
            if resized is not None:
                self.stats.size_changes.append(f"frame {record.index}: {resized}")
            if self.sink is not None:
                self.sink(row, getattr(frontend, "last_annotation", None), record)
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
        fw = self.frames
        if fw is not None and self.index < fw.warm_from:
            return False
        self.owned = not self.draining and (fw is None or self.index >= fw.own_from)
        if self.owned:
            self.stats.messages += 1
        if (self.in_window - 1) % max(self.opts.stride, 1):
            return False
        return not (self.opts.max_frames and self.stats.analysed >= self.opts.max_frames)

    def past_end(self) -> bool:
        """The next message on the topic lies past the frame window."""
        fw = self.frames
        return fw is not None and fw.own_to is not None and self.index + 1 >= fw.own_to

    @property
    def full(self) -> bool:
        return bool(self.opts.max_frames and self.stats.analysed >= self.opts.max_frames)

    def stamp(self, msg: Any, log_ns: int) -> int:
        try:
            t = header_stamp_ns(msg)
        except AttributeError:
            t = 0
        if t == 0:
            if self.owned:
                self.stats.zero_stamps += 1
            t = log_ns
        self._stamp_counted = (self.stats.last_t_ns is not None and t <= self.stats.last_t_ns
                               and self.owned)
        if self._stamp_counted:
            self.stats.non_monotonic_stamps += 1
        self.stats.last_t_ns = t
        return t

    def repeats(self, gray: np.ndarray, msg: Any, log_ns: int) -> bool:
        """Whether this message repeats the previous one: the same picture, pixel for pixel,
        with the same stamp. Such a copy (the topic recorded twice, a relay publishing it back)
        is counted and not analysed: analysed, it would read as a frame that did not move and
        matched perfectly, ratio-test rejection 0 against a scene's 0.3-0.7, and the readings
        against the recording's own level go wrong (docs/camera.md, "Repeated pictures").

        The same picture with a later stamp is analysed, and counted for the notes: a stalled
        camera whose driver goes on stamping its last picture looks exactly like a noise-free
        simulated camera standing still, which is a real observation. Uniform pictures (all
        black) repeat without any fault and are not counted.
        """
        try:
            t = stamp_ns(msg, log_ns)
        except AttributeError:
            t = log_ns
        prev, prev_t = self._picture
        if prev is None or prev.shape != gray.shape or gray.ndim != 2 or gray.size == 0 \
                or not (np.array_equal(prev[::16, ::16], gray[::16, ::16])
                        and np.array_equal(prev, gray)):
            # a sparse sample first: different pictures nearly always differ there
            self._picture = (gray, t)
            return False
        st = self.stats
        if t == prev_t:
            if self.owned:
                st.repeated_messages += 1
                if st.first_repeat is None:
                    st.first_repeat = self.index
            return True
        self._picture = (gray, t)
        if self.owned and int(gray.min()) != int(gray.max()):
            st.identical_pictures += 1
            if st.first_identical is None:
                st.first_identical = self.index
        return False

    def repeats_scan(self, scan: LidarScan) -> bool:
        """Whether this LiDAR message repeats the previous one: the same stamp and the same
        points (the topic recorded twice, or relayed back). Counted and not analysed, as a
        repeated picture is (:meth:`repeats`): registered, the copy would read as a perfect
        match with no motion. Its stamp, equal to the one before, is not counted as going
        back. Real sweeps are never equal point for point, so a later-stamped equal sweep is
        analysed as it comes."""
        prev = self._scan
        self._scan = scan
        if prev is None or prev.t_ns != scan.t_ns or prev.xyz.shape != scan.xyz.shape \
                or not np.array_equal(prev.xyz, scan.xyz):
            return False
        if self.owned:
            st = self.stats
            st.repeated_messages += 1
            if st.first_repeat is None:
                st.first_repeat = self.index
            if self._stamp_counted:  # stamp() counted the copy's stamp as not advancing
                st.non_monotonic_stamps -= 1
                self._stamp_counted = False
        return True

    def skip(self, exc: Exception) -> None:
        if not self.owned:
            return
        self.stats.skipped_undecodable += 1
        if self.stats.first_error is None:
            self.stats.first_error = str(exc)
        self.stats.last_error = str(exc)


_FOREVER_S = 1e9  # seconds (32 years): a bound that keeps nanosecond times in 64 bits


def time_window(rec: Recording, opts: Any) -> tuple[int | None, int | None]:
    """--start/--end as log times (ns); the options were validated by ``api.check_selection``.

    A start past the end of the recording is an error naming its duration; an end past it reads
    to the end.
    """
    start, end = rec.start_ns, rec.end_ns
    s = e = None
    duration = (end - start) / 1e9 if start is not None and end is not None else None
    if opts.start_s is not None:
        if duration is not None and opts.start_s > duration:
            raise ConfigError(f"--start {opts.start_s:g}: {rec.path} is only {duration:.3f} s "
                              "long", hint="see `frontdiag info` for its time span")
        s = (start or 0) + round(min(opts.start_s, _FOREVER_S) * 1e9)
    if opts.end_s is not None:
        e = (start or 0) + round(min(opts.end_s, _FOREVER_S) * 1e9)
        if end is not None:
            e = min(e, end)
    return s, e


def iter_camera_frames(rec: Recording, topic: str, msgtype: str, opts: Any = None,
                       stream: SensorStream | None = None) -> Iterator[CameraFrame]:
    """Decode the selected frames of one image topic (used by the decode-only benchmark)."""
    if opts is None:
        from frontdiag.api import AnalysisOptions

        opts = AnalysisOptions()
    stream = stream or SensorStream(topic, opts)
    conv = GrayConverter(topic, downscale=getattr(opts, "downscale", 1))
    s, e = time_window(rec, opts)
    stream.window_start = s
    for raw in rec.messages([topic], None, e):
        if stream.full:
            break
        if not stream.admit(raw.log_ns):
            continue
        frame = decode_camera(rec, raw, stream, conv)
        if frame is not None:
            stream.stats.analysed += 1
            yield frame


class StateKeys:
    """The camera state key after each frame of a pass (:func:`camera_key`), for the meeting
    test of a split run (frontdiag.parallel), kept as a 16-byte digest of the key's repr: the
    key's ints and floats written exactly, so two keys with the same digest hold the same
    values. 24 bytes a frame, where the keys themselves (the gap detector's last 20
    intervals among them) held about 600. A frame added twice reads as the last key added."""

    def __init__(self) -> None:
        self._frames: array[int] = array("q")
        self._digests = bytearray()
        self._index: dict[int, bytes] | None = None  # built on the first lookup

    @staticmethod
    def digest(key: Any) -> bytes:
        return hashlib.blake2b(repr(key).encode(), digest_size=16).digest()

    def add(self, frame: int, key: Any) -> None:
        self._frames.append(frame)
        self._digests += self.digest(key)
        self._index = None

    def update(self, other: StateKeys) -> None:
        """Add every key of ``other`` after this one's (they win where both hold a frame)."""
        self._frames.extend(other._frames)
        self._digests += other._digests
        self._index = None

    def items(self) -> Iterator[tuple[int, bytes]]:
        """(frame, digest) in the order added."""
        for i, f in enumerate(self._frames):
            yield f, bytes(self._digests[16 * i:16 * i + 16])

    def get(self, frame: int) -> bytes | None:
        """The digest of the key after ``frame``, None if it was not kept."""
        if self._index is None:
            self._index = dict(self.items())
        return self._index.get(frame)

    def matches(self, frame: int, key: Any) -> bool:
        """Whether ``key`` is the key kept after ``frame``."""
        return self.get(frame) == self.digest(key)

    def __len__(self) -> int:
        return len(self._frames)

    def __getstate__(self) -> tuple[array[int], bytearray]:
        return self._frames, self._digests

    def __setstate__(self, state: tuple[array[int], bytearray]) -> None:
        (self._frames, self._digests), self._index = state, None


@dataclass
class StreamRun:
    """What one pass of :func:`run_stream` produced."""

    rows: RowStore
    cam: SensorStream | None
    lid: SensorStream | None
    fault: FrontdiagError | None = None
    interrupted: bool = False
    keys: StateKeys = field(default_factory=StateKeys)  # camera frame -> state key after it
    stopped_at: int | None = None  # camera frame after which ``until`` stopped the pass
    end_state: Any = None  # camera hand-over state at the end (when asked)
    windows: int = 1  # camera windows analysed in parallel (frontdiag.parallel)
    part: Any = None  # a window's part of diagnostics.mcap (report.mcap_.DiagnosticsPart)


def camera_key(front: Any, stream: SensorStream) -> Any:
    """Everything camera rows after this frame depend on, in comparable form: the frontend's
    state key and the gap detector's history."""
    g = stream.gaps
    return (front.state_key(), g._last, tuple(g._dts))


def camera_state(front: Any, stream: SensorStream) -> Any:
    """A picklable hand-over of the camera frontend, its gap detector and the last picture (a
    copy: the run goes on)."""
    g = stream.gaps
    return copy.deepcopy((front.get_state(), g._last, list(g._dts), stream.stats.last_t_ns,
                          stream._picture))


def _restore_camera(front: Any, stream: SensorStream, state: Any) -> None:
    fstate, last, dts, last_t, picture = state
    front.set_state(fstate)
    stream.gaps._last, stream.gaps._dts = last, list(dts)
    stream.stats.last_t_ns = last_t
    stream._picture = picture  # a copy of it right after the hand-over is still a copy


def own_calibrations(rec: Recording, choice: TopicChoice, opts: Any,
                     intr: Intrinsics | None, limit: int | None = None
                     ) -> CalibrationsBySize | None:
    """Where K comes from the recording's CameraInfo, its messages for other image sizes (a
    camera reconfigured mid-recording, or a driver whose first CameraInfo is for another mode;
    ``limit``: messages read at most); not where the user passed a calibration."""
    if intr is None or not choice.camera_info or getattr(opts, "intrinsics", None) \
            or getattr(opts, "camera_info_file", None):
        return None
    return CalibrationsBySize(rec.path, choice.camera_info,
                              rectified=is_rectified_topic(choice.camera or ""),
                              limit=limit, downscale=getattr(opts, "downscale", 1))


def prime_converter(rec: Recording, topic: str, conv: GrayConverter, opts: Any) -> None:
    """Fix a mono16 converter's shift from the first frame of the selection, as a run from the
    start does (a window that starts later must scale its frames the same way)."""
    s, e = time_window(rec, opts)
    for raw in rec.messages([topic], s, e):
        try:
            conv(rec.deserialize(raw), raw.msgtype)
        except Exception:  # the run itself reports undecodable frames
            continue
        return


def feed_video(rec: Recording, raw: Any, conv: GrayConverter) -> None:
    """Decode a video message that is not analysed (before --start, or between --stride
    frames): the pictures after it are predicted from it."""
    try:
        conv(rec.deserialize(raw), raw.msgtype)
    except Exception as exc:  # the frames that are analysed report their own faults
        log.debug("video message on %s not decoded: %s", raw.topic, exc)


def video_feed_start(rec: Recording, topic: str, first_index: int, start_ns: int | None
                     ) -> int:
    """The message of a video topic to start decoding at for a pass whose first analysed
    message is the first at or after ``first_index`` logged at or after ``start_ns``: the last
    keyframe before it (:func:`frontdiag.io.images.is_keyframe`), so that a late --start or a
    later --jobs window does not decode the whole recording before it. 0 where keyframes
    cannot be told (VP9, AV1) or none comes before it."""
    last_key = 0
    for i, raw in enumerate(rec.messages([topic])):
        if i >= first_index and (start_ns is None or raw.log_ns >= start_ns):
            return last_key
        try:
            msg = rec.deserialize(raw)
            key = is_keyframe(msg.data, video_format(msg, raw.msgtype))
        except Exception:  # the pass itself reports undecodable messages
            continue
        if key is None:
            return 0
        if key:
            last_key = i
    return last_key


@contextmanager
def frame_boundary_interrupts() -> Iterator[Callable[[], bool]]:
    """Ctrl-C (or SIGTERM where it is handled like Ctrl-C) during the block is held until the
    pass asks, between two messages: a frame is analysed, its readings completed and its row
    kept, or none of that. An interrupt landing inside a frame would otherwise leave the
    frontend one frame ahead of the rows (the open interval then closes over a frame that is
    not in the table). A second Ctrl-C stops at once. Outside the main thread (a Dask worker's
    task) signals are not this thread's, and nothing changes."""
    import signal
    import threading

    from frontdiag.errors import interrupt_on_signal

    asked = [False]

    def hold(signum: int, frame: object) -> None:
        if asked[0]:
            raise KeyboardInterrupt
        asked[0] = True

    saved: dict[signal.Signals, Any] = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            if signal.getsignal(sig) in (signal.default_int_handler, interrupt_on_signal):
                saved[sig] = signal.signal(sig, hold)
    try:
        yield lambda: asked[0]
    finally:
        for sig, handler in saved.items():
            signal.signal(sig, handler)


def run_stream(rec: Recording, choice: TopicChoice, opts: Any, intr: Intrinsics | None, *,
               progress: ProgressFn | None = None, expected: int | None = None,
               frames: FrameWindow | None = None, resume: Any = None,
               until: Callable[[int, Any], bool] | None = None,
               record_keys: bool = False, want_end_state: bool = False,
               sink: FrameSink | None = None) -> StreamRun:
    """One sequential pass over the selected messages of ``rec``.

    ``frames`` restricts the camera to a window of frames (warm-up rows dropped); ``resume``
    starts the camera frontend from a hand-over state (:func:`camera_state`); ``until(frame,
    key)`` stops the pass after a camera frame; ``record_keys`` keeps the camera state key after
    every frame; ``sink`` sees each row kept, with what the frontend drew it from. The rows that
    can no longer change are packed as the pass goes (:class:`~frontdiag.rowstore.RowStore`).
    Faults and Ctrl-C end the pass and keep what was computed.
    """
    rows = RowStore()
    cam_front = lid_front = None
    cam_stream = lid_stream = None
    conv = None
    video = False
    if choice.camera:
        from frontdiag.camera.frontend import CameraFrontend, CameraParams

        cam_front = CameraFrontend(opts.camera_params or CameraParams(), intr,
                                   calibrations=own_calibrations(rec, choice, opts, intr))
        cam_stream = SensorStream(choice.camera, opts, frames)
        conv = GrayConverter(choice.camera, downscale=getattr(opts, "downscale", 1))
        video = is_video_topic(rec, choice.camera, choice.camera_type or "")
        # a window that starts later scales mono16 as a run from the start does; a video's
        # decoder instead sees every message from the start (feed_video)
        if frames is not None and frames.warm_from > 0 and not video:
            prime_converter(rec, choice.camera, conv, opts)
        if resume is not None:
            _restore_camera(cam_front, cam_stream, resume)
    if choice.lidar:
        from frontdiag.lidar.frontend import LidarFrontend, LidarParams

        lid_front = LidarFrontend(opts.lidar_params or LidarParams())
        lid_stream = SensorStream(choice.lidar, opts)
    out = StreamRun(rows, cam_stream, lid_stream)
    rec_start = rec.start_ns or 0
    s, e = time_window(rec, opts)
    # the transforms: the prior itself where no odometry topic is (choice.tf), and where the
    # LiDAR sits in the odometry's frame where one is (choice.tf_static)
    tf_odom = TfOdometry() if lid_front is not None and (
        choice.tf or (choice.odometry and choice.tf_static)) else None
    mount = _Mount()  # the odometry topic's child frame and the LiDAR's, once known
    odom_seen = False
    tf_topics = (choice.tf, choice.tf_static) if tf_odom is not None else ()
    read_topics = [t for t in (choice.camera, choice.lidar, choice.odometry, *tf_topics) if t]
    for stream in (cam_stream, lid_stream):
        if stream is not None:
            stream.window_start = s
            stream.sink = sink
    feed_from = 0
    if video and choice.camera and ((frames is not None and frames.warm_from > 0)
                                    or s is not None):
        feed_from = video_feed_start(rec, choice.camera, frames.warm_from if frames else 0, s)
    done = 0
    by_frame: dict[int, int] = {}  # owned camera rows' positions, for completions

    def complete() -> None:
        assert cam_front is not None
        for f, values in cam_front.take_updates():
            pos = by_frame.get(f)
            if pos is None:  # a warm-up row, not part of this run's table
                continue
            rows.update(pos, values)
        settle()

    def settle() -> None:
        if cam_front is None or not cam_front.pending:  # no row made so far can change
            rows.settled()

    # Odometry for a sweep's middle is usually logged after the sweep itself, and the prior
    # never extrapolates: hold decoded scans until odometry covers them (or stops coming).
    pending: deque[LidarScan] = deque()

    def tf_poses() -> None:
        """Hand the LiDAR frame's new poses on /tf to the prior (once its frame is chained)."""
        assert tf_odom is not None and lid_front is not None
        for t_ns, T in tf_odom.poses():
            lid_front.add_odometry(t_ns, T)

    def release(now_ns: int | None) -> None:
        while pending and lid_stream is not None and lid_front is not None:
            scan = pending[0]
            within = now_ns is not None and now_ns - scan.log_ns <= ODOM_WAIT_NS
            if within and len(pending) <= ODOM_WAIT_SCANS and not lid_front.odometry_covers(
                    lid_front.sweep_end_ns(scan)):
                return
            pending.popleft()
            rows.append(lid_stream.analyse(scan, lid_front, "lidar", rec_start))
            settle()

    with frame_boundary_interrupts() as stop_asked:
        try:
            for raw in rec.messages(read_topics, None, e):
                if stop_asked() and not (cam_stream is not None and cam_stream.draining):
                    # a window that read all its frames ends its read-on first (a keyframe
                    # interval or two): its rows are then those of every finished window
                    raise KeyboardInterrupt
                if raw.topic == choice.odometry and lid_front is not None:
                    try:
                        msg = rec.deserialize(raw)
                        lid_front.add_odometry(header_stamp_ns(msg), odometry_pose(msg))
                        odom_seen = True
                        mount.child = mount.child or str(getattr(msg, "child_frame_id", ""))
                    except Exception as exc:
                        log.debug("odometry message skipped: %s", exc)
                    release(raw.log_ns)
                    continue
                if tf_odom is not None and raw.topic in (choice.tf, choice.tf_static):
                    try:
                        tf_odom.add(rec.deserialize(raw), raw.topic == choice.tf_static,
                                    raw.log_ns)
                    except Exception as exc:
                        log.debug("tf message skipped: %s", exc)
                    if tf_odom.resolved:
                        tf_poses()
                        release(raw.log_ns)
                    continue
                if raw.topic == choice.camera and cam_stream and cam_front and conv:
                    if cam_stream.full and (lid_stream is None or lid_stream.full):
                        break
                    if cam_stream.past_end() and not cam_stream.draining:
                        if want_end_state:
                            out.end_state = camera_state(cam_front, cam_stream)
                        cam_stream.draining = True
                    if cam_stream.draining and not cam_front.pending:
                        break
                    if not cam_stream.admit(raw.log_ns):
                        # not analysed, but later pictures are decoded from it (from the last
                        # keyframe before the first message analysed)
                        if video and cam_stream.index >= feed_from:
                            feed_video(rec, raw, conv)
                        continue
                    frame = decode_camera(rec, raw, cam_stream, conv,
                                          None if video else cam_stream.repeats)
                    if frame is None:
                        # a video waits for its first keyframe, however many messages that is
                        if not (video and conv.video is not None and conv.video.pictures == 0):
                            check_all_failed(cam_stream)
                        continue
                    row = cam_stream.analyse(frame, cam_front, "camera", rec_start)
                    if cam_stream.owned:
                        by_frame[frame.index] = rows.append(row)
                    # after the row is registered: a frame that closes its keyframe interval
                    # completes readings of its own row too (it is that interval's last frame)
                    complete()
                    if cam_stream.draining:
                        continue
                    if record_keys or until is not None:
                        key = camera_key(cam_front, cam_stream)
                        if record_keys:
                            out.keys.add(frame.index, key)
                        if until is not None and until(frame.index, key):
                            # rows already made may wait for the interval to close: drain
                            out.stopped_at = frame.index
                            cam_stream.draining = True
                    if not cam_stream.owned:
                        continue
                elif raw.topic == choice.lidar and lid_stream and lid_front:
                    if lid_stream.full and (cam_stream is None or cam_stream.full):
                        break
                    if not lid_stream.admit(raw.log_ns):
                        continue
                    if opts.max_frames and lid_stream.stats.analysed + len(pending) >= opts.max_frames:
                        continue
                    scan = decode_lidar(rec, raw, lid_stream)
                    if scan is None:
                        check_all_failed(lid_stream)
                        continue
                    if lid_stream.repeats_scan(scan):
                        continue
                    if tf_odom is not None and choice.tf and not tf_odom.resolved \
                            and scan.frame_id and tf_odom.resolve(scan.frame_id):
                        tf_poses()
                    if tf_odom is not None and choice.odometry and mount.pending():
                        mount.place(tf_odom, scan.frame_id, lid_front)
                    if choice.odometry or (tf_odom is not None and choice.tf):
                        pending.append(scan)
                        release(raw.log_ns)
                    else:
                        rows.append(lid_stream.analyse(scan, lid_front, "lidar", rec_start))
                        settle()
                else:
                    continue
                done += 1
                if progress:
                    progress(done, expected or None)
        except KeyboardInterrupt:
            out.interrupted = True
        except FrontdiagError as exc:
            out.fault = exc
        if stop_asked():  # asked during the last frame or the drain: still an interruption
            out.interrupted = True
        if not out.interrupted:
            release(None)  # the scans still waiting for odometry that will not come
        if lid_stream is not None and tf_odom is not None and choice.tf:
            lid_stream.stats.prior_note = tf_prior_note(choice, tf_odom)
        elif lid_stream is not None and choice.odometry:
            lid_stream.stats.prior_note = mount.note(choice, odom_seen)
        if cam_stream is not None and conv is not None:
            cam_stream.stats.conversion = conv.mono16
        if cam_front is not None and cam_stream is not None:
            if want_end_state and out.end_state is None:
                out.end_state = camera_state(cam_front, cam_stream)
            cam_front.finish()  # the end of the frames read closes the open interval
            complete()
    return out


@dataclass
class _Mount:
    """Where the LiDAR sits in the frame an odometry topic's poses are of (its messages'
    ``child_frame_id``), from /tf_static: placed once, at the first scan after both frames are
    known, before any scan is registered with the prior."""

    child: str = ""
    lidar: str = ""
    T: np.ndarray | None = None
    tried: bool = False

    def pending(self) -> bool:
        return not self.tried

    def place(self, tree: TfOdometry, lidar_frame: str, front: Any) -> None:
        if not (self.child and lidar_frame):
            return  # asked again at the next scan
        self.tried, self.lidar = True, lidar_frame
        self.T = tree.static_chain(lidar_frame, self.child)
        if self.T is not None:
            front.set_mount(self.T)

    def note(self, choice: TopicChoice, seen: bool = False) -> str | None:
        """What the notes say about the mount; ``seen``: the odometry topic had messages."""
        if seen and not self.child:
            return (f"{choice.odometry} names no child frame (a pose topic, or an empty "
                    "child_frame_id): its motion is used as the LiDAR's, as if the LiDAR sat "
                    "where its poses are")
        if not self.tried:
            return None
        if self.T is None:
            return (f"{choice.tf_static} does not join the LiDAR's frame {self.lidar} to "
                    f"{self.child}, the frame {choice.odometry} gives poses of: its motion is "
                    "used as the LiDAR's")
        if np.allclose(self.T, np.eye(4)):
            return None
        return (f"{choice.odometry} gives poses of {self.child}; {choice.tf_static} places the "
                f"LiDAR ({self.lidar}) in it, so the prior is the LiDAR's own motion")


def tf_prior_note(choice: TopicChoice, tf_odom: TfOdometry) -> str:
    """Where the LiDAR's motion prior came from, when it was looked for on /tf."""
    if tf_odom.resolved:
        static = f" and {choice.tf_static}" if choice.tf_static and len(tf_odom.chain) > 1 \
            else ""
        return (f"no odometry topic; motion prior from {choice.tf}{static}: "
                f"{tf_odom.describe()}")
    seen = ", ".join(f"{tf_odom.parent[c]} → {c}" for c in sorted(tf_odom.dynamic)) or "none"
    return (f"no odometry topic, and {choice.tf} chains no odometry frame to the LiDAR's "
            f"frame (odometry transforms seen: {seen}); constant-velocity prior")


ODOM_WAIT_NS = 1_000_000_000
"""How long (log time) a scan waits for odometry covering it before it is registered with the
constant-velocity prior instead."""
ODOM_WAIT_SCANS = 20
"""At most this many scans wait (memory stays bounded when odometry stops)."""


def check_all_failed(stream: SensorStream) -> None:
    """Stop early when a topic cannot be decoded at all (e.g. an unknown encoding)."""
    st = stream.stats
    if st.analysed == 0 and st.skipped_undecodable >= 10:
        raise DecodeError(stream.topic, "message",
                          f"the first {st.skipped_undecodable} messages could not be decoded "
                          f"({st.first_error}{and_last(st)})")


def and_last(st: TopicStats) -> str:
    """``; last: ...`` where a later message was skipped for another reason (a video that
    holds its first pictures back says why only at the later ones)."""
    return f"; last: {st.last_error}" if st.last_error not in (None, st.first_error) else ""


def make_row(metrics: dict[str, Any], rec: CameraFrame | LidarScan, sensor: str,
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
