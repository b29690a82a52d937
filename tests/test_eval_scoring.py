"""The scorer on small hand-made tables with hand-computed scores."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from frontdiag.cli import main
from frontdiag.errors import ConfigError
from frontdiag.scoring import (
    format_markdown,
    format_pooled,
    read_frames,
    read_labels,
    score,
    split_conditions,
    wilson_interval,
)


def _labels(rows: list[tuple[int, int, str]]) -> pd.DataFrame:
    return pd.DataFrame(rows, columns=["t_start_ns", "t_end_ns", "condition"])


def _frames(conds: list[str], sensor: str = "camera", t0: int = 0) -> pd.DataFrame:
    return pd.DataFrame({"t_ns": range(t0, t0 + len(conds)), "sensor": sensor,
                         "conditions": conds})


def _by(report, cond):
    return next(c for c in report.conditions if c.condition == cond)


def test_hand_computed_camera_table() -> None:
    # frames 0-3 healthy, 4-7 repetitive, 8-9 healthy
    labels = _labels([(0, 3, "healthy"), (4, 7, "repetitive_structure"), (8, 9, "healthy")])
    conds = ["", "", "", "repetitive_structure",           # 3: one frame early (slack)
             "", "repetitive_structure", "repetitive_structure", "repetitive_structure",
             "", "detection_failure"]                       # 9: a false alarm
    rep = score(_frames(conds), labels)
    r = _by(rep, "repetitive_structure")
    assert (r.episodes, r.episodes_found) == (1, 1)
    assert (r.true_positives, r.false_positives) == (3, 0)   # frame 3 is slack
    assert r.precision == 1.0 and r.recall == 0.75
    assert r.f1 == pytest.approx(2 * 0.75 / 1.75)
    assert r.false_alarms == 0 and r.healthy_frames == 6
    d = _by(rep, "detection_failure")
    assert d.episodes == 0 and d.episode_recall is None
    assert (d.true_positives, d.false_positives, d.precision) == (0, 1, 0.0)
    assert d.false_alarm_rate == pytest.approx(1 / 6)
    assert (rep.healthy_frames, rep.false_alarms) == (6, 1)


def test_episode_found_rule_for_short_and_long_episodes() -> None:
    labels = _labels([(0, 1, "exposure_step"), (10, 12, "exposure_step"),
                      (20, 23, "exposure_step")])
    t = [0, 1, 10, 11, 12, 20, 21, 22, 23]
    c = ["exposure_step", "",          # 2-frame episode, 1 hit: found
         "exposure_step", "", "",      # 3-frame episode, 1 hit < 1.5: missed
         "exposure_step", "exposure_step", "", ""]  # 4 frames, 2 hits = 50 %: found
    rep = score(pd.DataFrame({"t_ns": t, "conditions": c}), labels)
    e = _by(rep, "exposure_step")
    assert (e.episodes, e.episodes_found) == (3, 2)
    assert e.episode_recall == pytest.approx(2 / 3)


def test_unlabelled_frames_are_not_errors() -> None:
    labels = _labels([(0, 2, "healthy"), (6, 9, "pure_rotation")])
    conds = ["", "", "", "pure_rotation", "pure_rotation", "", "", "pure_rotation",
             "pure_rotation", "pure_rotation"]
    # frames 3-5 unlabelled; 5 is also the slack frame before the episode
    p = _by(score(_frames(conds), labels), "pure_rotation")
    assert (p.true_positives, p.false_positives) == (3, 0)
    assert p.episodes_found == 1 and p.recall == 0.75


def test_conditions_are_scored_on_their_own_sensor() -> None:
    labels = _labels([(0, 9, "healthy"), (0, 9, "registration_degeneracy")])
    cam = _frames([""] * 10, "camera")
    lid = _frames(["registration_degeneracy"] * 5 + [""] * 5, "lidar")
    rep = score(pd.concat([cam, lid]), labels)
    r = _by(rep, "registration_degeneracy")
    assert r.sensors == ("lidar",)
    assert (r.frames_labelled, r.true_positives, r.episodes_found) == (10, 5, 1)
    assert r.healthy_frames == 0           # LiDAR rows are degenerate, not healthy
    assert rep.healthy_frames == 10        # camera rows stay healthy
    assert rep.false_alarms == 0
    # a camera row flagging a LiDAR-only condition is not a LiDAR detection
    cam2 = _frames(["registration_degeneracy"] + [""] * 9, "camera")
    r2 = _by(score(cam2, labels), "registration_degeneracy")
    assert r2.true_positives == 0 and r2.frames_flagged == 0


def test_table_without_sensor_column_is_camera() -> None:
    labels = _labels([(0, 3, "feature_clustering")])
    df = pd.DataFrame({"t_ns": [0, 1, 2, 3], "conditions": ["feature_clustering"] * 4})
    f = _by(score(df, labels), "feature_clustering")
    assert f.precision == 1.0 and f.recall == 1.0 and f.f1 == 1.0


def test_split_conditions_accepts_lists_strings_and_blanks() -> None:
    assert split_conditions("a;b") == ("a", "b")
    assert split_conditions(["a", "healthy"]) == ("a",)
    assert split_conditions(float("nan")) == ()
    assert split_conditions(None) == ()
    assert split_conditions("") == ()


def test_read_frames_parquet_and_csv(tmp_path: Path) -> None:
    df = pd.DataFrame({"t_ns": [0, 1], "sensor": ["camera", "camera"],
                       "conditions": [["planar_degeneracy"], []]})
    (tmp_path / "pq").mkdir()
    df.to_parquet(tmp_path / "pq" / "frames.parquet")
    a = read_frames(tmp_path / "pq")
    assert list(a["conditions"]) == [("planar_degeneracy",), ()]
    (tmp_path / "csv").mkdir()
    df.assign(conditions=["planar_degeneracy", ""]).to_csv(tmp_path / "csv" / "frames.csv",
                                                            index=False)
    b = read_frames(tmp_path / "csv")
    assert list(b["conditions"]) == [("planar_degeneracy",), ()]


def test_bad_labels_are_config_errors(tmp_path: Path) -> None:
    p = tmp_path / "l.csv"
    p.write_text("start,end,cond\n1,2,healthy\n")
    with pytest.raises(ConfigError):
        read_labels(p)
    p.write_text("t_start_ns,t_end_ns,condition\n1,2,sleepy\n")
    with pytest.raises(ConfigError):
        read_labels(p)


def _wilson_by_hand(k: int, n: int, z: float = 1.959963984540054) -> tuple[float, float]:
    """Wilson (1927): (p + z²/2n ± z·sqrt(p(1-p)/n + z²/4n²)) / (1 + z²/n)."""
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * (p * (1 - p) / n + z * z / (4 * n * n)) ** 0.5 / (1 + z * z / n)
    return centre - half, centre + half


@pytest.mark.parametrize(("k", "n"), [(3, 4), (0, 10), (10, 10), (11, 780), (1, 5)])
def test_wilson_interval_matches_the_formula(k: int, n: int) -> None:
    lo, hi = wilson_interval(k, n)
    want = _wilson_by_hand(k, n)
    assert (lo, hi) == pytest.approx(want, abs=1e-12)
    assert lo <= k / n <= hi
    assert wilson_interval(0, 0) is None


def test_recall_and_false_alarms_carry_their_interval() -> None:
    # four one-frame episodes of which three are flagged; 40 healthy frames with 2 alarms
    labels = _labels([(0, 39, "healthy"), (40, 40, "pure_rotation"), (42, 42, "pure_rotation"),
                      (44, 44, "pure_rotation"), (46, 46, "pure_rotation")])
    conds = [""] * 40
    conds[10] = conds[20] = "exposure_step"
    conds += ["pure_rotation", "", "pure_rotation", "", "pure_rotation", "", "", ""]
    rep = score(_frames(conds), labels)
    r = _by(rep, "pure_rotation")
    assert (r.episodes, r.episodes_found) == (4, 3)
    assert r.episode_recall_ci95 == pytest.approx(_wilson_by_hand(3, 4))  # 0.30-0.95
    assert (rep.false_alarms, rep.healthy_frames) == (2, 40)
    assert rep.false_alarm_rate_ci95 == pytest.approx(_wilson_by_hand(2, 40))
    d = rep.as_dict()
    row = next(c for c in d["conditions"] if c["condition"] == "pure_rotation")
    assert row["episode_recall_ci95"] == pytest.approx(list(_wilson_by_hand(3, 4)))
    assert d["false_alarm_rate_ci95"] == pytest.approx(list(_wilson_by_hand(2, 40)))
    text = format_pooled(rep)
    assert "3/4" in text and "0.30-0.95" in text
    assert "(95% CI 1.4-16.5 %)" in text


def test_the_markdown_table_is_the_readmes() -> None:
    """The same report as Markdown: a row per labelled condition (found, recall with its
    interval, precision, false alarms), the overall rate with its interval, and the conditions
    flagged without a label named under the table, not given a row of zeros."""
    labels = _labels([(0, 39, "healthy"), (40, 40, "pure_rotation"), (42, 42, "pure_rotation"),
                      (44, 44, "pure_rotation"), (46, 46, "pure_rotation")])
    conds = [""] * 40
    conds[10] = conds[20] = "exposure_step"
    conds += ["pure_rotation", "", "pure_rotation", "", "pure_rotation", "", "", ""]
    lines = format_markdown(score(_frames(conds), labels)).splitlines()
    assert lines[0].startswith("| condition | episodes found | episode recall (95 % interval)")
    assert "| pure_rotation | 3/4 | 0.75 (0.30–0.95) | 1.00 | 0/40 |" in lines
    assert lines[-3] == "| all conditions, healthy frames | | | | 2/40 (5.0 %; 1.4–16.5 %) |"
    assert lines[-1] == "Flagged but never labelled in these recordings: exposure_step (2 frames)."
    assert not any(ln.startswith("| exposure_step") for ln in lines)


def test_cli_eval_json_and_table(tmp_path: Path, capsys) -> None:
    res = tmp_path / "res"
    res.mkdir()
    pd.DataFrame({"t_ns": [0, 1, 2, 3], "sensor": "camera",
                  "conditions": ["", "", "pure_rotation", "pure_rotation"]}).to_csv(
        res / "frames.csv", index=False)
    lab = tmp_path / "l.csv"
    lab.write_text("t_start_ns,t_end_ns,condition\n0,1,healthy\n2,3,pure_rotation\n")
    assert main(["eval", str(res), "--labels", str(lab), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    pr = next(c for c in out["conditions"] if c["condition"] == "pure_rotation")
    assert pr["episode_recall"] == 1.0 and pr["frame_precision"] == 1.0
    assert pr["episode_recall_ci95"] == pytest.approx([0.2065, 1.0], abs=1e-4)  # 1 of 1
    assert out["false_alarm_rate"] == 0.0
    assert out["false_alarm_rate_ci95"] == pytest.approx([0.0, 0.6576], abs=1e-4)  # 0 of 2
    assert main(["eval", str(res), "--labels", str(lab)]) == 0
    text = capsys.readouterr().out
    assert "pure_rotation" in text and "0.21–1.00" in text and "0.0–65.8 %" in text
    assert main(["eval", str(tmp_path / "missing"), "--labels", str(lab)]) == 2
    # --markdown: the table alone on stdout; a failed gate's reasons on stderr, exit 1
    assert main(["eval", str(res), "--labels", str(lab), "--markdown"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[2] == "| pure_rotation | 1/1 | 1.00 (0.21–1.00) | 1.00 | 0/2 |"
    missed = tmp_path / "missed.csv"
    missed.write_text("t_start_ns,t_end_ns,condition\n0,1,pure_rotation\n2,3,pure_rotation\n")
    assert main(["eval", str(res), "--labels", str(missed), "--markdown",
                 "--min-recall", "1"]) == 1
    io = capsys.readouterr()
    assert "| pure_rotation | 1/2 |" in io.out and "accuracy gate" not in io.out
    assert io.err.startswith("accuracy gate failed: pure_rotation")
    assert main(["eval", str(res), "--labels", str(lab), "--markdown", "--json"]) == 2
    assert "choose one" in capsys.readouterr().err


def test_eval_of_a_recording_runs_the_analysis(tmp_path: Path, capsys) -> None:
    api = pytest.importorskip("frontdiag.api")
    if not hasattr(api, "analyze"):
        pytest.skip("frontdiag.api.analyze not available")
    from frontdiag.sim.run import SimOptions, simulate

    rec = tmp_path / "wall.mcap"
    simulate("blank_wall", rec, "mcap", SimOptions(seconds=0.5, width=160, height=120,
                                                   rate_hz=10.0, lidar=None))
    assert main(["eval", str(rec), "--json"]) == 0  # labels default to wall.mcap.labels.csv
    out = json.loads(capsys.readouterr().out)
    assert out["frames"] == 5
    assert [c["condition"] for c in out["conditions"]][:1] == ["detection_failure"]
