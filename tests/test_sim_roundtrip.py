"""Simulated recordings read back through every container, deterministically, with labels."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from frontdiag.cli import main
from frontdiag.conditions import LABELS
from frontdiag.sim.lidar import LidarSpec
from frontdiag.sim.run import SimOptions, labels_path_for, simulate
from frontdiag.sim.scenarios import SCENARIOS

TINY = dict(width=160, height=120, rate_hz=10.0, lidar=LidarSpec(beams=8, columns=128))
TOPICS = {"/camera/image_raw", "/camera/camera_info", "/lidar/points", "/odom",
          "/ground_truth", "/imu/data", "/tf", "/tf_static"}


def _read_rosbags(path: Path) -> dict[str, list]:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    out: dict[str, list] = {}
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS1_NOETIC)) as r:
        for conn, _t, raw in r.messages():
            if conn.topic in ("/tf", "/tf_static"):
                out.setdefault(conn.topic, []).append(None)
                continue
            out.setdefault(conn.topic, []).append(r.deserialize(raw, conn.msgtype))
    return out


def _read_mcap(path: Path, ros1: bool) -> dict[str, list]:
    from mcap.reader import make_reader

    if ros1:
        from mcap_ros1.decoder import DecoderFactory
    else:
        from mcap_ros2.decoder import DecoderFactory
    out: dict[str, list] = {}
    with open(path, "rb") as fh:
        for _s, ch, _m, msg in make_reader(fh, decoder_factories=[DecoderFactory()]) \
                .iter_decoded_messages():
            out.setdefault(ch.topic, []).append(msg)
    return out


@pytest.mark.parametrize("fmt", ["mcap", "bag", "db3", "mcap-ros1"])
def test_round_trip_every_container(tmp_path: Path, fmt: str) -> None:
    out = tmp_path / ("rec" + {"mcap": ".mcap", "bag": ".bag", "db3": "",
                               "mcap-ros1": ".mcap"}[fmt])
    res = simulate("healthy_loop", out, fmt, SimOptions(seconds=0.5, **TINY))
    msgs = (_read_mcap(out, fmt == "mcap-ros1") if fmt.startswith("mcap")
            else _read_rosbags(out))
    assert set(msgs) == TOPICS
    assert len(msgs["/camera/image_raw"]) == res.frames == 5
    assert len(msgs["/lidar/points"]) == res.scans == 5
    img = msgs["/camera/image_raw"][0]
    assert (img.height, img.width, img.encoding) == (120, 160, "mono8")
    pix = np.frombuffer(bytes(img.data), np.uint8)
    assert pix.size == 160 * 120 and pix.std() > 5  # textured, not flat
    info = msgs["/camera/camera_info"][0]
    K = np.asarray(getattr(info, "k", None) if hasattr(info, "k") else info.K).reshape(3, 3)
    assert K[0, 0] == pytest.approx(80.0 / np.tan(np.radians(35.0)))
    assert K[0, 2] == pytest.approx(79.5) and K[1, 2] == pytest.approx(59.5)
    cloud = msgs["/lidar/points"][0]
    names = [f.name for f in cloud.fields]
    assert names == ["x", "y", "z", "intensity", "ring", "time"]
    assert cloud.point_step == 22 and cloud.width > 100
    stamp = img.header.stamp
    sec = stamp.sec if hasattr(stamp, "sec") else stamp.secs
    assert sec == 1_700_000_000
    assert labels_path_for(out).is_file()


def test_same_seed_same_bytes_other_seed_other_bytes(tmp_path: Path) -> None:
    def pixels(seed: int, name: str) -> bytes:
        out = tmp_path / name
        simulate("lights_out", out, "mcap", SimOptions(seconds=0.3, seed=seed, **TINY))
        return b"".join(bytes(m.data) for m in _read_mcap(out, False)["/camera/image_raw"])

    a, b, c = pixels(3, "a.mcap"), pixels(3, "b.mcap"), pixels(4, "c.mcap")
    assert a == b
    assert a != c


def _labels(path: Path) -> list[tuple[int, int, str]]:
    with open(labels_path_for(path)) as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["t_start_ns", "t_end_ns", "condition"]
    return [(int(a), int(b), c) for a, b, c in rows[1:]]


def test_labels_come_from_construction(tmp_path: Path) -> None:
    out = tmp_path / "corridor.mcap"
    simulate("dock_corridor", out, "mcap", SimOptions(seconds=1.0, **TINY))
    labels = _labels(out)
    conds = {c for _, _, c in labels}
    assert conds == {"registration_degeneracy", "healthy"}  # camera healthy, LiDAR degenerate
    out = tmp_path / "lights.mcap"
    simulate("lights_out", out, "mcap", SimOptions(seconds=3.0, **TINY))
    labels = _labels(out)
    assert {c for _, _, c in labels} <= set(LABELS)
    dark = [(a, b) for a, b, c in labels if c == "detection_failure"]
    assert len(dark) == 1
    # the fade frames either side of the dark stretch are left unlabelled
    a, b = dark[0]
    healthy = [(x, y) for x, y, c in labels if c == "healthy"]
    assert all(y < a or x > b or (x <= a and y >= b) for x, y in healthy)


def test_exposure_step_is_labelled_on_the_step_frame(tmp_path: Path) -> None:
    out = tmp_path / "door.mcap"
    res = simulate("dock_door", out, "mcap",
                   SimOptions(seconds=6.0, width=160, height=120, rate_hz=10.0, lidar=None))
    assert res.exposure_steps, "the dock door must make the auto-exposure step"
    steps = [(a, b) for a, b, c in res.labels if c == "exposure_step"]
    assert [a for a, _ in steps] == res.exposure_steps
    assert all(a == b for a, b in steps)


def test_cli_list_and_errors(tmp_path: Path, capsys) -> None:
    assert main(["simulate", "--list"]) == 0
    assert "repetitive_aisle" in capsys.readouterr().out
    assert main(["simulate", "no_such_scenario", "-o", str(tmp_path / "x.mcap")]) == 2
    assert main(["simulate", "healthy_loop", "-o", str(tmp_path / "x.mcap"),
                 "--size", "big"]) == 2
    assert main(["simulate", "blank_wall", "-o", str(tmp_path / "w.bag"), "--format", "bag",
                 "--seconds", "0.3", "--size", "96x72", "--lidar", "4x64", "-q"]) == 0
    assert (tmp_path / "w.bag.labels.csv").is_file()


def test_existing_output_needs_force(tmp_path: Path) -> None:
    out = tmp_path / "w.mcap"
    out.write_bytes(b"keep me")
    args = ["simulate", "blank_wall", "-o", str(out), "--seconds", "0.2", "--size", "64x48",
            "--no-lidar", "-q"]
    assert main(args) == 2
    assert out.read_bytes() == b"keep me"
    assert main([*args, "--force"]) == 0
    assert out.read_bytes()[:8] != b"keep me"


def test_sample_logs_are_complete_small_and_labelled() -> None:
    import importlib.util
    import sys

    from frontdiag.scoring import read_labels

    root = Path(__file__).resolve().parent.parent / "sample_logs"
    spec = importlib.util.spec_from_file_location("sample_logs_generate", root / "generate.py")
    assert spec and spec.loader
    gen = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = gen  # dataclasses look their module up while being built
    try:
        spec.loader.exec_module(gen)
    finally:
        del sys.modules[spec.name]
    assert (root / "healthy_loop.mcap").is_file()
    assert {log.scenario for log in gen.LOGS} == set(SCENARIOS)
    assert {log.fmt for log in gen.LOGS} == {"mcap", "bag", "db3"}
    total = 0
    for log in gen.LOGS:
        path = root / log.file
        assert path.exists(), log.file
        labels = read_labels(labels_path_for(path))
        assert len(labels) > 0
        total += sum(f.stat().st_size for f in path.rglob("*")) if path.is_dir() \
            else path.stat().st_size
    assert total <= 25_000_000


@pytest.mark.parametrize("seconds", [12.0, 100.0, 300.0])
def test_healthy_loop_plan_covers_many_laps(seconds: float) -> None:
    """The lap plan is built per lap from distances: runs of several laps (over ~60 s this
    used to loop forever on a zero-length piece at a lap's end) cover exactly the asked time,
    alternate long sides (healthy) and turns (unlabelled), and start each lap on a long side."""
    from frontdiag.sim.scenarios import _LOOP, _healthy_loop

    segs = _healthy_loop(seconds)[0].segments
    assert sum(s.duration for s in segs) == pytest.approx(seconds, abs=1e-9)
    assert all(s.duration > 0 for s in segs)
    cams = [s.camera for s in segs]
    assert cams[::2] == ["healthy"] * len(cams[::2]) and set(cams[1::2]) <= {None}
    lap_s = _LOOP.length / 1.2
    starts = np.cumsum([0.0] + [s.duration for s in segs[:-1]])
    laps = int(seconds // lap_s)
    for k in range(1, laps + 1):  # a piece starts exactly at every lap boundary
        assert np.min(np.abs(starts - k * lap_s)) < 1e-6
