"""`frontdiag analyze` and `frontdiag info` end to end on tiny recordings."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from recording_factory import CONTAINERS, T0, cut_recording, frame, write_recording

import frontdiag
from frontdiag.cli import main
from frontdiag.io.writer import image_msg
from frontdiag.metrics import CAMERA_COLUMNS

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"


def run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    # The tiny fixtures are a textured plane sliding sideways with ~150 features: planar and
    # feature-starved by construction, so the rules rightly fire. These tests are about
    # reading and writing, so they do not gate unless a test asks for it.
    if args and args[0] == "analyze" and "--fail-on" not in args:
        args = [*args, "--fail-on", "never"]
    code = main(args)
    cap = capsys.readouterr()
    return code, cap.out, cap.err


@pytest.mark.parametrize("container", list(CONTAINERS))
def test_analyze_writes_the_table_for_every_container(tmp_path: Path, container: str,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    fmt, name = CONTAINERS[container]
    log = write_recording(tmp_path / name, fmt, n=5)
    out = tmp_path / "res"
    code, _, _ = run(["analyze", str(log), "--out", str(out), "--quiet"], capsys)
    assert code == 0
    df = pd.read_parquet(out / "frames.parquet")
    assert len(df) == 5
    assert set(CAMERA_COLUMNS) <= set(df.columns)
    assert list(df["frame"]) == [0, 1, 2, 3, 4]
    assert (df["sensor"] == "camera").all()
    assert df["status"].iloc[0] != "ok"  # nothing to match the first frame against
    man = json.loads((out / "manifest.json").read_text())
    assert man["topics"]["camera"] == "/cam/image_raw"
    assert man["intrinsics"]["source"].startswith("CameraInfo")
    assert man["params"]["camera"]["n_features"] == 1000
    assert "opencv" in man["versions"]  # the OpenCV that is loaded


def test_csv_output_and_terminal_summary(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    log = write_recording(tmp_path / "run.mcap", "mcap", n=4)
    code, stdout, _ = run(["analyze", str(log), "--out", str(tmp_path / "r"), "--format", "csv"],
                          capsys)
    assert code == 0
    assert (tmp_path / "r" / "frames.csv").exists()
    assert "entropy H/Hmax" in stdout  # the summary table, with units in the labels
    assert "latency (ms)" in stdout


def test_writing_the_result_leaves_the_table_as_it_was(tmp_path: Path) -> None:
    """The outputs convert list, vector and mixed columns on a shallow copy: the table handed
    to diagnostics.mcap's writer and to API callers keeps its lists and None."""
    from frontdiag.api import AnalysisOptions, run_analysis
    from frontdiag.output import write_table

    sample = Path(__file__).resolve().parents[1] / "sample_logs" / "dock_corridor.mcap"
    table = run_analysis(sample, AnalysisOptions()).table
    # a column of mixed objects, as a caller may add: written as strings
    table["note"] = pd.Series([1.5 if i % 3 else "x" for i in range(len(table))], dtype=object)
    table.loc[0, "note"] = np.nan
    before = table.copy(deep=True)
    assert table["lidar_weak_vec"].map(lambda v: isinstance(v, list)).any()
    assert table["rules"].map(lambda v: isinstance(v, list)).all()
    write_table(tmp_path, table, csv=True)
    pd.testing.assert_frame_equal(table, before)
    back = pd.read_parquet(tmp_path / "frames.parquet")
    assert pd.isna(back["note"].iloc[0]) and back["note"].tolist()[1:4] == ["1.5", "1.5", "x"]
    assert len(back) == len(table) and (tmp_path / "frames.csv").exists()


def test_frames_parquet_in_row_groups_reads_as_one_table(tmp_path: Path, monkeypatch) -> None:
    """frames.parquet is written a row group at a time with the types of the whole table: a
    vector, list or string column whose first group holds only None reads back as the rest's
    type, and the table's attrs (the manifest) come back as pandas stores them."""
    import pyarrow.parquet as pq

    from frontdiag import output
    from frontdiag.output import read_table, write_table

    monkeypatch.setattr(output, "PARQUET_ROWS", 7)
    n = 30
    table = pd.DataFrame({
        "frame": np.arange(n), "value": np.linspace(0.0, 1.0, n),
        "lidar_weak_vec": [None] * 10 + [[0.0, 1.0, float(i)] for i in range(n - 10)],
        "status": [None] * 15 + ["ok"] * (n - 15),
        "conditions": [[] for _ in range(20)] + [["planar_degeneracy"]] * (n - 20),
        "rules": [[] for _ in range(n)]})
    table.attrs["manifest"] = {"input": "r.mcap", "counts": {"camera": n}}
    write_table(tmp_path, table)
    assert pq.ParquetFile(tmp_path / "frames.parquet").metadata.num_row_groups == 5
    back = read_table(tmp_path)
    assert back.attrs == table.attrs
    assert back["lidar_weak_vec"].iloc[:10].isna().all()
    assert [list(v) for v in back["lidar_weak_vec"].iloc[10:]] == \
        table["lidar_weak_vec"].iloc[10:].tolist()
    assert back["status"].tolist() == table["status"].tolist()
    assert back["conditions"].tolist() == table["conditions"].tolist()
    assert back["rules"].tolist() == table["rules"].tolist()
    monkeypatch.setattr(output, "PARQUET_ROWS", 10 ** 6)  # one group: the same table
    write_table(tmp_path, table)
    pd.testing.assert_frame_equal(read_table(tmp_path), back)


def test_json_summary_on_stdout(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = write_recording(tmp_path / "run.mcap", "mcap", n=4)
    code, stdout, _ = run(["analyze", str(log), "--json"], capsys)
    assert code == 0
    data = json.loads(stdout)
    assert data["sensors"]["camera"]["frames"] == 4


def test_missing_file_is_one_line_exit_2(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(["analyze", str(tmp_path / "nope.mcap")], capsys)
    assert code == 2
    assert "nope.mcap" in err
    assert "Traceback" not in err
    assert len([line for line in err.splitlines() if line.strip()]) <= 2


def test_debug_shows_the_traceback(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(["--debug", "analyze", str(tmp_path / "nope.mcap")], capsys)
    assert code == 2
    assert "Traceback" in err


def test_ambiguous_topics_exit_2_with_exact_options(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    def extra(w, i, t):  # type: ignore[no-untyped-def]
        w.write("/cam2/image_raw", "sensor_msgs/msg/Image", image_msg(frame(i), "mono8", t), t)

    log = write_recording(tmp_path / "two.mcap", "mcap", n=2, extra=extra)
    code, _, err = run(["analyze", str(log)], capsys)
    assert code == 2
    assert "--camera-topic /cam/image_raw" in err and "--camera-topic /cam2/image_raw" in err
    code, _, _ = run(["analyze", str(log), "--camera-topic", "/cam2/image_raw", "-q"], capsys)
    assert code == 0


def test_unknown_topic_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = write_recording(tmp_path / "run.mcap", "mcap", n=2)
    code, _, err = run(["analyze", str(log), "--camera-topic", "/nope"], capsys)
    assert code == 2 and "/nope" in err


@pytest.mark.parametrize("fmt,name", [("mcap", "run.mcap"), ("ros2-db3", "run_db3"),
                                      ("ros2-db3", "run.db3")])
def test_truncated_recording_keeps_frames_before_the_damage(
        tmp_path: Path, fmt: str, name: str, capsys: pytest.CaptureFixture[str]) -> None:
    cut = cut_recording(tmp_path, fmt, name, n=150)
    out = tmp_path / "res"
    code, _, err = run(["analyze", str(cut), "--out", str(out), "--quiet"], capsys)
    assert code == 2
    assert "cut_" + name in err and "damaged" in err
    assert len(err.strip().splitlines()) <= 2  # the one-line error (and its hint)
    df = pd.read_parquet(out / "frames.parquet")
    assert 20 <= len(df) < 150
    assert json.loads((out / "manifest.json").read_text())["fault"]


def test_unknown_encoding_throughout_is_exit_2_naming_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from frontdiag.io.writer import RecordingWriter

    log = tmp_path / "yuv.mcap"
    with RecordingWriter(log, "mcap") as w:
        for i in range(12):
            vals = image_msg(frame(i), "mono8", T0 + i)
            vals["encoding"] = "yuv422"
            w.write("/cam/image_raw", "sensor_msgs/msg/Image", vals, T0 + i)
    code, _, err = run(["analyze", str(log), "-q"], capsys)
    assert code == 2
    assert "yuv422" in err and "/cam/image_raw" in err


def test_single_corrupt_message_is_skipped_and_counted(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    def extra(w, i, t):  # type: ignore[no-untyped-def]
        if i == 2:  # a bogus payload on the image topic, between good frames
            w.write_raw("/cam/image_raw", "sensor_msgs/msg/Image", b"\x00\x01\x02", t + 1)

    log = write_recording(tmp_path / "bad.mcap", "mcap", n=5, extra=extra)
    out = tmp_path / "res"
    code, stdout, _ = run(["analyze", str(log), "--out", str(out)], capsys)
    assert code == 0
    man = json.loads((out / "manifest.json").read_text())
    assert man["counts"]["/cam/image_raw"]["skipped_undecodable"] == 1
    assert len(pd.read_parquet(out / "frames.parquet")) == 5
    assert "undecodable" in stdout


def test_without_intrinsics_says_how_to_pass_k(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    log = write_recording(tmp_path / "nok.mcap", "mcap", n=4, with_info=False)
    out = tmp_path / "res"
    code, stdout, _ = run(["analyze", str(log), "--out", str(out)], capsys)
    assert code == 0
    assert "--intrinsics fx,fy,cx,cy" in stdout
    df = pd.read_parquet(out / "frames.parquet")
    assert df["inliers_e"].isna().all()
    assert df["n_keypoints"].notna().all()
    code, _, _ = run(["analyze", str(log), "--intrinsics", "120,120,80,60", "--out",
                      str(tmp_path / "k"), "-q"], capsys)
    assert code == 0
    man = json.loads((tmp_path / "k" / "manifest.json").read_text())
    assert man["intrinsics"]["source"] == "--intrinsics"


def test_bad_intrinsics_option_is_exit_2(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    log = write_recording(tmp_path / "run.mcap", "mcap", n=2)
    code, _, err = run(["analyze", str(log), "--intrinsics", "1,2,3"], capsys)
    assert code == 2 and "--intrinsics" in err


def test_camera_info_yaml(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = write_recording(tmp_path / "nok.mcap", "mcap", n=3, with_info=False)
    yaml_path = tmp_path / "cam.yaml"
    yaml_path.write_text(
        "image_width: 160\nimage_height: 120\ncamera_name: cam\n"
        "camera_matrix: {rows: 3, cols: 3, data: [120, 0, 80, 0, 120, 60, 0, 0, 1]}\n"
        "distortion_model: plumb_bob\n"
        "distortion_coefficients: {rows: 1, cols: 5, data: [0.01, 0, 0, 0, 0]}\n")
    code, _, _ = run(["analyze", str(log), "--camera-info", str(yaml_path), "--out",
                      str(tmp_path / "r"), "-q"], capsys)
    assert code == 0
    man = json.loads((tmp_path / "r" / "manifest.json").read_text())
    assert man["intrinsics"]["model"] == "plumb_bob"
    assert man["intrinsics"]["D"][0] == pytest.approx(0.01)


def test_same_recording_gives_the_same_table(tmp_path: Path) -> None:
    log = write_recording(tmp_path / "det.mcap", "mcap", n=6)
    a = frontdiag.analyze(log).to_pandas()
    b = frontdiag.analyze(log).to_pandas()
    cols = [c for c in a.columns if not c.startswith("ms_")]
    pd.testing.assert_frame_equal(a[cols], b[cols])


def test_python_api_returns_a_dataframe_with_manifest(tmp_path: Path) -> None:
    log = write_recording(tmp_path / "api.mcap", "mcap", n=4)
    df = frontdiag.analyze(log, max_frames=3).to_pandas()
    assert isinstance(df, pd.DataFrame) and len(df) == 3
    assert df.attrs["manifest"]["selection"]["max_frames"] == 3


def test_input_is_never_modified(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = write_recording(tmp_path / "ro.bag", "bag", n=4)
    before = hashlib.sha256(log.read_bytes()).hexdigest()
    assert run(["analyze", str(log), "--out", str(tmp_path / "r"), "-q"], capsys)[0] == 0
    assert hashlib.sha256(log.read_bytes()).hexdigest() == before


def test_refuses_to_write_into_the_input_folder(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    log = write_recording(tmp_path / "bagdir", "ros2-db3", n=2)
    code, _, err = run(["analyze", str(log), "--out", str(log / "res")], capsys)
    assert code == 2 and "input recording" in err


def test_info_lists_topics_and_choice(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = write_recording(tmp_path / "run.bag", "bag", n=5, with_info=False)
    code, stdout, _ = run(["info", str(log), "--json"], capsys)
    assert code == 0
    data = json.loads(stdout)
    topics = {t["topic"]: t for t in data["topics"]}
    assert topics["/cam/image_raw"]["count"] == 5
    assert topics["/cam/image_raw"]["rate_hz"] == pytest.approx(20.0)
    assert data["analyze_would_use"]["camera"] == "/cam/image_raw"
    assert any("CameraInfo" in o for o in data["oddities"])


def test_info_reports_stamp_gaps_and_non_monotonic_stamps(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    stamps = [T0 + i * 50_000_000 for i in range(10)]
    stamps[6] = stamps[4]  # goes backwards
    log = write_recording(tmp_path / "odd.mcap", "mcap", n=10, stamps=stamps)
    code, stdout, _ = run(["info", str(log), "--json"], capsys)
    assert code == 0
    odd = " ".join(json.loads(stdout)["oddities"])
    assert "non-monotonic" in odd


@pytest.mark.skipif(not (SHARED / "imu_bags_ros1").exists(), reason="../shared/data absent")
def test_real_imu_bag_has_no_usable_sensor_topics(capsys: pytest.CaptureFixture[str]) -> None:
    bag = SHARED / "imu_bags_ros1" / "sparkfun_razor.bag"
    code, _, err = run(["analyze", str(bag)], capsys)
    assert code == 2 and "no usable sensor topics" in err
    code, stdout, _ = run(["info", str(bag)], capsys)
    assert code == 0 and "/imu/data_raw" in stdout


@pytest.mark.skipif(not (SHARED / "rosbags_evo").exists(), reason="../shared/data absent")
def test_real_ros2_db3_and_ros1_bags_open(capsys: pytest.CaptureFixture[str]) -> None:
    for p in (SHARED / "rosbags_evo" / "tf_example", SHARED / "rosbags_evo" / "tf_example.bag",
              SHARED / "rosbags_evo" / "tf_example" / "tf_example.db3"):
        code, stdout, _ = run(["info", str(p), "--json"], capsys)
        assert code == 0
        counts = {t["topic"]: t["count"] for t in json.loads(stdout)["topics"]}
        assert counts["/tf"] == 517


def test_intrinsics_with_distortion_are_used(tmp_path: Path) -> None:
    from recording_factory import K

    from frontdiag.io.writer import RecordingWriter, camera_info_msg

    log = tmp_path / "dist.mcap"
    with RecordingWriter(log, "mcap") as w:
        for i in range(3):
            t = T0 + i * 50_000_000
            w.write("/cam/image_raw", "sensor_msgs/msg/Image", image_msg(frame(i), "mono8", t), t)
            w.write("/cam/camera_info", "sensor_msgs/msg/CameraInfo",
                    camera_info_msg(K, 160, 120, t, D=np.array([0.1, -0.05, 0, 0]),
                                    model="equidistant"), t)
    df = frontdiag.analyze(log).to_pandas()
    assert df.attrs["manifest"]["intrinsics"]["model"] == "equidistant"


def test_rules_fire_on_the_planar_feature_starved_fixture_and_gate(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # a picture sliding 4 px a frame: one homography explains every match (h_over_e ~ 1), as
    # a pan or a plane would; at 1 px a frame there is too little image motion to call either
    log = write_recording(tmp_path / "plane.mcap", "mcap", n=6, shift=4)
    out = tmp_path / "res"
    junit = tmp_path / "junit.xml"
    code, stdout, _ = run(["analyze", str(log), "--out", str(out), "--fail-on", "fail",
                           "--junit", str(junit)], capsys)
    assert code == 1
    assert "gate failed" in stdout
    df = pd.read_parquet(out / "frames.parquet")
    assert {"conditions", "rules", "verdict"} <= set(df.columns)
    fired = {c for conds in df["conditions"] for c in conds}
    assert fired & {"planar_degeneracy", "pure_rotation"}
    assert (out / "episodes.parquet").exists()
    import xml.etree.ElementTree as ET

    assert ET.parse(junit).getroot().iter("testcase")
    # the same run without rules, or with the gate off, exits 0
    assert run(["analyze", str(log), "--no-rules", "-q", "--fail-on", "fail"], capsys)[0] == 0
    assert run(["analyze", str(log), "-q", "--fail-on", "never"], capsys)[0] == 0


def test_bad_rules_dir_is_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = write_recording(tmp_path / "r.mcap", "mcap", n=2)
    bad = tmp_path / "rules"
    bad.mkdir()
    (bad / "x.toml").write_text('[[rule]]\nid = "X-1"\ncondition = "no_such_condition"\n')
    code, _, err = run(["analyze", str(log), "--rules", str(bad)], capsys)
    assert code == 2 and "x.toml" in err


def test_a_production_budget_shows_ransac_starvation(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The reference experiment: no ratio test, no mutual check, a 40-iteration budget.
    The inlier ratio halves and the iterations it requires exceed the budget: FD-RAN-001."""
    log = Path(__file__).resolve().parents[1] / "sample_logs" / "healthy_loop.mcap"
    res = {}
    for name, extra in (("default", []),
                        ("budget", ["--ratio", "1.0", "--no-mutual", "--ransac-iters", "40"])):
        out = tmp_path / name
        run(["analyze", str(log), "--no-lidar", "-q", "--fail-on", "never", "--out", str(out),
             *extra], capsys)
        res[name] = pd.read_parquet(out / "frames.parquet")
    ok, starved = res["default"], res["budget"]
    assert not any("ransac_starved" in c for c in ok["conditions"])
    assert starved["inlier_ratio"].median() < 0.7 * ok["inlier_ratio"].median()
    assert (starved["ransac_iters_run"].dropna() <= 40).all()
    hit = starved["conditions"].map(lambda c: "ransac_starved" in c)
    assert hit.mean() > 0.5
    assert (starved.loc[hit, "ransac_iters_required"] > 40).all()
    assert json.loads((tmp_path / "budget" / "manifest.json").read_text())[
        "params"]["camera"]["ransac_max_iters"] == 40


@pytest.mark.parametrize(("flag", "value"), [("--ratio", "1.5"), ("--ratio", "0"),
                                             ("--ransac-iters", "0")])
def test_bad_frontend_settings_are_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                          flag: str, value: str) -> None:
    log = write_recording(tmp_path / "r.mcap", "mcap", n=2)
    code, _, err = run(["analyze", str(log), flag, value], capsys)
    assert code == 2 and flag in err


def test_a_camera_standing_still_is_reported_under_pure_rotation(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Identical frames: H/E = 1 at zero parallax and nothing turned either. Nothing can be
    triangulated from them, so the frames read pure_rotation, and explain names the reason."""
    log = write_recording(tmp_path / "still.mcap", "mcap", n=30, shift=0)
    out = tmp_path / "res"
    run(["analyze", str(log), "-q", "--out", str(out)], capsys)
    df = pd.read_parquet(out / "frames.parquet")
    assert (df["h_over_e"].dropna() > 0.9).all() and (df["parallax_med_deg"].dropna() < 0.1).all()
    hit = df["conditions"].map(lambda c: "pure_rotation" in c)
    assert hit.iloc[5:].all()
    frame = int(df.loc[hit, "frame"].iloc[3])
    code, stdout, _ = run(["explain", str(out), "--frame", str(frame)], capsys)
    assert code == 0 and "standing still" in stdout


def test_stride_past_a_tracking_rate_is_named_not_read_as_repetition(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The repetitive sample log (10 Hz) is found at its own rate. At --stride 6 the frames are
    0.6 s apart (their rejection reads 83-85 %, from baseline as much as from repetition):
    FD-REP-001 does not read those rows and says so in a note."""
    log = Path(__file__).resolve().parents[1] / "sample_logs" / "repetitive_aisle"
    seen = {}
    for stride in ("1", "6"):
        code, stdout, _ = run(["analyze", str(log), "--no-lidar", "--json", "--stride", stride],
                              capsys)
        assert code == 0
        seen[stride] = json.loads(stdout)
    full, wide = seen["1"], seen["6"]
    share = {s: d["verdicts"]["conditions"].get("repetitive_structure", {}).get("frames", 0)
             for s, d in seen.items()}
    assert share["1"] > 10 and share["6"] == 0
    assert not any("FD-REP-001" in n for n in full["notes"])
    assert any("FD-REP-001" in n and "0.34 s" in n for n in wide["notes"])


def _recording_with_info(path: Path, K_info: np.ndarray, w_info: int, h_info: int,
                         **extra: object) -> Path:
    from recording_factory import H, W

    P = np.hstack([K_info, np.zeros((3, 1))])
    assert (W, H) == (160, 120)
    return _recording_with_infos(path, [{"k": K_info.reshape(-1), "p": P.reshape(-1),
                                         "width": w_info, "height": h_info, **extra}])


def _recording_with_infos(path: Path, infos: list[dict]) -> Path:
    """Six frames; CameraInfo message i carries ``infos[i]`` over the good one (the last
    entry for the rest)."""
    from recording_factory import DT, H, K, W

    from frontdiag.io.writer import RecordingWriter, camera_info_msg

    with RecordingWriter(path, "mcap") as w:
        for i in range(6):
            t = T0 + i * DT
            w.write("/cam/image_raw", "sensor_msgs/msg/Image",
                    image_msg(frame(i, 0, shift=2), "mono8", t), t)
            w.write("/cam/camera_info", "sensor_msgs/msg/CameraInfo",
                    {**camera_info_msg(K, W, H, t), **infos[min(i, len(infos) - 1)]}, t)
    return path


def test_the_first_usable_camera_info_is_used(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    """A driver publishes an unset CameraInfo (K all zeros) until its calibration file is
    loaded, or the first message is damaged: the first usable one is used, with a note."""
    from recording_factory import K

    from frontdiag.api import analyze

    zeros = {"k": np.zeros(9), "p": np.zeros(12)}
    bad_d = {"d": np.array([0.1, 0.0, 0.0])}  # plumb_bob takes 4, 5, 8, 12 or 14
    good = analyze(_recording_with_infos(tmp_path / "good.mcap", [{}]))
    for name, infos, first in (("late.mcap", [zeros, zeros, {}], "no K (all zeros)"),
                               ("bad.mcap", [bad_d, {}], "distortion")):
        t = analyze(_recording_with_infos(tmp_path / name, infos))
        man = t.attrs["manifest"]
        assert np.allclose(man["intrinsics"]["K"], K), name
        used = [n for n in man["notes"] if "used; the" in n]
        assert len(used) == 1 and f"message {len(infos)} used" in used[0] and first in used[0]
        cols = [c for c in good.columns if not c.startswith("ms_")]
        pd.testing.assert_frame_equal(good[cols], t[cols])
    # none usable: unset ones leave the run without intrinsics (noted); a refused one stops it
    unset = analyze(_recording_with_infos(tmp_path / "unset.mcap", [zeros]))
    assert unset.attrs["manifest"]["intrinsics"] is None
    assert (unset["status"].iloc[1:] == "no_intrinsics").all()
    assert any("none of its first 6 messages is usable (the first: no K (all zeros))" in n
               for n in unset.attrs["manifest"]["notes"])
    code, _out, err = run(["analyze", str(_recording_with_infos(tmp_path / "d.mcap", [bad_d]))],
                          capsys)
    assert code == 2 and "distortion" in err and "Traceback" not in err


def test_a_camera_info_for_the_images_size_beats_an_earlier_one_for_another(
        tmp_path: Path) -> None:
    """A driver publishes its full-resolution calibration (320x240) before binning takes
    effect, then the binned one for its 160x120 images, which is not the first scaled: the one
    made for the images is used, with a note, and the table is that of the binned one alone."""
    from recording_factory import K

    from frontdiag.api import analyze

    full = K.copy()
    full[:2] *= 2.0
    full[0, 2] += 7.0  # not the binned calibration scaled
    first = {"k": full.reshape(-1), "p": np.hstack([full, np.zeros((3, 1))]).reshape(-1),
             "width": 320, "height": 240}
    good = analyze(_recording_with_infos(tmp_path / "good.mcap", [{}]))
    t = analyze(_recording_with_infos(tmp_path / "binned.mcap", [first, {}]))
    man = t.attrs["manifest"]
    assert np.allclose(man["intrinsics"]["K"], K)
    assert any("message 2 used, the first made for the images' 160x120 (the first usable one "
               "is for 320x240)" in n for n in man["notes"]), man["notes"]
    cols = [c for c in good.columns if not c.startswith("ms_")]
    pd.testing.assert_frame_equal(good[cols], t[cols])


def test_a_camera_info_for_another_image_size_is_scaled_or_flagged(tmp_path: Path) -> None:
    """A resize node (or binning) that passes the full-size CameraInfo on: K describes 320x240
    while the images are 160x120. Same aspect ratio: K is scaled to the images (pixel centres:
    cx' = (cx + 0.5) s - 0.5) and a note says so; the table equals the one with the images' own
    K. Another aspect ratio (a crop) cannot be scaled: K is kept, with a note."""
    from recording_factory import K

    from frontdiag.api import analyze

    full = K.copy()
    full[0, 0], full[1, 1] = 2 * K[0, 0], 2 * K[1, 1]
    full[0, 2], full[1, 2] = (K[0, 2] + 0.5) * 2 - 0.5, (K[1, 2] + 0.5) * 2 - 0.5
    own = analyze(_recording_with_info(tmp_path / "own.mcap", K, 160, 120))
    big = analyze(_recording_with_info(tmp_path / "big.mcap", full, 320, 240))
    man = big.attrs["manifest"]
    assert np.allclose(man["intrinsics"]["K"], K)
    assert (man["intrinsics"]["width"], man["intrinsics"]["height"]) == (160, 120)
    assert any("is for 320x240 images, the camera's are 160x120: K scaled by 0.5" in n
               for n in man["notes"])
    cols = [c for c in own.columns if not c.startswith("ms_")]
    pd.testing.assert_frame_equal(own[cols], big[cols])

    crop = analyze(_recording_with_info(tmp_path / "crop.mcap", K, 160, 160))
    man = crop.attrs["manifest"]
    assert np.allclose(man["intrinsics"]["K"], K)
    assert any("another aspect ratio (a crop" in n and "--intrinsics" in n for n in man["notes"])
    # one eye's calibration on a side-by-side stereo pair (160x120 holds two 80x120 eyes)
    pair = analyze(_recording_with_info(tmp_path / "pair.mcap", K, 80, 120))
    assert any("a stereo pair side by side" in n and "--camera-topic" in n
               for n in pair.attrs["manifest"]["notes"])
    # `frontdiag info` says the same before anything is analysed
    from frontdiag.inspect import inspect_recording

    assert any("K scaled by 0.5" in o for o in inspect_recording(tmp_path / "big.mcap").oddities)
    assert any("another aspect ratio" in o
               for o in inspect_recording(tmp_path / "crop.mcap").oddities)
    assert not inspect_recording(tmp_path / "own.mcap").oddities


def test_a_change_of_image_size_restarts_the_frontend_with_k_fitted(tmp_path: Path) -> None:
    """A camera reconfigured mid-recording (binning off, another resolution): from frame 8 the
    images are 320x240, the CameraInfo still says 160x120. Nothing is matched across the
    change; the frontend starts afresh there with K scaled to the new size, so the rows from
    frame 8 on are those of a recording that starts at frame 8 (whose K is scaled the same way
    before the run), and the rows before it those of a recording that ends at frame 7, the
    recording's own levels (the rules' baselines) included."""
    import cv2
    from recording_factory import DT, K

    from frontdiag.api import analyze
    from frontdiag.io.writer import RecordingWriter, camera_info_msg

    def write(path: Path, frames: range) -> Path:
        with RecordingWriter(path, "mcap") as w:
            for i in frames:
                t = T0 + i * DT
                img = frame(i, 0, shift=2)
                if i >= 8:
                    img = cv2.resize(img, (320, 240), interpolation=cv2.INTER_LINEAR)
                w.write("/cam/image_raw", "sensor_msgs/msg/Image", image_msg(img, "mono8", t), t)
                w.write("/cam/camera_info", "sensor_msgs/msg/CameraInfo",
                        camera_info_msg(K, 160, 120, t), t)
        return path

    mixed = analyze(write(tmp_path / "mixed.mcap", range(16)))
    head = analyze(write(tmp_path / "head.mcap", range(8)))
    tail = analyze(write(tmp_path / "tail.mcap", range(8, 16)))
    assert mixed["status"].tolist()[7:9] == ["ok", "size_changed"]
    assert mixed["h_over_e"].iloc[9:].notna().all()
    # every column, the rules' baselines and verdicts included: the recording's own levels and
    # the rules' persistence windows (k of n rows) are read on each side of the change apart
    cols = [c for c in mixed.columns if not c.startswith("ms_")]
    pd.testing.assert_frame_equal(mixed[cols].iloc[:8], head[cols])
    later = mixed[cols].iloc[8:].reset_index(drop=True)
    want = tail[cols].copy()
    for c in [c for c in cols if c.endswith("_frame") or c == "frame"]:
        want[c] = want[c].where(want[c] < 0, want[c] + 8)  # the tail numbers its frames from 0
    want["t_rel_s"] = want["t_rel_s"] + 8 * DT / 1e9  # and its time from its own start
    want.loc[0, "status"] = "size_changed"
    pd.testing.assert_frame_equal(later, want)
    notes = mixed.attrs["manifest"]["notes"]
    assert any("the image size changed 1 time(s)" in n and "frame 8: 160x120 -> 320x240" in n
               and "K scaled by 2" in n for n in notes), notes


def test_a_change_of_image_size_takes_the_recordings_own_calibration_for_it(
        tmp_path: Path) -> None:
    """The driver reconfigured to 320x240 publishes the calibration of that mode, which is not
    the 160x120 one scaled (another principal point): from the change on, the frontend uses
    it, and the rows equal those of a recording that starts there with it."""
    import cv2
    from recording_factory import DT, K

    from frontdiag.api import analyze
    from frontdiag.io.writer import RecordingWriter, camera_info_msg

    K2 = K.copy()
    K2[:2] *= 2.0
    K2[0, 2] += 9.0  # not the 160x120 calibration scaled
    K2[1, 2] -= 6.0

    def write(path: Path, frames: range) -> Path:
        with RecordingWriter(path, "mcap") as w:
            for i in frames:
                t = T0 + i * DT
                img = frame(i, 0, shift=2)
                info = camera_info_msg(K, 160, 120, t)
                if i >= 8:
                    img = cv2.resize(img, (320, 240), interpolation=cv2.INTER_LINEAR)
                    info = camera_info_msg(K2, 320, 240, t)
                w.write("/cam/image_raw", "sensor_msgs/msg/Image", image_msg(img, "mono8", t), t)
                w.write("/cam/camera_info", "sensor_msgs/msg/CameraInfo", info, t)
        return path

    mixed = analyze(write(tmp_path / "mixed.mcap", range(16)))
    tail = analyze(write(tmp_path / "tail.mcap", range(8, 16)))
    assert np.allclose(tail.attrs["manifest"]["intrinsics"]["K"], K2)
    cols = ["n_matches", "inliers_e", "inliers_h", "h_over_e", "parallax_med_deg", "rot_deg",
            "pose_info_cond", "status"]
    want = tail[cols].copy()
    want.loc[0, "status"] = "size_changed"
    pd.testing.assert_frame_equal(mixed[cols].iloc[8:].reset_index(drop=True), want)
    notes = mixed.attrs["manifest"]["notes"]
    assert any("frame 8: 160x120 -> 320x240: K from CameraInfo on /cam/camera_info message 9, "
               "made for 320x240 images" in n for n in notes), notes
    # with --intrinsics the user's calibration stands (its image size unknown: kept)
    given = analyze(tmp_path / "mixed.mcap", intrinsics="100,100,79.5,59.5")
    changes = [n for n in given.attrs["manifest"]["notes"] if "frame 8: 160x120" in n]
    assert changes and "K kept" in changes[0] and "CameraInfo" not in changes[0], changes


def test_downscale_reads_the_recording_as_its_shrunk_pictures(tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]
                                                              ) -> None:
    """--downscale 2 on 320x240 pictures with their 320x240 CameraInfo gives the table of a
    recording of the same pictures shrunk to 160x120 with the CameraInfo scaled to them; the
    report re-reads pictures shrunk too."""
    import cv2
    from recording_factory import DT, K

    from frontdiag.api import AnalysisOptions, analyze, run_analysis
    from frontdiag.io.camera_info import scaled_K
    from frontdiag.io.images import shrink
    from frontdiag.io.writer import RecordingWriter, camera_info_msg
    from frontdiag.report.frame_image import read_pixels

    K_big = scaled_K(K, 2.0, 2.0)

    def write(path: Path, factor: int) -> Path:
        with RecordingWriter(path, "mcap") as w:
            for i in range(16):
                t = T0 + i * DT
                img = cv2.resize(frame(i, 0, shift=2), (320, 240),
                                 interpolation=cv2.INTER_LINEAR)
                Ki, size = K_big, (320, 240)
                if factor > 1:
                    img, Ki, size = shrink(img, factor), scaled_K(K_big, 0.5, 0.5), (160, 120)
                w.write("/cam/image_raw", "sensor_msgs/msg/Image", image_msg(img, "mono8", t),
                        t)
                w.write("/cam/camera_info", "sensor_msgs/msg/CameraInfo",
                        camera_info_msg(Ki, *size, t), t)
        return path

    big = write(tmp_path / "big.mcap", 1)
    res = run_analysis(big, AnalysisOptions(downscale=2))
    small = analyze(write(tmp_path / "small.mcap", 2))
    cols = [c for c in small.columns if not c.startswith("ms_")]
    pd.testing.assert_frame_equal(res.table[cols], small[cols])
    assert np.allclose(res.manifest["intrinsics"]["K"], small.attrs["manifest"]["intrinsics"]["K"])
    assert res.manifest["selection"]["downscale"] == 2
    assert any("shrunk by 2" in n for n in res.manifest["notes"])
    got = read_pixels(res.manifest, "/cam/image_raw", T0 + 5 * DT)
    assert got is not None and got.shape == (120, 160)
    # out of range: one line, exit 2
    code, _out, err = run(["analyze", str(big), "--downscale", "0"], capsys)
    assert code == 2 and "--downscale 0" in err


def test_a_size_a_pixel_off_is_the_same_view(tmp_path: Path) -> None:
    """Photographs of one camera, two of them saved a pixel larger (1281x721 among 1280x720,
    as in a published calibration set): the same view, matched on as before, K kept."""
    import cv2
    from recording_factory import DT, K

    from frontdiag.api import analyze
    from frontdiag.io.writer import RecordingWriter, camera_info_msg

    path = tmp_path / "pad.mcap"
    with RecordingWriter(path, "mcap") as w:
        for i in range(8):
            t = T0 + i * DT
            img = frame(i, 0, shift=2)
            if i in (3, 4):
                img = cv2.copyMakeBorder(img, 0, 1, 0, 1, cv2.BORDER_REPLICATE)
            w.write("/cam/image_raw", "sensor_msgs/msg/Image", image_msg(img, "mono8", t), t)
            w.write("/cam/camera_info", "sensor_msgs/msg/CameraInfo",
                    camera_info_msg(K, 160, 120, t), t)
    t = analyze(path)
    assert t["status"].tolist() == ["first_frame"] + ["ok"] * 7
    assert t["width"].tolist()[2:6] == [160, 161, 161, 160]
    assert not any("size changed" in n for n in t.attrs["manifest"]["notes"])


def _repeating(path: Path, n: int, repeat: dict[int, tuple[int, int]]) -> Path:
    """Frames 0..n-1 each followed by the messages ``repeat[i] = (copies, stamp step ns)``
    give: the same picture again, stamped ``step`` later each time (0: the same stamp)."""
    from recording_factory import DT, K

    from frontdiag.io.writer import RecordingWriter, camera_info_msg

    with RecordingWriter(path, "mcap") as w:
        log = T0
        for i in range(n):
            img = frame(i, 0, shift=2)
            t = T0 + i * DT
            copies, step = repeat.get(i, (0, 0))
            for c in range(copies + 1):
                log += 1_000_000
                w.write("/cam/image_raw", "sensor_msgs/msg/Image",
                        image_msg(img, "mono8", t + c * step), log)
                w.write("/cam/camera_info", "sensor_msgs/msg/CameraInfo",
                        camera_info_msg(K, 160, 120, t + c * step), log)
    return path


def test_repeated_pictures_are_counted_not_analysed(tmp_path: Path) -> None:
    """Every message twice (a topic recorded twice): analysed, each copy would read as a frame
    that did not move and matched perfectly (rejection 0). The copies are skipped and noted,
    and the rows are the single recording's. The same picture with later stamps (a stalled
    camera, or a noise-free simulation standing still: they cannot be told apart) is analysed
    and noted."""
    from frontdiag.api import analyze

    one = analyze(_repeating(tmp_path / "one.mcap", 12, {}))
    twice = analyze(_repeating(tmp_path / "twice.mcap", 12, {i: (1, 0) for i in range(12)}))
    assert twice["frame"].tolist() == list(range(0, 24, 2))
    # everything but the frame numbers (message positions) and the time since the recording's
    # first message (its log clock, which the copies advance)
    cols = [c for c in one.columns
            if not c.startswith("ms_") and not c.endswith("frame") and c != "t_rel_s"]
    pd.testing.assert_frame_equal(one[cols], twice[cols])
    man = twice.attrs["manifest"]
    assert man["coverage"]["/cam/image_raw"]["repeats"] == 12
    assert man["coverage"]["/cam/image_raw"]["share"] == 1.0
    assert any("12 message(s) repeated the picture before them with the same stamp (first: "
               "frame 1)" in n for n in man["notes"]), man["notes"]
    assert not any("non-monotonic" in n for n in man["notes"])
    from frontdiag.inspect import inspect_recording  # info says the same before any analysis

    odd = inspect_recording(tmp_path / "twice.mcap").oddities
    assert any("12 message(s) repeat the header stamp of the one before them" in o
               for o in odd), odd
    assert not any("non-monotonic" in o for o in odd)

    stall = analyze(_repeating(tmp_path / "stall.mcap", 12, {5: (3, 10_000_000)}))
    assert stall["frame"].tolist() == list(range(15))
    assert any("3 picture(s) equal the one before them pixel for pixel, with a later stamp "
               "(first: frame 6)" in n for n in stall.attrs["manifest"]["notes"])


def test_a_repeated_uniform_picture_is_analysed(tmp_path: Path) -> None:
    """A black view (a lens cap) repeats without any fault: every frame is a row, and no
    note calls it a stall."""
    from recording_factory import DT

    from frontdiag.api import analyze
    from frontdiag.io.writer import RecordingWriter

    path = tmp_path / "black.mcap"
    with RecordingWriter(path, "mcap") as w:
        for i in range(6):
            t = T0 + i * DT
            w.write("/cam/image_raw", "sensor_msgs/msg/Image",
                    image_msg(np.zeros((120, 160), np.uint8), "mono8", t), t)
    t = analyze(path, intrinsics="100,100,80,60")
    assert len(t) == 6
    assert not any("pixel for pixel" in n for n in t.attrs["manifest"]["notes"])


def test_rectified_images_are_read_with_p_not_k_and_d(tmp_path: Path) -> None:
    """image_rect topics carry images already rectified; their intrinsics are P's left 3x3 and
    no distortion (sensor_msgs/CameraInfo), while K and D describe the raw images. The raw
    topic of the same camera keeps K and D."""
    from recording_factory import DT, K

    from frontdiag.api import analyze
    from frontdiag.io.camera_info import is_rectified_topic
    from frontdiag.io.writer import RecordingWriter, camera_info_msg

    P = np.array([[110.0, 0.0, 78.0, 0.0], [0.0, 110.0, 61.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
    D = np.array([-0.2, 0.05, 0.0, 0.0, 0.0])

    def write(path: Path, topic: str, p: np.ndarray) -> Path:
        with RecordingWriter(path, "mcap") as w:
            for i in range(6):
                t = T0 + i * DT
                w.write(topic, "sensor_msgs/msg/Image",
                        image_msg(frame(i, 0, shift=2), "mono8", t), t)
                info = camera_info_msg(K, 160, 120, t, D=D)
                info["p"] = p.reshape(-1)
                w.write("/stereo/left/camera_info", "sensor_msgs/msg/CameraInfo", info, t)
        return path

    rect = analyze(write(tmp_path / "rect.mcap", "/stereo/left/image_rect", P))
    intr = rect.attrs["manifest"]["intrinsics"]
    assert np.allclose(intr["K"], P[:, :3]) and intr["model"] == "none" and intr["D"] == []
    assert any("the images are rectified, so P's intrinsics are used" in n
               for n in rect.attrs["manifest"]["notes"])
    raw = analyze(write(tmp_path / "raw.mcap", "/stereo/left/image_raw", P))
    intr = raw.attrs["manifest"]["intrinsics"]
    assert np.allclose(intr["K"], K) and np.allclose(intr["D"], D)
    unset = analyze(write(tmp_path / "unset.mcap", "/stereo/left/image_rect", np.zeros((3, 4))))
    assert np.allclose(unset.attrs["manifest"]["intrinsics"]["K"], K)
    assert any("P is unset; K and D are used" in n for n in unset.attrs["manifest"]["notes"])
    assert is_rectified_topic("/zed/zed_node/left/image_rect_color/compressed")
    assert is_rectified_topic("/camera/infra1/image_rect_raw")
    assert not is_rectified_topic("/camera/color/image_raw")
    assert not is_rectified_topic("/direct/image")


def test_a_camera_info_region_of_interest_and_binning_move_k_to_the_images(
        tmp_path: Path) -> None:
    """CameraInfo keeps the full-resolution calibration and says which part of the sensor the
    images show (roi, in full-resolution pixels) and how many pixels each sums (binning). A
    160x120 crop at (80, 60) of a 320x240 sensor, and the 320x240 sensor binned 2x2, both give
    the table of the images' own K."""
    from recording_factory import K

    from frontdiag.api import analyze

    own = analyze(_recording_with_info(tmp_path / "own.mcap", K, 160, 120))
    cols = [c for c in own.columns if not c.startswith("ms_")]
    full = K.copy()
    full[0, 2], full[1, 2] = K[0, 2] + 80, K[1, 2] + 60
    roi = analyze(_recording_with_info(
        tmp_path / "roi.mcap", full, 320, 240,
        roi={"x_offset": 80, "y_offset": 60, "width": 160, "height": 120}))
    man = roi.attrs["manifest"]
    assert np.allclose(man["intrinsics"]["K"], K)
    assert any("region of interest 160x120 at (80, 60)" in n for n in man["notes"])
    pd.testing.assert_frame_equal(own[cols], roi[cols])
    binned = K.copy()
    binned[0, 0], binned[1, 1] = 2 * K[0, 0], 2 * K[1, 1]
    binned[0, 2], binned[1, 2] = (K[0, 2] + 0.5) * 2 - 0.5, (K[1, 2] + 0.5) * 2 - 0.5
    b2 = analyze(_recording_with_info(tmp_path / "bin.mcap", binned, 320, 240,
                                      binning_x=2, binning_y=2))
    man = b2.attrs["manifest"]
    assert np.allclose(man["intrinsics"]["K"], K)
    assert any("binning 2x2" in n for n in man["notes"])
    assert not any("scaled" in n for n in man["notes"])  # binning explained the size
    pd.testing.assert_frame_equal(own[cols], b2[cols])


def test_a_short_focal_length_is_said_to_lengthen_the_motion_span(tmp_path: Path) -> None:
    """At 120 px (the factory's K) the span FD-ROT-001 reads the motion over is
    0.33 s x 495 / 120 = 1.36 s, and the notes say so (from 1.5 times 0.33 s on); a long
    focal length, or a frontend with rot_span_focal_px = 0, keeps 0.33 s and says nothing."""
    from dataclasses import replace

    from frontdiag.api import analyze
    from frontdiag.camera.frontend import CameraParams

    rec = write_recording(tmp_path / "run.mcap", "mcap", n=4)

    def focal_notes(**kw: object) -> list[str]:
        df = analyze(rec, **kw)
        return [n for n in df.attrs["manifest"]["notes"] if n.startswith("focal length")]

    notes = focal_notes()
    assert len(notes) == 1
    assert notes[0].startswith("focal length 120 px, under 495 px") and "over 1.36 s" in notes[0]
    assert focal_notes(intrinsics="600,600,80,60") == []
    assert focal_notes(intrinsics="400,400,80,60") == []  # 0.41 s: too close to 0.33 s to say
    assert "over 0.54 s" in focal_notes(intrinsics="300,300,80,60")[0]
    assert focal_notes(camera_params=replace(CameraParams(), rot_span_focal_px=0.0)) == []
