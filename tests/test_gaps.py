"""A gap in the recording (a pause, or a jump to another place) restarts the frontends."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from recording_factory import DT, T0, write_recording

from frontdiag.api import GAP_STATUS, analyze
from frontdiag.timing import GapDetector


def test_gap_detector_needs_a_long_interval_relative_to_the_stream() -> None:
    g = GapDetector(min_gap_s=0.5, factor=5.0)
    ts = [0.0, 0.1, 0.2, 0.3, 0.45, 0.6, 2.0, 2.1, 2.2]
    got = [g.observe(int(t * 1e9)) for t in ts]
    assert got == [False] * 6 + [True, False, False]
    assert g.count == 1


def test_stride_and_dropped_frames_are_not_gaps() -> None:
    g = GapDetector(min_gap_s=0.5, factor=5.0)
    # every 10th frame of a 30 Hz stream (0.33 s apart) and one dropped pair (0.99 s)
    ts = [i / 3 for i in range(10)] + [10 / 3 + 0.66, 10 / 3 + 1.0]
    assert not any(g.observe(int(t * 1e9)) for t in ts)
    # a slow stream: 0.6 s apart is its normal interval, not a gap
    g = GapDetector(min_gap_s=0.5, factor=5.0)
    assert not any(g.observe(int(t * 1e9)) for t in np.arange(0, 10, 0.6))


def test_backwards_stamps_are_not_gaps() -> None:
    g = GapDetector()
    assert [g.observe(t) for t in (10, 5, 6, 7)] == [False, False, False, False]


def test_analyze_restarts_the_camera_frontend_after_a_gap(tmp_path: Path) -> None:
    stamps = [T0 + i * DT for i in range(8)] + [T0 + 7 * DT + 3_000_000_000 + i * DT
                                               for i in range(1, 5)]
    rec = write_recording(tmp_path / "gap.mcap", "mcap", n=len(stamps), stamps=stamps)
    df = analyze(rec)
    status = df["status"].tolist()
    assert status[0] == "first_frame"
    assert status[8] == GAP_STATUS and status.count(GAP_STATUS) == 1
    assert np.isnan(df.loc[8, "ratio_reject_rate"])  # nothing compared across the gap
    assert df.loc[9, "n_matches"] > 0                 # tracking resumes on the new side
    assert any("1 gap(s)" in n for n in df.attrs["manifest"]["notes"])


def _lidar_recording(path: Path, copies: int) -> Path:
    """Five VLP-style sweeps of the synthetic hall as PointCloud2, each message ``copies``
    times with the same stamp (a topic recorded twice when ``copies`` is 2)."""
    from frontdiag.io.writer import RecordingWriter
    from frontdiag.lidar import synth
    from frontdiag.lidar.se3 import se3_exp
    from frontdiag.sim.messages import pointcloud2_msg

    scene = synth.hall_scene()
    twist = np.array([0.0, 0.0, 0.05, 1.5, 0.0, 0.0])
    with RecordingWriter(path, "mcap") as w:
        for k in range(5):
            xyz, t = synth.spinning_scan(scene, beams=16, columns=512,
                                         pose0=se3_exp(twist * 0.1 * k), twist=twist, seed=k)
            keep = np.isfinite(xyz).all(axis=-1)
            pts = {"x": xyz[keep, 0], "y": xyz[keep, 1], "z": xyz[keep, 2],
                   "intensity": np.zeros(int(keep.sum())),
                   "ring": np.zeros(int(keep.sum())), "time": t[keep]}
            for c in range(copies):
                w.write("/points", "sensor_msgs/msg/PointCloud2",
                        pointcloud2_msg(pts, T0 + k * 100_000_000),
                        T0 + k * 100_000_000 + c * 1_000_000)
    return path


def test_a_lidar_topic_recorded_twice_reads_as_recorded_once(tmp_path: Path) -> None:
    """Each sweep sent twice with its stamp: the copy is counted and not registered (it would
    read as a perfect match with no motion), and its stamp is not a stamp going back."""
    once = analyze(_lidar_recording(tmp_path / "once.mcap", 1))
    twice = analyze(_lidar_recording(tmp_path / "twice.mcap", 2))
    assert twice["frame"].tolist() == [0, 2, 4, 6, 8]
    cols = [c for c in once.columns if not c.startswith("ms_") and c not in ("frame", "log_ns")]
    pd.testing.assert_frame_equal(once[cols], twice[cols])
    notes = twice.attrs["manifest"]["notes"]
    assert any("5 message(s) repeated the scan before them with the same stamp" in n
               for n in notes), notes
    assert not any("non-monotonic" in n for n in notes), notes
    assert twice.attrs["manifest"]["coverage"]["/points"]["repeats"] == 5
