"""One recording on several processes: time windows of camera frames analysed in parallel.

The camera frames are split into ``jobs`` consecutive windows. Each window's frontend starts a
short warm-up before the window (``OVERLAP_KEYFRAMES`` keyframe intervals) and drops those rows.
The frontend keeps nothing older than its reference keyframe and the keyframe before it
(:meth:`~frontdiag.camera.frontend.CameraFrontend.state_key`), so once the warm-up and the run
of the previous window pick the same two keyframes, every later row is the row a single pass
gives. That is checked, not assumed: both runs record the state key after each frame of the
overlap, and a window whose warm-up did not meet the previous window's state (a camera standing
still keeps its keyframes 20 frames apart at any phase) is re-run from the previous window's
hand-over state until it meets its own first run, whose rows are kept from there. The table of a
parallel run is therefore the table of a serial run, timing columns aside.

LiDAR is not windowed: its local map has no bounded history to warm up; when the recording has a
LiDAR topic, one more process runs the LiDAR frontend over the whole selection.

A video topic's pictures depend on the ones before them back to a keyframe, so each window's
decoder is fed every message from the start of the recording, analysing none before its
warm-up (:func:`frontdiag.runner.feed_video`): decoding costs 1-3 ms a picture against 20 ms
for the analysis, so the later windows decode what the earlier ones analyse and the split still
pays.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import shutil
import tempfile
from collections.abc import Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from frontdiag.io.readers import Recording, damage_hint, open_recording, without_path
from frontdiag.io.topics import TopicChoice
from frontdiag.records import Intrinsics
from frontdiag.rowstore import RowStore
from frontdiag.runner import (
    FrameSink,
    FrameWindow,
    ProgressFn,
    SensorStream,
    StateKeys,
    StreamRun,
    TopicStats,
    run_stream,
)

if TYPE_CHECKING:
    from frontdiag.report.mcap_ import DiagnosticsWriter

log = logging.getLogger(__name__)

OVERLAP_KEYFRAMES = 3  # warm-up length in keyframe intervals (kf_max_frames frames each)
MIN_WINDOW_FRAMES = 50  # below this per window, one process is faster than the warm-ups
PROGRESS_POLL_S = 0.2  # how often a split run's progress bar reads the windows' counters


def plan_windows(n_frames: int, jobs: int, overlap: int) -> list[FrameWindow]:
    """``jobs`` consecutive windows over ``n_frames`` camera messages, each warmed up on up to
    ``overlap`` messages before it (fewer windows when the recording is short).

    The cuts give every window the same work, warm-up included: the first window has none, so it
    owns ``overlap`` frames more than the others. With equal cuts the slowest window would be
    the one with a warm-up, ``n/k + overlap`` frames, and the first worker would idle for the
    difference."""
    k = max(1, min(jobs, n_frames // max(MIN_WINDOW_FRAMES, overlap)))
    work = (n_frames + (k - 1) * overlap) / k  # frames each window runs, warm-up included
    bounds = [0] + [round(i * work - (i - 1) * overlap) for i in range(1, k)] + [n_frames]
    return [FrameWindow(warm_from=max(0, bounds[i] - overlap), own_from=bounds[i],
                        own_to=None if i == k - 1 else bounds[i + 1]) for i in range(k)]


WINDOW_PRELOAD = ("frontdiag.runner", "frontdiag.camera.frontend", "frontdiag.report.mcap_")
"""What a window worker runs: imported once in the worker server."""
FLEET_PRELOAD = (*WINDOW_PRELOAD, "frontdiag.api", "frontdiag.fleet", "frontdiag.output",
                 "frontdiag.report", "frontdiag.verdicts", "pyarrow.parquet")
"""A fleet worker also builds the table, evaluates the rules and writes the result folder
(pandas, Arrow: about 0.45 s more, which each worker paid on its first recording)."""


def _context(preload: Sequence[str] = WINDOW_PRELOAD) -> Any:
    # forkserver: workers fork from a clean server process, not from a parent that may hold
    # threads (progress bars, OpenCV's pool); the modules they run are imported there once.
    # The server is one per process: the preload of the first call that starts it holds.
    ctx = mp.get_context("forkserver")
    ctx.set_forkserver_preload(list(preload))
    return ctx


def prestart(preload: Sequence[str] = WINDOW_PRELOAD) -> None:
    """Start the worker server now, so that its imports (OpenCV, NumPy, the frontend: about
    0.6 s) run while the caller loads the rules and scans the recording, instead of delaying
    the first window. The pool created later forks its workers from it."""
    from multiprocessing import forkserver

    try:
        _context(preload)  # the preload list must be set before the server starts
        forkserver.ensure_running()
    except (OSError, ValueError) as exc:  # the pool will try again and report it
        log.debug("worker server not started early: %s", exc)


_PROGRESS: Any = None
"""In a window worker: the shared counters its tasks report frames analysed into (one slot a
task, :func:`_run_windows`), or None."""


def shared_counters(ctx: Any, tasks: int) -> Any:
    """Counters a pool's tasks report their progress into, read by the main process: two slots
    a task, frames analysed and frames expected (0: unknown); see :func:`task_progress`."""
    return ctx.RawArray("q", 2 * tasks)


def task_progress(slot: int | None) -> ProgressFn | None:
    """In a pool worker given counters (:func:`worker_init`): the progress callback of task
    ``slot``, writing into its two slots; None elsewhere."""
    counters = _PROGRESS
    if slot is None or counters is None:
        return None
    at = 2 * slot

    def progress(done: int, expected: int | None) -> None:
        counters[at], counters[at + 1] = done, expected or 0

    return progress


def worker_init(progress: Any = None) -> None:
    """Pool workers ignore Ctrl-C while they wait for a task (an idle worker has nothing to
    keep and would only print a traceback); :func:`interruptible` re-arms it for a task.
    ``progress``: shared counters for the tasks' frame counts (a window run's progress bar)."""
    import signal

    global _PROGRESS
    _PROGRESS = progress
    signal.signal(signal.SIGINT, signal.SIG_IGN)


# glibc's mallopt parameters (malloc.h) and the values its own dynamic thresholds grow to on
# 64-bit Linux (DEFAULT_MMAP_THRESHOLD_MAX 32 MiB; the trim threshold follows at twice it)
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
FRAME_MMAP_THRESHOLD = 32 * 2**20
FRAME_TRIM_THRESHOLD = 64 * 2**20
_MALLOC_FIXED = ("MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_", "MALLOC_TOP_PAD_")


def frame_sized_malloc() -> bool:
    """Undo an environment that fixed glibc's malloc thresholds low; returns whether it did.

    Dask's nanny starts every worker with ``MALLOC_TRIM_THRESHOLD_=65536`` (its
    ``distributed.nanny.pre-spawn-environ``). Setting any threshold turns glibc's dynamic ones
    off, which leaves the mmap threshold at 128 KiB: every picture-sized array (a 1280x720 grey
    frame is 900 KiB, and each pyramid level, patch stack and temporary above 128 KiB too) is
    then mapped, zero-filled and unmapped at each use, and every free above 64 KiB is trimmed.
    A fleet task took 1.5-1.75x its time in such a worker (1.2-1.3 s against 1.9-2.1 s a
    recording of 90 frames, benchmarks/bench_real.py's fleet). Where one of those variables is
    set, the thresholds are raised to what glibc's dynamic ones grow to on 64-bit Linux
    (mmap 32 MiB, trim 64 MiB: freed memory up to that is kept for the next frame rather than
    returned), or kept where the environment set them higher still; elsewhere glibc's own
    behaviour is left alone."""
    import os
    import sys

    if not sys.platform.startswith("linux") or not any(v in os.environ for v in _MALLOC_FIXED):
        return False

    def env_bytes(name: str) -> int:
        try:
            return int(os.environ.get(name, "0"))
        except ValueError:
            return 0

    # a trim threshold set higher (by someone who chose it) is kept; the mmap threshold goes
    # to the ceiling of glibc's own dynamic one
    mmap_at = FRAME_MMAP_THRESHOLD
    trim_at = max(FRAME_TRIM_THRESHOLD, env_bytes("MALLOC_TRIM_THRESHOLD_"))
    import ctypes

    try:
        libc = ctypes.CDLL("libc.so.6")
        return bool(libc.mallopt(M_MMAP_THRESHOLD, mmap_at)
                    and libc.mallopt(M_TRIM_THRESHOLD, trim_at))
    except (OSError, AttributeError):  # not glibc (musl has no mallopt to speak of)
        return False


@contextmanager
def one_blas_thread() -> Iterator[None]:
    """BLAS on one thread for the block, the caller's setting restored after. The frontend's
    products are small (the 1 000 x 961 patch moments of the keypoints' orientation, 3 x 3 and
    9 x 9 decompositions): a second thread never speeds them up, spins on the other core, and
    slows the command by up to 1.8x when that core is busy (docs/performance.md).
    threadpoolctl limits the libraries loaded when the block starts, so the ones the pass
    would load on first use (FAISS's and SciPy's own OpenBLAS) are loaded first."""
    import scipy.linalg  # noqa: F401  (SciPy's OpenBLAS)
    from threadpoolctl import threadpool_limits

    from frontdiag.camera.matching import faiss_module

    faiss_module()  # FAISS's OpenBLAS
    with threadpool_limits(limits=1, user_api="blas"):
        yield


@contextmanager
def one_core() -> Iterator[None]:
    """A task that is itself the parallelism (a window, a recording of a fleet): OpenCV and
    BLAS on one thread each, so that N tasks use N cores and not N x threads. OpenCV's setting
    stays for the process (a worker runs only such tasks); BLAS's is restored after. A worker
    whose environment fixed glibc's malloc thresholds low (a Dask worker) gets thresholds fit
    for pictures (:func:`frame_sized_malloc`)."""
    import cv2

    frame_sized_malloc()
    cv2.setNumThreads(1)
    with one_blas_thread():
        yield


@contextmanager
def interruptible() -> Iterator[None]:
    """In a pool worker (see :func:`worker_init`): Ctrl-C and SIGTERM during the block raise
    KeyboardInterrupt, which the pass turns into "interrupted, frames so far kept". Elsewhere
    (the main process, a Dask worker's thread) nothing changes."""
    import signal
    import threading

    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGINT) is not signal.SIG_IGN):
        yield
        return

    from frontdiag.errors import interrupt_on_signal

    old_term = signal.signal(signal.SIGTERM, interrupt_on_signal)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, old_term)


DRAIN_GRACE_S = 5.0  # how long an interrupted worker gets to hand back its frames


def drain(pool: ProcessPoolExecutor, futures: list[Future[Any]],
          grace_s: float = DRAIN_GRACE_S) -> None:
    """After Ctrl-C (or SIGTERM) in this process: nothing queued starts, and the running tasks
    end their pass and return what they computed.

    A Ctrl-C in a terminal reaches every process of its group, so the workers stop by
    themselves within a frame. A signal to this process alone (``kill``, a supervisor's
    SIGTERM) does not reach them: they are sent SIGINT, which their pass handles the same way.
    A worker that still has not answered after the grace period is terminated (its task is
    lost); a second Ctrl-C ends the wait at once."""
    import os
    import signal
    from concurrent.futures import wait

    for f in futures:
        f.cancel()  # only those not yet running
    procs = list((getattr(pool, "_processes", None) or {}).values())
    try:
        _, pending = wait(futures, timeout=grace_s / 5)
        if pending:
            for proc in procs:
                if proc.is_alive() and proc.pid is not None:
                    os.kill(proc.pid, signal.SIGINT)
            wait(pending, timeout=grace_s)
    except KeyboardInterrupt:
        pass
    for proc in procs:
        if proc.is_alive():
            proc.terminate()


def window_overlap(params: Any, stride: int = 1) -> int:
    """Frames of warm-up before each window but the first: ``OVERLAP_KEYFRAMES`` keyframe
    intervals of ``params.kf_max_frames`` analysed frames (``stride`` recording frames each)."""
    return OVERLAP_KEYFRAMES * int(params.kf_max_frames) * max(stride, 1)


def _task(path: Path, choice: TopicChoice, opts: Any, intr: Intrinsics | None,
          frames: FrameWindow | None, resume: Any = None, until_keys: StateKeys | None = None,
          part: str | None = None, slot: int | None = None) -> StreamRun:
    """One window (or the whole LiDAR stream) in a worker process; ``part``: a file for the
    annotations of the frames it analyses (its part of diagnostics.mcap, ``StreamRun.part``);
    ``slot``: where in the worker's shared counters it reports the frames it has analysed."""
    until = None if until_keys is None else until_keys.matches
    progress = task_progress(slot)
    sink = None
    if part is not None:
        from frontdiag.report.mcap_ import DiagnosticsWriter

        sink = DiagnosticsWriter(part, part=True)
        sink.open()
    try:
        with interruptible(), one_core(), open_recording(path) as rec:
            run = run_stream(rec, choice, opts, intr, frames=frames, resume=resume, until=until,
                             record_keys=frames is not None,
                             want_end_state=frames is not None, sink=sink, progress=progress)
            reader_fault(path, rec, run)
    finally:
        if sink is not None:
            sink.close()  # what was analysed before a fault or Ctrl-C is in the file
    if sink is not None:
        run.part = sink.part()
        for stream in (run.cam, run.lid):  # the writer stays here: the run goes back pickled
            if stream is not None:
                stream.sink = None
    return run


def reader_fault(path: Path, rec: Recording, run: StreamRun) -> None:
    """Damage the reader met (and skipped past quietly) becomes the pass's fault."""
    from frontdiag.errors import RecordingError

    if rec.fault is not None and run.fault is None:
        run.fault = RecordingError(path, without_path(rec.fault.message, path),
                                   hint=damage_hint(rec.fault), resumed=rec.fault.resumed)


def run_windows(path: Path, rec: Recording, choice: TopicChoice, opts: Any,
                intr: Intrinsics | None, *, progress: ProgressFn | None = None,
                expected: int | None = None, sink: FrameSink | None = None) -> StreamRun:
    """The pass of :func:`frontdiag.runner.run_stream`, computed by ``opts.jobs`` processes
    (``StreamRun.windows`` says how many camera windows). ``sink`` sees the frames where the
    recording is analysed in this process, in one window; a diagnostics.mcap writer
    (``report.mcap_.DiagnosticsWriter``) also receives those of the windows analysed in other
    processes, as parts merged in window order (the same messages as one pass writes)."""
    from frontdiag.camera.frontend import CameraParams

    n_cam = next((t.count for t in rec.topics if t.topic == choice.camera), None)
    cparams = opts.camera_params or CameraParams()
    overlap = window_overlap(cparams, opts.stride)
    windows = plan_windows(n_cam, opts.jobs, overlap) if n_cam else []
    if len(windows) < 2 or opts.max_frames:
        # nothing to split (no camera, a short one, or a frame budget counted from the start)
        log.info("one window: analysing %s in one process", path)
        return run_stream(rec, choice, opts, intr, progress=progress, expected=expected,
                          sink=sink)
    cam_choice = replace(choice, lidar=None, lidar_type=None, odometry=None)
    lid_choice = replace(choice, camera=None, camera_type=None, camera_info=None)
    # diagnostics.mcap: each task writes the annotations of its frames to a part file beside
    # it, merged in below (other sinks are not called for frames analysed elsewhere)
    from frontdiag.report.mcap_ import DiagnosticsWriter

    diag = sink if isinstance(sink, DiagnosticsWriter) else None
    parts_dir = None
    if diag is not None:
        parts_dir = Path(tempfile.mkdtemp(prefix=f"{PARTS_PREFIX}{os.getpid()}-",
                                          dir=diag.path.parent))
    try:
        return _run_windows(path, choice, opts, intr, windows, cam_choice, lid_choice,
                            progress, expected, parts_dir, diag)
    finally:
        if parts_dir is not None:
            shutil.rmtree(parts_dir, ignore_errors=True)


PARTS_PREFIX = ".frontdiag-parts-"
"""The folder a split run writes its parts of diagnostics.mcap to, beside the result:
``.frontdiag-parts-<pid of the run>-<random>``, removed when the run ends."""


def remove_stale_parts(folder: Path) -> None:
    """Remove the part folders that runs killed outright (SIGKILL, a power cut: no ``finally``
    ran) left in ``folder``: those whose run's process is gone. A folder of a run still going
    (another process writing into the same result folder) is left alone."""
    if os.name != "posix":  # signal 0 probes a process only on POSIX
        return
    for d in folder.glob(f"{PARTS_PREFIX}*"):
        try:
            pid = int(d.name[len(PARTS_PREFIX):].split("-", 1)[0])
        except ValueError:
            continue
        if pid == os.getpid():
            continue
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            log.info("removing %s, left by a run that was killed", d)
            shutil.rmtree(d, ignore_errors=True)
        except OSError:  # alive, another user's
            continue


def _part(parts_dir: Path | None, name: str) -> str | None:
    return None if parts_dir is None else str(parts_dir / f"{name}.mcap")


def _run_windows(path: Path, choice: TopicChoice, opts: Any, intr: Intrinsics | None,
                 windows: list[FrameWindow], cam_choice: TopicChoice, lid_choice: TopicChoice,
                 progress: ProgressFn | None, expected: int | None, parts_dir: Path | None,
                 diag: DiagnosticsWriter | None) -> StreamRun:
    runs: list[StreamRun | None] = [None] * len(windows)
    lid_run: StreamRun | None = None
    interrupted = False
    ctx = _context()
    # each task reports the frames it has analysed into its slot (the LiDAR task the last), so
    # the progress bar moves while the windows run, not only as each one ends
    counters = shared_counters(ctx, len(windows) + 1)
    pool = ProcessPoolExecutor(max_workers=opts.jobs, mp_context=ctx,
                               initializer=worker_init, initargs=(counters,))
    futs: dict[Future[StreamRun], int] = {
        pool.submit(_task, path, cam_choice, opts, intr, w, part=_part(parts_dir, f"window{i}"),
                    slot=i): i for i, w in enumerate(windows)}
    lid_fut = pool.submit(_task, path, lid_choice, opts, intr, None,
                          part=_part(parts_dir, "lidar"),
                          slot=len(windows)) if choice.lidar else None
    all_futs: list[Future[StreamRun]] = [*futs, *([lid_fut] if lid_fut else [])]
    # a window's first frames are its warm-up: not rows, not counted
    warm = [-(-(w.own_from - w.warm_from) // max(opts.stride, 1)) for w in windows] + [0]
    rows_of: dict[int, int] = {}  # slot -> rows of a finished task
    shown = 0
    try:
        pending = set(all_futs)
        while pending:
            finished, pending = wait(pending, timeout=PROGRESS_POLL_S, return_when=FIRST_COMPLETED)
            for fut in finished:
                run = fut.result()
                if fut is lid_fut:
                    lid_run = run
                    rows_of[len(windows)] = len(run.rows)
                else:
                    runs[futs[fut]] = run
                    rows_of[futs[fut]] = len(run.rows)
            if progress:
                live = sum(rows_of[i] if i in rows_of else max(0, counters[2 * i] - warm[i])
                           for i in range(len(warm)))
                if expected:
                    live = min(live, expected)
                shown = max(shown, live)  # never backwards
                progress(shown, expected or None)
    except KeyboardInterrupt:
        # Each window's worker keeps the frames it analysed before the interruption (as one
        # pass would): collect them, so the windows up to the interrupted one are kept.
        interrupted = True
        drain(pool, all_futs)
        for fut in all_futs:
            if fut.done() and not fut.cancelled() and fut.exception() is None:
                if fut is lid_fut:
                    lid_run = fut.result()
                elif runs[futs[fut]] is None:
                    runs[futs[fut]] = fut.result()
    finally:
        pool.shutdown(wait=not interrupted, cancel_futures=interrupted)
    cam_rows, cam_stream, fault, cut, parts = _stitch(path, cam_choice, opts, intr, windows,
                                                      runs, parts_dir)
    if diag is not None:
        for part, frames in parts:
            diag.merge_part(part, frames)
        if lid_run is not None and lid_run.part is not None:
            diag.merge_part(lid_run.part)
    rows = cam_rows
    lid_stream = None
    if lid_run is not None:
        rows.extend(lid_run.rows)
        lid_stream = lid_run.lid
        fault = fault or lid_run.fault
        interrupted = interrupted or lid_run.interrupted
    return StreamRun(rows, cam_stream, lid_stream, fault=fault,
                     interrupted=interrupted or cut, windows=len(windows))


Parts = list[tuple[Any, "tuple[int, int | None] | None"]]
"""Part files of diagnostics.mcap to merge, in order, each with the frames to take from it
(None: all)."""


def _stitch(path: Path, choice: TopicChoice, opts: Any, intr: Intrinsics | None,
            windows: list[FrameWindow], runs: list[StreamRun | None],
            parts_dir: Path | None = None
            ) -> tuple[RowStore, SensorStream | None, Any, bool, Parts]:
    """Camera rows and counts of consecutive windows, in order, as one pass would give them,
    and the windows' parts of diagnostics.mcap that hold the same frames.

    Stops at the first window that is missing (interrupted), was interrupted, or was cut short
    by damage: what follows it would not be in a single pass's result either. Damage a window's
    reader reports although the window read all its frames (a garbage tail after a bag's index
    is seen when the file is opened) lies beyond that window: the next windows go on, and the
    damage is the pass's fault at the end, as in one pass.
    """
    rows = RowStore()
    parts: Parts = []
    merged: SensorStream | None = None
    prev: StreamRun | None = None
    later_fault: Any = None
    for i, (w, run) in enumerate(zip(windows, runs, strict=True)):
        if run is None:
            return rows, merged, None, True, parts
        if prev is not None and not _met(prev, run, w):
            run, window_parts = _rerun(path, choice, opts, intr, w, prev, run,
                                       _part(parts_dir, f"window{i}-continued"))
            parts += window_parts
        elif run.part is not None:
            parts.append((run.part, None))
        rows.extend(run.rows)
        merged = _merge_counts(merged, run.cam)
        if run.interrupted or (run.fault is not None and not _read_whole(run, w)):
            return rows, merged, run.fault, run.interrupted, parts
        later_fault = later_fault or run.fault
        prev = run
        log.debug("window %d: frames %d-%s, %d rows", i, w.own_from, w.own_to, len(run.rows))
    return rows, merged, later_fault, False, parts


def _read_whole(run: StreamRun, w: FrameWindow) -> bool:
    """Whether the window's run read every message it owns (the last window owns the rest of
    the recording, so damage anywhere after its start cuts it short)."""
    return w.own_to is not None and run.cam is not None and run.cam.index >= w.own_to - 1


def _met(prev: StreamRun, run: StreamRun, w: FrameWindow) -> bool:
    """Whether the warm-up of ``run`` reached the state ``prev`` had at some frame before the
    window, after which both give the same rows."""
    return any(prev.keys.get(f) == d for f, d in run.keys.items() if f < w.own_from)


def _rerun(path: Path, choice: TopicChoice, opts: Any, intr: Intrinsics | None,
           w: FrameWindow, prev: StreamRun, first: StreamRun, part: str | None = None
           ) -> tuple[StreamRun, Parts]:
    """Window ``w`` continued from the previous window's end state, until it meets its own
    first run; that run's rows and end state are right from there on. Also the parts of
    diagnostics.mcap holding those frames: the continued run's up to the meeting frame, the
    first run's after it."""
    log.info("window at frame %d: warm-up did not meet the previous window; continuing it "
             "from the previous window's state", w.own_from)
    fix = _task(path, choice, opts, intr, FrameWindow(w.own_from, w.own_from, w.own_to),
                resume=prev.end_state, until_keys=first.keys, part=part)
    if fix.stopped_at is None:  # never met: the continued run is the window
        fix.cam = first.cam  # counts do not depend on the frontend's state
        return fix, ([(fix.part, None)] if fix.part is not None else [])
    rows = fix.rows
    rows.extend(first.rows.after_frame(fix.stopped_at))
    parts: Parts = []
    if fix.part is not None and first.part is not None:
        parts = [(fix.part, (0, fix.stopped_at)), (first.part, (fix.stopped_at + 1, None))]
    keys = StateKeys()
    keys.update(first.keys)
    keys.update(fix.keys)
    return replace(first, rows=rows, keys=keys), parts


def _merge_counts(acc: SensorStream | None, cur: SensorStream | None) -> SensorStream | None:
    """Counts of consecutive windows added up (each window counted only what it owns)."""
    if cur is None or acc is None:
        return cur if acc is None else acc
    a, b = acc.stats, cur.stats
    acc.stats = TopicStats(
        messages=a.messages + b.messages, analysed=a.analysed + b.analysed,
        skipped_undecodable=a.skipped_undecodable + b.skipped_undecodable,
        first_error=a.first_error if a.first_error is not None else b.first_error,
        last_error=b.last_error if b.last_error is not None else a.last_error,
        non_monotonic_stamps=a.non_monotonic_stamps + b.non_monotonic_stamps,
        zero_stamps=a.zero_stamps + b.zero_stamps,
        last_t_ns=b.last_t_ns if b.last_t_ns is not None else a.last_t_ns,
        gaps=a.gaps + b.gaps, size_changes=a.size_changes + b.size_changes,
        repeated_messages=a.repeated_messages + b.repeated_messages,
        identical_pictures=a.identical_pictures + b.identical_pictures,
        first_repeat=a.first_repeat if a.first_repeat is not None else b.first_repeat,
        first_identical=a.first_identical if a.first_identical is not None
        else b.first_identical,
        conversion=a.conversion if a.conversion is not None else b.conversion,
        prior_note=a.prior_note or b.prior_note)
    acc.index = cur.index
    return acc
