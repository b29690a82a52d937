"""The log times diagnostics.mcap keeps for every analysed frame (report.mcap_.LogTimes)."""

from __future__ import annotations

import pickle

from frontdiag.report.mcap_ import LogTimes


def test_log_times_read_back_per_topic_and_frame_with_a_default() -> None:
    t = LogTimes()
    for f in (0, 1, 2, 5):
        t.add("/cam", f, 1000 + f)
    t.add("/lidar", 1, 7)
    assert [t.get("/cam", f, -1) for f in (0, 1, 2, 3, 5, 6)] == [1000, 1001, 1002, -1, 1005, -1]
    assert t.get("/lidar", 1, -1) == 7
    assert t.get("/lidar", 0, -1) == -1
    assert t.get("/other", 0, 42) == 42
    assert len(t) == 5


def test_the_last_time_added_for_a_frame_wins_also_after_a_lookup() -> None:
    t = LogTimes()
    t.add("/cam", 3, 10)
    t.add("/cam", 1, 11)
    assert t.get("/cam", 3, -1) == 10
    t.add("/cam", 3, 12)  # added after the index was built
    assert t.get("/cam", 3, -1) == 12
    other = LogTimes()
    other.add("/cam", 1, 21)
    other.add("/cam", 9, 29)
    t.update(other)  # a window's part, merged after
    assert [t.get("/cam", f, -1) for f in (1, 3, 9)] == [21, 12, 29]
    assert [other.get("/cam", f, -1) for f in (1, 3, 9)] == [21, -1, 29]


def test_log_times_cross_to_another_process_whole() -> None:
    t = LogTimes()
    for f in range(100):
        t.add("/cam", f, 5 * f)
    assert t.get("/cam", 50, -1) == 250  # an index built before pickling is not sent
    back = pickle.loads(pickle.dumps(t))
    assert [back.get("/cam", f, -1) for f in (0, 50, 99, 100)] == [0, 250, 495, -1]
