"""`analyze --jobs N`: time windows in parallel give the serial table (timing columns aside)."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from recording_factory import write_recording

from frontdiag.api import AnalysisOptions, run_analysis
from frontdiag.camera.frontend import CameraParams
from frontdiag.parallel import plan_windows, window_overlap


def _same_table(a: pd.DataFrame, b: pd.DataFrame) -> None:
    cols = [c for c in a.columns if not c.startswith("ms_")]
    assert list(a.columns) == list(b.columns)
    pd.testing.assert_frame_equal(a[cols], b[cols])


def test_windows_cover_every_frame_once() -> None:
    ws = plan_windows(1000, 3, 60)
    # equal work per window, warm-up included: (1000 + 2 * 60) / 3 = 373.3 frames each, so the
    # first window (no warm-up) owns 373 frames and the others 313 + 60 warm-up
    assert [w.own_from for w in ws] == [0, 373, 687]
    assert [w.own_to for w in ws] == [373, 687, None]
    assert [w.warm_from for w in ws] == [0, 313, 627]
    runs = [(w.own_to or 1000) - w.warm_from for w in ws]
    assert max(runs) - min(runs) <= 1
    two = plan_windows(1200, 2, 60)
    assert [(w.warm_from, w.own_from, w.own_to) for w in two] == [(0, 0, 630), (570, 630, None)]
    assert len(plan_windows(100, 4, 60)) == 1  # too short to pay for a warm-up


def test_downscaled_windows_give_the_serial_table(tmp_path: Path) -> None:
    path = write_recording(tmp_path / "run.mcap", "mcap", n=150, shift=2)
    serial = run_analysis(path, AnalysisOptions(downscale=2))
    par = run_analysis(path, AnalysisOptions(downscale=2, jobs=2))
    assert par.windows == 2 and serial.table["width"].eq(80).all()
    _same_table(serial.table, par.table)
    assert serial.manifest["notes"] == par.manifest["notes"]


@pytest.mark.parametrize("shift", [1, 0], ids=["moving", "still"])
def test_parallel_table_equals_serial(tmp_path: Path, shift: int) -> None:
    # still: keyframes every kf_max_frames at whatever phase the run started, so a window's
    # warm-up never meets the serial keyframes and the window is continued from its neighbour
    path = write_recording(tmp_path / "run.mcap", "mcap", n=150, shift=shift)
    serial = run_analysis(path, AnalysisOptions())
    par = run_analysis(path, AnalysisOptions(jobs=2))
    assert len(serial.table) == 150
    _same_table(serial.table, par.table)
    assert serial.manifest["counts"] == par.manifest["counts"]
    assert serial.verdicts.episodes.equals(par.verdicts.episodes)


def test_a_serial_pass_runs_blas_on_one_thread(tmp_path: Path) -> None:
    """The frontend's products are small: in a serial pass BLAS runs on one thread (a second
    one spun on the other core for nothing, and slowed the command by up to 1.8x when that
    core was busy), and the caller's setting is back afterwards."""
    from threadpoolctl import threadpool_info, threadpool_limits

    def blas_threads() -> set[int]:
        return {i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}

    seen: list[set[int]] = []
    path = write_recording(tmp_path / "run.mcap", "mcap", n=8)
    with threadpool_limits(limits=2, user_api="blas"):
        caller = blas_threads()
        assert caller  # numpy's BLAS is loaded
        run_analysis(path, AnalysisOptions(),
                     sink=lambda row, annotation, record: seen.append(blas_threads()))
        after = blas_threads()
    assert len(seen) == 8 and all(s == {1} for s in seen)
    assert after == caller
    seen.clear()  # --jobs 2 on a recording too short to split: analysed here, the same way
    with threadpool_limits(limits=2, user_api="blas"):
        res = run_analysis(path, AnalysisOptions(jobs=2),
                           sink=lambda row, annotation, record: seen.append(blas_threads()))
    assert res.windows == 1 and len(seen) == 8 and all(s == {1} for s in seen)


def test_frames_reach_the_sink_wherever_they_are_analysed_in_this_process(tmp_path: Path
                                                                         ) -> None:
    """--jobs 2 on a recording too short to split runs in one window here: its frames reach
    the sink; split into windows they do not (diagnostics.mcap's writer gets them as parts
    instead: the test below), and ``windows`` says which happened."""
    seen: list[int] = []

    def sink(row: dict, annotation: object, record: object) -> None:
        seen.append(int(row["frame"]))

    short = write_recording(tmp_path / "short.mcap", "mcap", n=30)
    res = run_analysis(short, AnalysisOptions(jobs=2), sink=sink)
    assert res.windows == 1 and seen == list(range(30))
    seen.clear()
    long = write_recording(tmp_path / "long.mcap", "mcap", n=150)
    res = run_analysis(long, AnalysisOptions(jobs=2), sink=sink)
    assert res.windows == 2 and seen == []


def _diagnostics(path: Path) -> dict[str, list[tuple[int, str]]]:
    """diagnostics.mcap per topic: (log time, content) in log-time order; the row messages
    decoded without their timing fields (``ms_*``, measured anew by every run), every other
    message as its bytes."""
    import math
    from collections import defaultdict

    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    def plain(v: object) -> object:
        return "nan" if isinstance(v, float) and math.isnan(v) else v

    out: dict[str, list[tuple[int, str]]] = defaultdict(list)
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, ch, m, msg in reader.iter_decoded_messages(log_time_order=False):
            head = getattr(msg, "header", None)
            stamp = (head.stamp.sec, head.stamp.nanosec, head.frame_id) if head else None
            if ch.topic == "/diagnostics":
                st = msg.status[0]
                v: object = (stamp, st.level, st.name, st.message, st.hardware_id,
                             [(k.key, k.value) for k in st.values if not k.key.startswith("ms_")])
            elif ch.topic.endswith("/metrics"):
                v = (stamp, [(k, plain(getattr(msg, k))) for k in msg.__slots__
                             if not k.startswith("ms_") and k != "header"])
            else:
                v = bytes(m.data)
            out[ch.topic].append((m.log_time, repr(v)))
    return {t: sorted(v) for t, v in out.items()}


@pytest.mark.parametrize("source", ["moving", "still", "camera+lidar"])
def test_a_split_run_writes_the_diagnostics_of_a_serial_run(tmp_path: Path, source: str
                                                            ) -> None:
    """With --jobs 2 each window streams its image annotations (the LiDAR task its points)
    into a part file, merged in window order: diagnostics.mcap holds the messages a
    single-process run writes, annotations and points byte for byte, the row messages on the
    recording's log times with its frame ids (timing fields aside). ``still``: the second
    window's warm-up never meets the first window's keyframes, so it is continued from that
    window's state, and its first frames' annotations come from the continued run."""
    from frontdiag.cli import main

    if source == "camera+lidar":
        path = tmp_path / "corridor.mcap"
        assert main(["simulate", "dock_corridor", "-o", str(path), "--size", "160x120",
                     "--lidar", "16x256", "--seconds", "8", "--seed", "2"]) == 0
    else:
        path = write_recording(tmp_path / "run.mcap", "mcap", n=150,
                               shift=1 if source == "moving" else 0)
    res = {}
    for jobs in (1, 2):
        out = tmp_path / f"jobs{jobs}"
        assert main(["analyze", str(path), "--out", str(out), "-q", "--fail-on", "never",
                     "--jobs", str(jobs)]) == 0
        res[jobs] = _diagnostics(out / "diagnostics.mcap")
    assert run_analysis(path, AnalysisOptions(jobs=2)).windows == 2
    assert res[1] == res[2]
    n_cam = 150 if source != "camera+lidar" else 120
    assert len(res[2]["/frontdiag/camera/annotations"]) == n_cam
    if source == "camera+lidar":
        assert len(res[2]["/frontdiag/lidar/used_points"]) == 80
    assert not list((tmp_path / "jobs2").glob(".frontdiag-parts-*"))  # the parts are gone


@pytest.mark.parametrize("jobs", [2, 1])
def test_a_killed_runs_parts_are_removed_by_the_next_run(tmp_path: Path, jobs: int) -> None:
    """A split run killed outright (SIGKILL: no ``finally`` runs) leaves its part folder; the
    next run into that folder, split or not, removes it, and leaves the folder of a run still
    going."""
    import os
    import signal

    from frontdiag.cli import main

    path = write_recording(tmp_path / "run.mcap", "mcap", n=150)
    out = tmp_path / "res"
    out.mkdir()
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()  # a process that has ended: its pid names a killed run's folder
    stale = out / f".frontdiag-parts-{gone.pid}-x1"
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        running = out / f".frontdiag-parts-{live.pid}-x2"
        for d in (stale, running):
            d.mkdir()
            (d / "window0.mcap").write_bytes(b"")
        assert main(["analyze", str(path), "--out", str(out), "-q", "--fail-on", "never",
                     "--jobs", str(jobs), "--force"]) == 0
        assert not stale.exists() and running.exists()
        assert sorted(p.name for p in out.glob(".frontdiag-parts-*")) == [running.name]
    finally:
        os.kill(live.pid, signal.SIGKILL)
        live.wait()


def test_a_part_merges_the_frames_asked_for(tmp_path: Path) -> None:
    """A window continued from its neighbour's state until it meets its own first run takes
    its first frames' annotations from the continued run's part and the rest from its own:
    a part keeps each annotation's frame index and a merge takes a range of them, with every
    frame's log time and the topic's frame id."""
    from types import SimpleNamespace

    from mcap.reader import make_reader

    from frontdiag.records import CameraAnnotation
    from frontdiag.report.mcap_ import TOPIC_ANNOTATIONS, DiagnosticsWriter

    ann = CameraAnnotation(8, 6, np.zeros((1, 2), np.float32), np.zeros(1, np.uint8),
                           np.zeros((6, 8), int))
    part = DiagnosticsWriter(tmp_path / "part.mcap", part=True)
    with part:
        for i in range(10):
            rec = SimpleNamespace(topic="/cam", index=i, log_ns=1000 + i, t_ns=500 + i,
                                  frame_id="cam_optical")
            part({}, ann, rec)  # type: ignore[arg-type]
    out = DiagnosticsWriter(tmp_path / "merged.mcap")
    with out:
        out.merge_part(part.part(), (3, 6))
        out.merge_part(part.part(), (8, None))
        assert out.log_ns("/cam", 4, 0) == 1004 and out.log_ns("/cam", 9, 0) == 1009
        assert out._frame_ids == {"/cam": "cam_optical"}
    with open(tmp_path / "merged.mcap", "rb") as f:
        got = [(m.log_time, m.sequence) for _, ch, m in make_reader(f).iter_messages(
            log_time_order=False) if ch.topic == TOPIC_ANNOTATIONS]
    assert got == [(1003, 0), (1004, 0), (1005, 0), (1006, 0), (1008, 0), (1009, 0)]


def test_a_split_run_reports_progress_while_its_windows_run(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Each window reports the frames it has analysed (warm-up aside) as it goes: the bar moves
    while the windows run (reporting only as each window ended gave one value between 0 and
    the total), never goes back, never passes the total, and ends on it."""
    import frontdiag.parallel

    monkeypatch.setattr(frontdiag.parallel, "PROGRESS_POLL_S", 0.02)
    n = 600
    path = write_recording(tmp_path / "run.mcap", "mcap", n=n)
    seen: list[tuple[int, int | None]] = []
    res = run_analysis(path, AnalysisOptions(jobs=2),
                       progress=lambda done, expected: seen.append((done, expected)))
    assert res.windows == 2 and len(res.table) == n
    done = [d for d, _ in seen]
    assert done == sorted(done) and done[-1] == n and max(done) <= n
    assert {e for _, e in seen} == {n}
    assert len({d for d in done if 0 < d < n}) >= 3, done


def test_rules_reading_longer_intervals_raise_the_two_interval_threshold(tmp_path: Path) -> None:
    from frontdiag.api import _read_intervals_for
    from frontdiag.verdicts import load_ruleset

    shipped = _read_intervals_for(load_ruleset(), AnalysisOptions())
    assert shipped.camera_params is None  # 4.9 px: the frontend's default already covers it
    ov = tmp_path / "ov.toml"
    ov.write_text('[FD-PLN-001]\nthreshold.min_parallax_px = 7.5\n')
    raised = _read_intervals_for(load_ruleset(overrides=ov), AnalysisOptions())
    assert raised.camera_params.two_interval_px == 7.5


@pytest.mark.parametrize("kind", ["garbage_tail", "cut"])
def test_damage_gives_the_serial_frames_and_fault(tmp_path: Path, kind: str) -> None:
    # garbage after a bag's index is seen when the file is opened, by every window's reader;
    # it lies after all frames, so the windows before the last must not stop the stitching
    # there (they did: --jobs 2 kept 60 of the 120 frames a serial pass keeps). A cut inside
    # the second window stops both passes at the same frame.
    from damage import damaged_copy, make_source

    src = make_source(tmp_path / "src", "bag", n=120)
    bad = damaged_copy(src, tmp_path / kind / src.name, kind, 0.8, 0.5)
    serial = run_analysis(bad, AnalysisOptions())
    par = run_analysis(bad, AnalysisOptions(jobs=2))
    assert serial.fault is not None and par.fault is not None
    assert str(par.fault) == str(serial.fault)
    if kind == "garbage_tail":
        assert len(serial.table) == 120
    else:
        assert 60 < len(serial.table) < 120  # the damage is inside the second window
    _same_table(serial.table, par.table)


def test_interrupted_windows_keep_the_frames_before_the_interruption(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # Ctrl-C reaches the main process while the workers run: the workers are told to stop
    # (SIGINT) and hand back their frames. The result is the result of a single process
    # interrupted at the same frame (the recording's own baselines are read over the same
    # rows), but for the span readings of its last rows where the interruption fell just
    # after a window that had finished (_same_but_the_drained_spans).
    import frontdiag.parallel
    from frontdiag.camera import frontend

    path = write_recording(tmp_path / "run.mcap", "mcap", n=150, shift=1)
    whole = run_analysis(path, AnalysisOptions())

    real_wait = frontdiag.parallel.wait
    seen = [0]  # frames the windows have reported analysed

    def interrupted_wait(fs, timeout=None, return_when=None):  # type: ignore[no-untyped-def]
        # where the main process waits for its windows, once a worker has analysed a frame:
        # interrupted at once, workers still starting (on a loaded machine) would have none
        if seen[0] == 0:
            return real_wait(fs, timeout=timeout, return_when=return_when)
        raise KeyboardInterrupt

    def progress(done, expected):  # type: ignore[no-untyped-def]
        seen[0] = done

    with monkeypatch.context() as m:
        m.setattr(frontdiag.parallel, "wait", interrupted_wait)
        par = run_analysis(path, AnalysisOptions(jobs=2), progress=progress)
    assert par.interrupted
    kept = len(par.table)
    assert 0 < kept <= 150
    real = frontend.CameraFrontend.process

    def process(self, frame):  # type: ignore[no-untyped-def]
        if frame.index == kept:
            raise KeyboardInterrupt
        return real(self, frame)

    monkeypatch.setattr(frontend.CameraFrontend, "process", process)
    serial = run_analysis(path, AnalysisOptions())
    assert serial.interrupted == (kept < 150)
    _same_but_the_drained_spans(serial.table, par.table, whole.table)


SPAN_COLUMNS = ("span_frame", "span_dt_s", "rot_only_px_span", "epi_residual_px_span",
                "parallax_med_deg_span")


def _same_but_the_drained_spans(serial: pd.DataFrame, par: pd.DataFrame,
                                whole: pd.DataFrame) -> None:
    """The parallel table of an interrupted run against a single process interrupted at the
    same frame. A window that finished read on past its last frame until the span readings of
    its last rows (FD-ROT-001's motion over 0.33 s, completed when a later keyframe comes) were
    complete, as every finished window does; a single process interrupted a few frames after
    it closes them early. So where the interruption fell shortly after a finished window, the
    rows just before that window's end may differ in those columns, and there the parallel
    rows hold what the whole recording gives; every other value is equal."""
    span = [c for c in SPAN_COLUMNS if c in serial.columns]
    rest = [c for c in serial.columns if c not in span]
    _same_table(serial[rest], par[rest])
    a, b = serial[span].reset_index(drop=True), par[span].reset_index(drop=True)
    differs = np.flatnonzero(~((a == b) | (a.isna() & b.isna())).all(axis=1).to_numpy())
    if len(differs):
        ends = {w.own_to for w in plan_windows(len(whole), 2,
                                                window_overlap(CameraParams()))}
        # one block of rows, ending where a window ends
        assert (differs == np.arange(differs[0], differs[-1] + 1)).all()
        assert differs[-1] + 1 in ends
        pd.testing.assert_frame_equal(b.iloc[differs], whole[span].iloc[differs])




@pytest.fixture
def default_sigint() -> Iterator[None]:
    """Python's own Ctrl-C handler for the test, whatever the test run inherited: a run
    started in the background of a non-interactive shell (`cmd &`, nohup) has SIGINT ignored,
    and frontdiag leaves an ignored signal ignored."""
    import signal

    saved = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, saved)


@pytest.mark.usefixtures("default_sigint")
def test_a_signal_inside_a_frame_stops_at_the_frame_boundary(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Ctrl-C landing in the middle of frame 40 ends the pass after that frame, with the table
    of a pass that read 41 frames: the frontend is never a frame ahead of the rows."""
    import os
    import signal

    from frontdiag.camera import frontend

    path = write_recording(tmp_path / "run.mcap", "mcap", n=80, shift=1)
    real = frontend.CameraFrontend.process

    def process(self, frame):  # type: ignore[no-untyped-def]
        if frame.index == 40:
            os.kill(os.getpid(), signal.SIGINT)  # delivered here, half-way through the frame
        return real(self, frame)

    with monkeypatch.context() as m:
        m.setattr(frontend.CameraFrontend, "process", process)
        stopped = run_analysis(path, AnalysisOptions())
    assert stopped.interrupted
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored
    short = run_analysis(path, AnalysisOptions(max_frames=41))
    assert list(stopped.table["frame"]) == list(range(41))
    _same_table(short.table, stopped.table)


@pytest.mark.usefixtures("default_sigint")
def test_a_second_signal_stops_at_once() -> None:
    import os
    import signal

    from frontdiag.runner import frame_boundary_interrupts

    with frame_boundary_interrupts() as asked:
        assert not asked()
        os.kill(os.getpid(), signal.SIGINT)
        assert asked()  # held, not raised
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_an_ignored_interrupt_stays_ignored() -> None:
    """Under nohup (SIGINT ignored) the pass neither installs its handler nor stops."""
    import os
    import signal

    from frontdiag.runner import frame_boundary_interrupts

    saved = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with frame_boundary_interrupts() as asked:
            assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
            os.kill(os.getpid(), signal.SIGINT)
            assert not asked()
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, saved)


@pytest.mark.parametrize("own_info", [False, True], ids=["scaled", "own-calibration"])
def test_a_change_of_image_size_gives_the_serial_table_in_windows(tmp_path: Path,
                                                                  own_info: bool) -> None:
    """160x120 images, 320x240 from frame 30 (before the second window's warm-up), 160x120
    again from frame 120 (inside it): each window fits K to each frame's size, as the serial
    run does (scaled, or the recording's own CameraInfo for 320x240 where it has one), and
    the size changes are counted once."""
    import cv2
    from recording_factory import DT, T0, K, frame

    from frontdiag.io.writer import RecordingWriter, camera_info_msg, image_msg

    path = tmp_path / "sizes.mcap"
    with RecordingWriter(path, "mcap") as w:
        for i in range(150):
            t = T0 + i * DT
            img = frame(i, 0, shift=1)
            info = camera_info_msg(K, 160, 120, t)
            if 30 <= i < 120:
                img = cv2.resize(img, (320, 240), interpolation=cv2.INTER_LINEAR)
                if own_info:
                    K2 = K.copy()
                    K2[:2] *= 2.0
                    K2[0, 2] += 9.0
                    info = camera_info_msg(K2, 320, 240, t)
            w.write("/cam/image_raw", "sensor_msgs/msg/Image", image_msg(img, "mono8", t), t)
            w.write("/cam/camera_info", "sensor_msgs/msg/CameraInfo", info, t)
    serial = run_analysis(path, AnalysisOptions())
    par = run_analysis(path, AnalysisOptions(jobs=2))
    assert par.windows == 2
    assert serial.table["status"].eq("size_changed").sum() == 2
    assert any(("K from CameraInfo" if own_info else "K scaled by 2") in n
               for n in serial.manifest["notes"])
    _same_table(serial.table, par.table)
    assert serial.manifest["counts"] == par.manifest["counts"]
    assert serial.manifest["notes"] == par.manifest["notes"]


@pytest.mark.parametrize("shift", [1, 0], ids=["moving", "still"])
def test_repeated_pictures_give_the_serial_table_in_windows(tmp_path: Path, shift: int) -> None:
    """Every picture delivered twice (a topic recorded twice), 151 frames: the second window
    owns from message 181, a copy. Still: the warm-up never meets the serial keyframes, so the
    window is continued from its neighbour's state, which must hold the picture before it (or
    the copy is analysed there and skipped serially). The table and counts are the serial
    ones."""
    from recording_factory import DT, T0, frame

    from frontdiag.io.writer import RecordingWriter, image_msg

    path = tmp_path / "twice.mcap"
    with RecordingWriter(path, "mcap") as w:
        for i in range(151):
            t = T0 + i * DT
            for c in range(2):
                w.write("/cam/image_raw", "sensor_msgs/msg/Image",
                        image_msg(frame(i, 0, shift=shift), "mono8", t), t + c)
    serial = run_analysis(path, AnalysisOptions(intrinsics="100,100,80,60"))
    par = run_analysis(path, AnalysisOptions(intrinsics="100,100,80,60", jobs=2))
    assert par.windows == 2
    assert len(serial.table) == 151
    _same_table(serial.table, par.table)
    assert serial.manifest["counts"] == par.manifest["counts"]
    assert serial.manifest["notes"] == par.manifest["notes"]


def test_thermal_counts_give_the_serial_table_in_windows(tmp_path: Path) -> None:
    """mono16 on a pedestal (a thermal camera's counts) is mapped by a window fixed from the
    selection's first frame: a window that starts later maps its frames the same way, and the
    scene warming by 150 counts over the run changes the grey levels as in the serial run."""
    import numpy as np
    from recording_factory import DT, T0, K, frame

    from frontdiag.io.writer import RecordingWriter, camera_info_msg, image_msg

    path = tmp_path / "thermal.mcap"
    with RecordingWriter(path, "mcap") as w:
        for i in range(150):
            t = T0 + i * DT
            counts = (7300 + i + 3 * frame(i, 0, shift=1).astype(np.int64)).astype(np.uint16)
            w.write("/thermal/image_raw", "sensor_msgs/msg/Image",
                    image_msg(counts, "mono16", t), t)
            w.write("/thermal/camera_info", "sensor_msgs/msg/CameraInfo",
                    camera_info_msg(K, 160, 120, t), t)
    serial = run_analysis(path, AnalysisOptions())
    par = run_analysis(path, AnalysisOptions(jobs=2))
    assert par.windows == 2
    _same_table(serial.table, par.table)
    assert serial.manifest["notes"] == par.manifest["notes"]
    assert any("on a pedestal" in n for n in serial.manifest["notes"])
    # read as the 8-bit frames are, not as a detection failure
    assert not serial.table["conditions"].map(lambda c: "detection_failure" in c).any()
    # a picture re-read for the report is mapped as the run mapped it, not from itself
    from frontdiag.io.images import GrayConverter
    from frontdiag.io.readers import open_recording
    from frontdiag.report.frame_image import read_pixels

    conv = GrayConverter("/thermal/image_raw")  # the run's: mapped from the first frame
    with open_recording(path) as rec:
        raws = list(rec.messages(["/thermal/image_raw"]))
        seen = [conv(rec.deserialize(r), r.msgtype)[0] for r in raws]
    got = read_pixels(serial.manifest, "/thermal/image_raw", T0 + 140 * DT)
    assert got is not None and np.array_equal(got, seen[140])


@pytest.mark.usefixtures("default_sigint")
def test_a_window_asked_to_stop_in_its_read_on_still_completes_its_rows(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A window that has analysed all its frames reads on until its last keyframe interval
    closes. Ctrl-C (or the SIGINT an interrupted run sends its workers) arriving in that read-on
    marks the window interrupted but lets the read-on finish, so its rows are those the window
    gives uninterrupted: the interrupted parallel table then holds whole-recording readings
    there, not readings of whatever frame the signal happened to land on."""
    import os
    import signal

    from frontdiag.api import calibration_for_images
    from frontdiag.camera import frontend
    from frontdiag.io.readers import open_recording
    from frontdiag.io.topics import choose_topics
    from frontdiag.parallel import _task

    path = write_recording(tmp_path / "run.mcap", "mcap", n=150, shift=1)
    opts = AnalysisOptions(jobs=2)
    with open_recording(path) as rec:
        choice = choose_topics(rec.topics)
        intr = calibration_for_images(rec, choice, opts, [])
    first = plan_windows(150, 2, window_overlap(CameraParams()))[0]
    assert first.own_to is not None
    calm = _task(path, choice, opts, intr, first)
    assert not calm.interrupted
    real = frontend.CameraFrontend.process
    seen: list[int] = []

    def process(self, frame):  # type: ignore[no-untyped-def]
        seen.append(frame.index)
        if frame.index == first.own_to:
            os.kill(os.getpid(), signal.SIGINT)  # the first frame past the window
        return real(self, frame)

    with monkeypatch.context() as m:
        m.setattr(frontend.CameraFrontend, "process", process)
        asked = _task(path, choice, opts, intr, first)
    assert asked.interrupted
    assert max(seen) > first.own_to  # the read-on went past the frame the signal landed on
    got = asked.rows.frame()
    assert got["frame"].tolist() == list(range(first.own_to))
    _same_table(calm.rows.frame(), got)


_MALLINFO_PROBE = """
import ctypes, sys
import numpy as np
from frontdiag.parallel import frame_sized_malloc

class MallInfo2(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd",
                                              "usmblks", "fsmblks", "uordblks", "fordblks",
                                              "keepcost")]

libc = ctypes.CDLL("libc.so.6")
libc.mallinfo2.restype = MallInfo2

def mapped(nbytes):
    # mmapped chunks while a picture-sized array is alive, beyond those before it
    before = libc.mallinfo2().hblks
    a = np.empty(nbytes, np.uint8)
    a[:] = 1
    n = libc.mallinfo2().hblks - before
    del a
    return n

frame = 1280 * 720 * 4
first, second = mapped(frame), mapped(frame)
did = frame_sized_malloc()
print(first, second, int(did), mapped(frame))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc")
def test_a_dask_like_environment_gets_malloc_thresholds_fit_for_pictures() -> None:
    """Dask's nanny starts workers with MALLOC_TRIM_THRESHOLD_=65536, which fixes glibc's mmap
    threshold at 128 KiB: every picture-sized array is mapped afresh. A fleet task raises it;
    where nothing fixed the thresholds it leaves glibc's dynamic ones alone."""
    import ctypes

    try:
        ctypes.CDLL("libc.so.6").mallinfo2  # noqa: B018  glibc 2.33 and later
    except (OSError, AttributeError):
        pytest.skip("not glibc 2.33+")
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    run = [sys.executable, "-c", _MALLINFO_PROBE]
    fixed = subprocess.run(run, env={**env, "MALLOC_TRIM_THRESHOLD_": "65536"},
                           capture_output=True, text=True, check=True).stdout.split()
    # fixed low: mapped every time until the thresholds are raised, then taken from the heap
    assert fixed == ["1", "1", "1", "0"]
    dynamic = subprocess.run(run, env=env, capture_output=True, text=True,
                             check=True).stdout.split()
    # glibc's own: the first is mapped, its free raises the threshold; nothing is changed
    assert dynamic == ["1", "0", "0", "0"]
