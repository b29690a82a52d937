"""The library API: ``analyze(path, ...) -> DataFrame``, plus the richer :func:`run_analysis`.

One streaming pass: messages are read in log-time order, decoded one at a time and handed to the
camera and LiDAR frontends; only the per-frame rows are kept, never the pixels or points, so
memory does not grow with the length of the recording.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from frontdiag import __version__
from frontdiag.errors import (
    ConfigError,
    DecodeError,
    FrontdiagError,
    RecordingError,
    TopicError,
)
from frontdiag.io.camera_info import (
    HOW_TO_PASS_K,
    fit_to_images,
    from_camera_info,
    is_rectified_topic,
    load_camera_info_yaml,
    parse_intrinsics,
)
from frontdiag.io.decode import header_stamp_ns, odometry_pose
from frontdiag.io.images import is_video_message
from frontdiag.io.readers import (
    Recording,
    damage_hint,
    open_recording,
    recording_size,
    without_path,
)
from frontdiag.io.topics import TopicChoice, choose_topics
from frontdiag.metrics import CAMERA_COLUMNS, LIDAR_COLUMNS
from frontdiag.records import GAP_STATUS, SIZE_STATUS, Intrinsics
from frontdiag.rowstore import RowStore
from frontdiag.runner import (
    FrameSink,
    ProgressFn,
    SensorStream,
    StreamRun,
    TopicStats,
    and_last,
    iter_camera_frames,
    own_calibrations,
    run_stream,
)
from frontdiag.versions import versions

log = logging.getLogger(__name__)

__all__ = ["GAP_STATUS", "Analysis", "AnalysisOptions", "ProgressFn", "TopicStats", "analyze",
           "header_stamp_ns", "iter_camera_frames", "odometry_pose", "run_analysis"]


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
    rules_extra: list[str] | None = None  # rules directories added to rules_dir's (--rules DIR)
    select: list[str] | None = None
    ignore: list[str] | None = None
    jobs: int = 1  # processes for one recording (time windows, frontdiag.parallel)
    downscale: int = 1  # camera pictures shrunk by this factor before the frontend sees them


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
    windows: int = 1  # camera windows analysed in parallel (--jobs); 1: in this process


# --------------------------------------------------------------------------------------------
# decoding helpers
# --------------------------------------------------------------------------------------------

def resolve_intrinsics(rec: Recording, choice: TopicChoice, opts: AnalysisOptions,
                       notes: list[str]) -> Intrinsics | None:
    """Explicit options win over the recording's CameraInfo, which is then not read at all (so a
    broken CameraInfo cannot stop a run the user calibrated)."""
    if opts.intrinsics is not None:
        explicit: Intrinsics | None = parse_intrinsics(opts.intrinsics)
    elif opts.camera_info_file is not None:
        explicit = load_camera_info_yaml(opts.camera_info_file, notes)
    else:
        explicit = None
    if explicit is not None:
        if choice.camera_info:
            notes.append(f"using {explicit.source} instead of the CameraInfo on "
                         f"{choice.camera_info}")
        return explicit
    if not choice.camera_info:
        return None
    topic = choice.camera_info
    unusable: list[str] = []  # why each message before the one used was passed over
    refused: ConfigError | None = None
    for i, raw in enumerate(rec.messages([topic])):
        if i >= CAMERA_INFO_SEARCH:
            break
        try:
            msg = rec.deserialize(raw)
        except Exception as exc:
            unusable.append(f"undecodable ({exc})")
            continue
        own: list[str] = []  # its notes, kept only if it is the one used
        try:
            from_rec = from_camera_info(msg, topic, own,
                                        rectified=is_rectified_topic(choice.camera or ""))
        except ConfigError as exc:
            refused = refused or exc
            unusable.append(str(exc).removeprefix(f"CameraInfo on {topic}: "))
            continue
        if from_rec is None:
            unusable.append("no K (all zeros)")
            continue
        if unusable:
            before = (f"the one before it was not usable: {unusable[0]}" if len(unusable) == 1
                      else f"the {len(unusable)} before it were not usable (the first: "
                           f"{unusable[0]})")
            notes.append(f"CameraInfo on {topic}: message {i + 1} used; {before}")
        notes.extend(own)
        return from_rec
    if refused is not None:
        raise refused  # no usable calibration and one the user must mend or override
    if unusable:
        shown = unusable[0] if len(unusable) == 1 else \
            f"none of its first {len(unusable)} messages is usable (the first: {unusable[0]})"
        notes.append(f"CameraInfo on {topic}: {shown}; no intrinsics")
    return None


def calibration_for_images(rec: Recording, choice: TopicChoice, opts: AnalysisOptions,
                           notes: list[str]) -> Intrinsics | None:
    """The calibration for the camera's first images: :func:`resolve_intrinsics`, and where the
    recording's first usable CameraInfo is for another image size (a driver that publishes its
    full-resolution calibration before binning takes effect), the first one made for the
    images' size instead; otherwise the one found, fitted to the images (``fit_to_images``)."""
    intr = resolve_intrinsics(rec, choice, opts, notes)
    if intr is None or intr.width <= 0 or intr.height <= 0:
        return intr
    size = first_image_size(rec, choice, opts.downscale)
    # within the messages resolve_intrinsics reads: a resize node that passes the full-size
    # CameraInfo on has none for the images, and its whole topic is not read
    cal = own_calibrations(rec, choice, opts, intr, limit=CAMERA_INFO_SEARCH) \
        if size is not None and (intr.width, intr.height) != size else None
    own = cal.calibration(*size) if cal is not None and size is not None else None
    if own is not None and size is not None:
        notes.append(f"CameraInfo on {choice.camera_info}: message {own[1]} used, the "
                     f"first made for the images' {size[0]}x{size[1]} (the first usable "
                     f"one is for {intr.width}x{intr.height})")
        return own[0]
    return fit_to_images(intr, size, notes)


MAX_DOWNSCALE = 8
"""--downscale's largest factor: 4K shrunk by 8 is 480x270, about the smallest a frontend runs."""

CAMERA_INFO_SEARCH = 100
"""CameraInfo messages read for a usable calibration. A driver may publish an unset one (K all
zeros) until its calibration file is loaded, or a message may be damaged: the first usable one
within these is used, with a note."""


VIDEO_KEYFRAME_SEARCH = 600
"""Messages of a video topic read for its first picture (a keyframe every 20 s at 30 Hz)."""


def first_image_size(rec: Recording, choice: TopicChoice, downscale: int = 1
                     ) -> tuple[int, int] | None:
    """(width, height) of the camera topic's first image as the frontend sees it (shrunk by
    ``downscale``; of a video topic, its first picture, within VIDEO_KEYFRAME_SEARCH messages),
    or None when it cannot be read (the run then reports that frame itself). A raw image whose
    header gives no size (a zero width or height: a damaged or unset message) says nothing
    of the camera's; the next ones, within the same search, are read instead."""
    from frontdiag.io.images import GrayConverter, shrunk_size

    assert choice.camera is not None
    conv = GrayConverter(choice.camera, downscale=downscale)
    video = False
    for i, raw in enumerate(rec.messages([choice.camera])):
        try:
            msg = rec.deserialize(raw)
            video = is_video_message(msg, raw.msgtype)
            if not video and hasattr(msg, "width") and hasattr(msg, "height"):
                if int(msg.width) > 0 and int(msg.height) > 0:
                    return shrunk_size(int(msg.width), int(msg.height), downscale)
                if i + 1 >= VIDEO_KEYFRAME_SEARCH:
                    return None
                continue
            gray, _ = conv(msg, raw.msgtype)
            return int(gray.shape[1]), int(gray.shape[0])
        except Exception:
            if not video or i + 1 >= VIDEO_KEYFRAME_SEARCH:
                return None
    return None


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


def check_selection(opts: AnalysisOptions) -> None:
    """Refuse options no recording can satisfy, before the recording is opened."""
    import math

    for name, value in (("--start", opts.start_s), ("--end", opts.end_s)):
        if value is not None and not math.isfinite(value):
            raise ConfigError(f"{name} {value}: must be a finite number of seconds")
    if opts.start_s is not None and opts.start_s < 0:
        raise ConfigError(f"--start {opts.start_s:g}: must be >= 0 seconds")
    if opts.end_s is not None and opts.start_s is not None and opts.end_s <= opts.start_s:
        raise ConfigError(f"--end {opts.end_s:g} must be after --start {opts.start_s:g}")
    if opts.end_s is not None and opts.end_s < 0:
        raise ConfigError(f"--end {opts.end_s:g}: must be >= 0 seconds")
    if opts.stride < 1:
        raise ConfigError(f"--stride {opts.stride}: must be >= 1")
    if opts.max_frames is not None and opts.max_frames < 1:
        raise ConfigError(f"--max-frames {opts.max_frames}: must be >= 1")
    if not 1 <= opts.downscale <= MAX_DOWNSCALE:
        raise ConfigError(f"--downscale {opts.downscale}: must be a whole factor from 1 to "
                          f"{MAX_DOWNSCALE}")
    if opts.intrinsics is not None:
        parse_intrinsics(opts.intrinsics)


# --------------------------------------------------------------------------------------------
# the pass
# --------------------------------------------------------------------------------------------

def run_analysis(path: Path | str, options: AnalysisOptions | None = None,
                 progress: ProgressFn | None = None, sink: FrameSink | None = None) -> Analysis:
    """Re-run the frontend on a recording and return the per-frame table with its manifest.

    Damage met part-way (a truncated file, an undecodable topic) does not lose the frames
    before it: they are returned with ``Analysis.fault`` set. Ctrl-C does the same with
    ``Analysis.interrupted``. ``sink`` sees every analysed frame as it goes where they are
    analysed in this process: with ``jobs > 1`` and a recording split into windows
    (``Analysis.windows`` > 1) they are analysed elsewhere and it is not called, except for
    diagnostics.mcap's writer (``report.mcap_.DiagnosticsWriter``), which receives the windows'
    annotations as parts (``parallel.run_windows``).
    """
    opts = options or AnalysisOptions()
    check_selection(opts)
    if opts.jobs < 1:
        raise ConfigError(f"--jobs {opts.jobs}: must be >= 1")
    if opts.jobs > 1:
        from frontdiag.parallel import prestart

        prestart()
    path = Path(path)
    t_start = time.perf_counter()
    ruleset = None
    if opts.rules:  # load (and validate) the rules before spending time on the recording
        from frontdiag.verdicts import load_ruleset

        ruleset = load_ruleset(
            Path(opts.rules_dir) if opts.rules_dir else None,
            Path(opts.rules_overrides) if opts.rules_overrides else None,
            select=opts.select, ignore=opts.ignore,
            extra_dirs=[Path(d) for d in opts.rules_extra or ()])
        opts = _read_intervals_for(ruleset, opts)
    notes: list[str] = []
    with open_recording(path) as rec:
        topic_infos = rec.topics
        try:
            choice = choose_topics(topic_infos, camera_topic=opts.camera_topic,
                                   lidar_topic=opts.lidar_topic, odom_topic=opts.odom_topic,
                                   use_camera=opts.use_camera, use_lidar=opts.use_lidar)
        except TopicError:
            if rec.fault is not None:  # the damage hid the topics: say so, not "no topics"
                raise RecordingError(path, without_path(rec.fault.message, path)) from None
            raise
        notes.extend(choice.notes)
        if choice.camera and opts.downscale > 1:
            notes.append(f"{choice.camera}: pictures shrunk by {opts.downscale} (--downscale; "
                         "each pixel the mean of its block) before the frontend sees them; "
                         "keypoints, pixel readings and K are those of the shrunk pictures")
        intr = calibration_for_images(rec, choice, opts, notes) if choice.camera else None
        if choice.camera and intr is None:
            notes.append(f"no intrinsics: E, parallax, rotation and pose information are not "
                         f"computed; {HOW_TO_PASS_K}")
        if intr is not None:
            notes.extend(short_focal_note(intr, opts))
        counts = {t.topic: t.count for t in topic_infos}
        expected = sum(_expected(counts.get(t), opts, rec) or 0
                       for t in (choice.camera, choice.lidar) if t)
        from frontdiag.parallel import one_blas_thread, run_windows

        with one_blas_thread():  # small products: a second thread only spins
            if opts.jobs > 1:
                run = run_windows(path, rec, choice, opts, intr, progress=progress,
                                  expected=expected, sink=sink)
            else:
                run = run_stream(rec, choice, opts, intr, progress=progress,
                                 expected=expected, sink=sink)
        fault = _stream_notes(path, rec, run, notes)
        table = _table(run.rows)
        coverage = _coverage(run, table)
        if fault is None and not run.interrupted:
            fault = _nothing_analysed(coverage, counts, opts)
        manifest = _manifest(path, rec, choice, intr, opts, run.cam, run.lid, notes,
                             fault, run.interrupted, time.perf_counter() - t_start)
        manifest["coverage"] = coverage
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
                    fault=fault, interrupted=run.interrupted, verdicts=verdicts,
                    ruleset=ruleset, windows=run.windows)


def _read_intervals_for(ruleset: Any, opts: AnalysisOptions) -> AnalysisOptions:
    """The camera frontend's readings for the H/E quadrant rules, set from those rules.

    It takes its two-interval reading on intervals shorter than ``two_interval_px``; rules that
    read intervals up to a larger ``min_parallax_px`` raise it. It takes the rotation-only fit
    where H/E is above ``rot_fit_he`` with parallax at least ``rot_fit_parallax_deg``; rules
    with a ``rot_fit_px`` and a lower ``he_degenerate`` or ``parallax_split_deg`` lower them; it
    also takes it on intervals that turned ``rot_fit_turn_px``, lowered to the rules' own.
    """

    from frontdiag.camera.frontend import CameraParams

    cp = opts.camera_params or CameraParams()
    quadrant = [r for r in ruleset.frame_rules if r.check == "he_parallax_quadrant"]
    need = max((float(r.param("min_parallax_px")) for r in quadrant
                if "min_parallax_px" in r.params), default=0.0)
    rot = [r for r in quadrant if "rot_fit_px" in r.params]
    he = min((float(r.param("he_degenerate")) for r in rot), default=cp.rot_fit_he)
    par = min((float(r.param("parallax_split_deg")) for r in rot),
              default=cp.rot_fit_parallax_deg)
    turn = min((float(r.param("rot_fit_turn_px")) for r in rot if "rot_fit_turn_px" in r.params),
               default=cp.rot_fit_turn_px)
    new = replace(cp, two_interval_px=max(need, cp.two_interval_px),
                  rot_fit_he=min(he, cp.rot_fit_he),
                  rot_fit_parallax_deg=min(par, cp.rot_fit_parallax_deg),
                  rot_fit_turn_px=min(turn, cp.rot_fit_turn_px))
    return opts if new == cp else replace(opts, camera_params=new)


SHORT_FOCAL_SPAN_RATIO = 1.5
"""The span FD-ROT-001 reads the motion over is said in the notes from this multiple of
``rot_span_s`` on (f under 330 px at the defaults): at 640x480 and 752x480 (f 457-458 px) it
grows by under a tenth, and on the validation set shrunk 2x slow hand-held motion at 307 px
still read as standing still."""


def short_focal_note(intr: Intrinsics, opts: AnalysisOptions) -> list[str]:
    """The note that FD-ROT-001 reads the motion over a span much longer than 0.33 s, where
    the focal length in pixels is well under the frontend's ``rot_span_focal_px``
    (docs/rules.md, "The span at low resolution")."""
    from frontdiag.camera.frontend import CameraParams, span_seconds

    cp = opts.camera_params or CameraParams()
    f = float(intr.K[0, 0])
    span = span_seconds(cp, f)
    if cp.rot_span_s <= 0 or span < SHORT_FOCAL_SPAN_RATIO * cp.rot_span_s:
        return []
    return [f"focal length {f:.0f} px, under {cp.rot_span_focal_px:g} px: FD-ROT-001 reads the "
            f"motion over {span:.2f} s rather than {cp.rot_span_s:g} s before calling it a turn "
            "or standing still, since parallax in pixels shrinks with the focal length while "
            "localisation noise does not; slow motion can still read as standing still at "
            "short focal lengths (docs/rules.md, \"The span at low resolution\")"]


def _stream_notes(path: Path, rec: Recording, run: StreamRun,
                  notes: list[str]) -> FrontdiagError | None:
    """The pass's fault (its own, the reader's, or a topic nothing could be decoded from) and
    the notes its counts call for."""
    fault = run.fault
    if rec.fault is not None and fault is None:
        fault = RecordingError(path, without_path(rec.fault.message, path),
                               hint=damage_hint(rec.fault),
                               resumed=rec.fault.resumed)
    for stream in (run.cam, run.lid):
        if stream is None:
            continue
        st = stream.stats
        if st.analysed == 0 and st.skipped_undecodable and fault is None:
            fault = DecodeError(stream.topic, "message",
                                f"no message could be decoded ({st.skipped_undecodable} "
                                f"skipped; first: {st.first_error}{and_last(st)})")
        if st.conversion:
            notes.append(f"{stream.topic}: {st.conversion['note']}")
        if st.prior_note:
            notes.append(f"{stream.topic}: {st.prior_note}")
        if st.non_monotonic_stamps:
            notes.append(f"{stream.topic}: {st.non_monotonic_stamps} non-monotonic header "
                         "stamps")
        if st.zero_stamps:
            notes.append(f"{stream.topic}: {st.zero_stamps} zero header stamps (log time "
                         "used)")
        if st.skipped_undecodable:
            notes.append(f"{stream.topic}: {st.skipped_undecodable} undecodable messages "
                         f"skipped (first: {st.first_error}{and_last(st)})")
        if st.gaps:
            notes.append(f"{stream.topic}: {st.gaps} gap(s) in the recording; the frontend "
                         f"started afresh after each (rows with status {GAP_STATUS})")
        if st.repeated_messages:
            what = "scan" if stream is run.lid else "picture"
            notes.append(f"{stream.topic}: {st.repeated_messages} message(s) repeated the "
                         f"{what} before them with the same stamp (first: frame "
                         f"{st.first_repeat}), as where a topic was recorded twice or relayed "
                         "back: not analysed")
        if st.identical_pictures:
            notes.append(f"{stream.topic}: {st.identical_pictures} picture(s) equal the one "
                         f"before them pixel for pixel, with a later stamp (first: frame "
                         f"{st.first_identical}): a camera that stalled while its driver went on "
                         "stamping, or a noise-free simulated camera standing still; analysed "
                         "as they come (a stall reads as standing still)")
        if st.size_changes:
            shown = "; ".join(st.size_changes[:3])
            more = f"; and {len(st.size_changes) - 3} more" if len(st.size_changes) > 3 else ""
            notes.append(f"{stream.topic}: the image size changed {len(st.size_changes)} "
                         f"time(s), and the frontend started afresh at each (rows with status "
                         f"{SIZE_STATUS}): {shown}{more}")
    return fault


NO_RESULT = ("too_few_points",)
"""Row statuses that carry no measurement: the frame was read but nothing could be evaluated."""


def _coverage(run: StreamRun, table: pd.DataFrame) -> dict[str, dict[str, Any]]:
    """Per sensor topic: frames present (in the --start/--end window), rows, and the frames
    that produced a measurement (rows whose status is not in NO_RESULT and not an error)."""
    out: dict[str, dict[str, Any]] = {}
    for sensor, stream in (("camera", run.cam), ("lidar", run.lid)):
        if stream is None:
            continue
        rows = table[table["topic"] == stream.topic] if not table.empty else table
        status = rows["status"].astype(str) if not rows.empty else pd.Series(dtype=str)
        empty = status.isin(NO_RESULT) | status.str.startswith("error")
        present = int(stream.stats.messages)
        evaluated = int((~empty).sum())
        # a message delivered twice is one frame (TopicStats.repeated_messages)
        repeats = int(stream.stats.repeated_messages)
        distinct = present - repeats
        out[stream.topic] = {
            "sensor": sensor, "frames_present": present, "rows": len(rows),
            "frames_analysed": evaluated, "repeats": repeats,
            "share": round(evaluated / distinct, 4) if distinct > 0 else 0.0,
            "no_result": {str(k): int(v) for k, v in status[empty].value_counts().items()},
        }
    return out


def _nothing_analysed(coverage: dict[str, dict[str, Any]], counts: dict[str, int | None],
                      opts: AnalysisOptions) -> FrontdiagError | None:
    """An analysis that measured nothing on a sensor it read is an error, never a pass."""
    for topic, c in coverage.items():
        if c["frames_analysed"]:
            continue
        if c["frames_present"] == 0:
            windowed = opts.start_s is not None or opts.end_s is not None
            why = ("no message between --start and --end" if windowed and counts.get(topic)
                   else "the topic has no messages")
        elif c["no_result"]:
            why = "every frame: " + ", ".join(f"{k} ({v})" for k, v in c["no_result"].items())
        else:
            why = "no frame could be decoded"
        return FrontdiagError(f"topic {topic}: nothing analysed ({why})",
                              hint="see `frontdiag info` for what the recording holds")
    return None


def _table(rows: RowStore) -> pd.DataFrame:
    """Rows in time order with the contract columns first (the store emptied)."""
    lead = list(dict.fromkeys(["frame", "t_ns", "t_rel_s", "sensor", "topic",
                               *CAMERA_COLUMNS, *LIDAR_COLUMNS]))
    if not len(rows):
        return pd.DataFrame(columns=lead)
    df = rows.frame()
    for col in lead:
        if col not in df.columns:
            df[col] = np.nan
    rest = [c for c in df.columns if c not in lead]
    df = df[lead + rest]
    return df.sort_values(["t_ns", "sensor"], kind="stable").reset_index(drop=True)


def _manifest(path: Path, rec: Recording, choice: TopicChoice, intr: Intrinsics | None,
              opts: AnalysisOptions, cam: SensorStream | None, lid: SensorStream | None,
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
    selection = {k: getattr(opts, k)
                 for k in ("start_s", "end_s", "max_frames", "stride", "downscale")}
    rules = None if not opts.rules else {
        "dir": opts.rules_dir, "extra_dirs": opts.rules_extra,
        "overrides": opts.rules_overrides, "select": opts.select, "ignore": opts.ignore}
    return {
        "frontdiag_version": __version__,
        "versions": versions(),
        "created_unix_s": int(time.time()),
        "input": {"path": str(path.resolve()), "backend": rec.backend,
                  "size_bytes": recording_size(path), "start_ns": rec.start_ns, "end_ns": rec.end_ns},
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
