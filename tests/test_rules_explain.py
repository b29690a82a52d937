"""`frontdiag rules list/explain` and `frontdiag explain RESULT_DIR` on a saved table."""

from __future__ import annotations

import json

import pytest
from test_verdicts_support import frames

from frontdiag.cli import main
from frontdiag.report import write_rules_snapshot
from frontdiag.verdicts import Ruleset, load_ruleset


@pytest.fixture
def result_dir(tmp_path):
    d = tmp_path / "out"
    d.mkdir()
    t = frames(60, {range(10, 20): {"h_over_e": 0.98, "parallax_med_deg": 0.04},
                    range(30, 40): {"entropy_norm": 0.36, "pose_info_cond": 5000.0}})
    t.to_parquet(d / "frames.parquet")
    return d


def test_rules_list_names_every_rule(capsys) -> None:
    assert main(["rules", "list"]) == 0
    out = capsys.readouterr().out
    for r in load_ruleset().rules:
        assert r.id in out


def test_rules_explain_shows_text_thresholds_and_units(capsys) -> None:
    assert main(["rules", "explain", "fd-clu-001"]) == 0
    out = capsys.readouterr().out
    assert "wrong fix" in out and "2000 features in the same box" in out
    assert "entropy_alarm = 0.6 (entropy_norm, ratio)" in out
    assert "persistence 3 of 5" in out


def test_a_rule_id_after_rules_is_explained(capsys) -> None:
    """`frontdiag rules FD-CLU-001` is `rules explain FD-CLU-001`; other words stay errors."""
    assert main(["rules", "explain", "FD-CLU-001"]) == 0
    by_explain = capsys.readouterr().out
    assert main(["rules", "fd-clu-001"]) == 0
    assert capsys.readouterr().out == by_explain
    assert main(["rules", "FD-NOP-001"]) == 2
    assert "unknown rule" in capsys.readouterr().err
    assert main(["rules", "lsit"]) == 2
    assert "No such command" in capsys.readouterr().err


def test_rules_explain_unknown_id_exits_2(capsys) -> None:
    assert main(["rules", "explain", "FD-NOP-001"]) == 2
    assert "unknown rule" in capsys.readouterr().err


def test_explain_frame_shows_fired_rule_and_ruled_out_lookalike(result_dir, capsys) -> None:
    assert main(["explain", str(result_dir), "--frame", "15"]) == 0
    out = capsys.readouterr().out
    assert "verdict (what the rules found): fail" in out and "conditions pure_rotation" in out
    assert "frontend status: ok" in out  # the frontend evaluated it; the rules judged it
    assert "FD-ROT-001 pure_rotation [fail] FIRED" in out
    assert "planar_degeneracy ruled out by parallax 0.04 deg < 0.3" in out
    assert "parallax_med_deg" in out and "FD-ROT-001 parallax_split_deg=0.3" in out


def test_explain_by_time_and_clustering_confirmation(result_dir, capsys) -> None:
    assert main(["explain", str(result_dir), "--t", "1.17"]) == 0     # frame 35 at 30 Hz
    out = capsys.readouterr().out
    assert "frame 35" in out
    assert "detection_failure ruled out by keypoint_fill 1 (1000 keypoints) >= 0.3" in out
    assert "confirmed" in out


def test_explain_reports_not_yet_persistent_hits(tmp_path, capsys) -> None:
    d = tmp_path / "o"
    d.mkdir()
    frames(30, {12: {"h_over_e": 0.98, "parallax_med_deg": 0.04}}).to_parquet(d / "frames.parquet")
    assert main(["explain", str(d), "--frame", "12"]) == 0
    out = capsys.readouterr().out
    # the window spans at least 0.33 s: at the table's 30 Hz, 6 of 10 rows
    assert "holds here, not persistent" in out and "needs 6 of 10 consecutive rows" in out
    assert "at least 0.33 s" in out


def test_explain_uses_the_rules_snapshot_of_the_run(result_dir, tmp_path, capsys) -> None:
    ov = tmp_path / "ov.toml"
    ov.write_text("[FD-ROT-001]\nthreshold.parallax_split_deg = 0.01\n")
    write_rules_snapshot(result_dir, load_ruleset(overrides=ov))
    back = Ruleset.from_dict(json.loads((result_dir / "rules.json").read_text()))
    assert back.get("FD-ROT-001").param("parallax_split_deg") == 0.01
    assert main(["explain", str(result_dir), "--frame", "15"]) == 0
    assert "FD-ROT-001 pure_rotation [fail] clear" in capsys.readouterr().out


def test_explain_reads_the_rules_dir_named_in_the_manifest(result_dir, tmp_path, capsys) -> None:
    import shutil

    from frontdiag.verdicts import default_rules_dir

    mine = tmp_path / "myrules"
    shutil.copytree(default_rules_dir(), mine)
    (mine / "lidar.toml").unlink()
    (result_dir / "manifest.json").write_text(json.dumps({"rules": {"dir": str(mine)}}))
    assert main(["explain", str(result_dir), "--frame", "15"]) == 0
    assert "FD-REG" not in capsys.readouterr().out


@pytest.mark.parametrize("args", [[], ["--frame", "999"], ["--frame", "1", "--t", "0.1"],
                                  ["--frame", "1", "--topic", "/nope"]])
def test_explain_bad_selection_exits_2(result_dir, args, capsys) -> None:
    assert main(["explain", str(result_dir), *args]) == 2
    assert capsys.readouterr().err.strip()


def test_explain_missing_result_dir_exits_2(tmp_path, capsys) -> None:
    assert main(["explain", str(tmp_path), "--frame", "1"]) == 2
    assert "frames.parquet" in capsys.readouterr().err


def test_explain_ambiguous_frame_lists_topics(tmp_path, capsys) -> None:
    import pandas as pd

    d = tmp_path / "o"
    d.mkdir()
    pd.concat([frames(10, topic="/a"), frames(10, topic="/b")]).to_parquet(d / "frames.parquet")
    assert main(["explain", str(d), "--frame", "3"]) == 2
    assert "--topic /a or --topic /b" in capsys.readouterr().err
    assert main(["explain", str(d), "--frame", "3", "--topic", "/b"]) == 0


def test_explain_takes_the_camera_row_of_a_camera_and_lidar_frame(tmp_path, capsys) -> None:
    """Frame numbers count per topic: frame 3 of a camera + LiDAR run is the camera's unless
    --topic says otherwise, and the LiDAR topic is named; two cameras stay ambiguous."""
    import pandas as pd

    d = tmp_path / "o"
    d.mkdir()
    pd.concat([frames(10, {3: {"n_keypoints": 77}}, topic="/cam"),
               frames(10, sensor="lidar", topic="/scan")]).to_parquet(d / "frames.parquet")
    assert main(["explain", str(d), "--frame", "3"]) == 0
    out = capsys.readouterr().out
    assert "frame 3 camera /cam" in out
    assert "/scan has a row here too: add --topic /scan" in out
    assert main(["explain", str(d), "--time", "0.1"]) == 0  # frame 3 at 30 Hz, on both topics
    assert "frame 3 camera /cam" in capsys.readouterr().out
    assert main(["explain", str(d), "--frame", "3", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert (doc["topic"], doc["also_on"]) == ("/cam", ["/scan"])
    assert next(m["value"] for m in doc["metrics"] if m["name"] == "n_keypoints") == 77
    assert main(["explain", str(d), "--frame", "3", "--topic", "/scan", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert (doc["sensor"], doc["topic"], doc["also_on"]) == ("lidar", "/scan", [])
    pd.concat([frames(10, topic="/left"), frames(10, topic="/right"),
               frames(10, sensor="lidar", topic="/scan")]).to_parquet(d / "frames.parquet")
    assert main(["explain", str(d), "--frame", "3"]) == 2
    assert "--topic /left or --topic /right or --topic /scan" in capsys.readouterr().err


@pytest.mark.parametrize(("px", "weak"), [(3.0, True), (12.0, False)])
def test_explain_calls_a_planar_reading_weak_when_the_parallax_is_few_pixels(
        tmp_path, capsys, px, weak) -> None:
    d = tmp_path / "o"
    d.mkdir()
    plane = {"h_over_e": 0.95, "parallax_med_deg": 0.8, "parallax_med_px": px}
    frames(30, {range(10, 20): plane}).to_parquet(d / "frames.parquet")
    assert main(["explain", str(d), "--frame", "15"]) == 0
    out = capsys.readouterr().out
    assert "planar quadrant" in out
    assert ("not read: the parallax is" in out) is weak
