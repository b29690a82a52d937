"""Gating, baselines and the reporters (JUnit, JSON, console, episodes.parquet)."""

from __future__ import annotations

import io
import json
import xml.etree.ElementTree as ET

import pandas as pd
import pytest
from rich.console import Console
from test_verdicts_support import frames

from frontdiag.errors import ConfigError
from frontdiag.report import (
    reanalyse_command,
    render_console_summary,
    to_json,
    write_episodes,
    write_junit,
)
from frontdiag.verdicts import evaluate, gate, load_ruleset, parse_max_fraction


@pytest.fixture(scope="module")
def ruleset():
    return load_ruleset()


@pytest.fixture
def warn_only(ruleset):
    """A run whose only finding is a warn-level repetitive-structure episode."""
    return evaluate(frames(100, {range(10, 20): {"ratio_reject_rate": 0.85, "in_frame_twin_rate": 0.3}}), ruleset)


@pytest.fixture
def failing(ruleset):
    return evaluate(frames(100, {range(30, 34): {"n_keypoints": 100}}), ruleset)


def test_exit_codes_follow_fail_on(warn_only, failing, ruleset) -> None:
    assert gate(evaluate(frames(50), ruleset)).exit_code == 0
    assert gate(warn_only, fail_on="fail").exit_code == 0
    assert gate(warn_only, fail_on="warn").exit_code == 1
    assert gate(failing, fail_on="fail").exit_code == 1
    g = gate(failing, fail_on="never")
    assert g.exit_code == 0 and g.passed
    assert gate(failing).failed_rules == ["FD-DET-001"]


def test_bad_fail_on_is_a_config_error(failing) -> None:
    with pytest.raises(ConfigError):
        gate(failing, fail_on="sometimes")  # type: ignore[arg-type]


def test_max_fraction_gates_even_with_fail_on_never(failing) -> None:
    assert gate(failing, fail_on="never", max_fraction={"fail": 0.05}).exit_code == 0
    g = gate(failing, fail_on="never", max_fraction={"fail": 0.02})
    assert g.exit_code == 1
    assert "4.0% of 100 frames" in g.reasons[0]


def test_parse_max_fraction() -> None:
    assert parse_max_fraction(["fail=0.02", "warn=0.1"]) == {"fail": 0.02, "warn": 0.1}
    assert parse_max_fraction(["fail=0.02,warn=0.5"]) == {"fail": 0.02, "warn": 0.5}
    assert parse_max_fraction(["nopose=0.05"]) == {"nopose": 0.05}
    for bad in (["fail"], ["error=0.1"], ["fail=2"], ["fail=x"], ["nopose=-1"]):
        with pytest.raises(ConfigError):
            parse_max_fraction(bad)


def _lost_track(ruleset):
    """100 frames: the first has no pose by design, 12 lost track (too few matches, E failed),
    and 3 of those also read too few keypoints (a detection failure names them)."""
    t = frames(100, {range(40, 43): {"n_keypoints": 100}})
    t["status"] = "ok"
    t.loc[0, "status"] = "first_frame"
    t.loc[30:38, "status"] = "too_few_matches"
    t.loc[40:42, "status"] = "essential_failed"
    return evaluate(t, ruleset)


def test_frames_with_no_pose_are_counted_and_gated(ruleset) -> None:
    res = _lost_track(ruleset)
    assert gate(res, fail_on="never", max_fraction={"nopose": 0.15}).exit_code == 0
    g = gate(res, fail_on="never", max_fraction={"nopose": 0.10})
    assert g.exit_code == 1
    assert g.reasons == ["max-fraction: no pose on 12.1% of 99 frames (too_few_matches 9, "
                         "essential_failed 3) > 10.0%"]
    buf = io.StringIO()
    render_console_summary(Console(file=buf, width=400, color_system=None), res, g)
    text = buf.getvalue()
    assert "no pose on 12 of 99 frames (too_few_matches 9, essential_failed 3)" in text
    assert "9 of them carry no condition" in text
    assert to_json(res, g)["no_pose"] == {"frames": 12, "expected": 99, "unnamed": 9,
                                          "statuses": {"too_few_matches": 9,
                                                       "essential_failed": 3}}
    # a run that never lost track says nothing about it
    clean = evaluate(frames(50), ruleset)
    buf = io.StringIO()
    render_console_summary(Console(file=buf, width=400, color_system=None), clean, gate(clean))
    assert "no pose" not in buf.getvalue()


def test_the_html_summary_counts_the_frames_with_no_pose(ruleset, tmp_path) -> None:
    from frontdiag.report.html import ReportInputs, RunData, _summary_html

    res = _lost_track(ruleset)
    page = _summary_html(ReportInputs(RunData(tmp_path, res.table, {}, res, ruleset)))
    assert "no pose on 12 of 99 frames (too_few_matches 9, essential_failed 3)" in page
    assert "9 of them carry no condition" in page
    clean = evaluate(frames(50), ruleset)
    assert "no pose" not in _summary_html(ReportInputs(RunData(tmp_path, clean.table, {}, clean,
                                                               ruleset)))


def test_episode_length_limit_from_run_toml(ruleset) -> None:
    lidar = frames(100, {range(10, 80): {"lidar_eig_min": 12.0, "lidar_cond": 1500.0}},
                   sensor="lidar", rate_hz=10)
    res = evaluate(lidar, ruleset)
    g = gate(res, fail_on="fail")
    assert any("episode limit: registration_degeneracy lasted 6.9 s > 5 s" in r for r in g.reasons)


def test_run_finding_gates_at_its_severity(ruleset) -> None:
    import numpy as np

    t = frames(90, {range(90): {"ref_frame": 0}})
    rot = np.cumsum(np.full(90, 0.2))
    dmean = np.zeros(90)
    for s in (20, 50, 75):
        dmean[s] = 20.0
        rot[s:] += 3.0
    t["rot_deg"], t["d_mean_intensity"] = rot, dmean
    res = evaluate(t, ruleset)
    assert "FD-RUN-001" in gate(res, fail_on="warn").failed_rules
    assert "FD-RUN-001" not in gate(res, fail_on="fail").failed_rules


# --- baseline -----------------------------------------------------------------------------------

def _save(tmp_path, name, table, ruleset, recording="aisle7.mcap"):
    d = tmp_path / name
    d.mkdir()
    evaluate(table, ruleset).table.to_parquet(d / "frames.parquet")
    (d / "manifest.json").write_text(json.dumps({"input": recording}))
    return d


def test_baseline_same_run_passes(tmp_path, ruleset) -> None:
    base = _save(tmp_path, "base", frames(100), ruleset)
    assert gate(evaluate(frames(100), ruleset), baseline=base).exit_code == 0


def test_baseline_fails_on_a_metric_median_regression(tmp_path, ruleset) -> None:
    base = _save(tmp_path, "base", frames(100), ruleset)
    worse = frames(100)
    worse["n_keypoints"] = 850            # -15% against a 10% tolerance
    g = gate(evaluate(worse, ruleset), fail_on="never", baseline=base)
    assert g.exit_code == 1
    assert any("median n_keypoints 1000 -> 850" in r for r in g.reasons)


def test_baseline_ignores_improvements(tmp_path, ruleset) -> None:
    base = _save(tmp_path, "base", frames(100), ruleset)
    better = frames(100)
    better["ratio_reject_rate"] = 0.2
    assert gate(evaluate(better, ruleset), baseline=base).exit_code == 0


def test_baseline_fails_on_a_condition_share_regression(tmp_path, ruleset) -> None:
    base = _save(tmp_path, "base", frames(100), ruleset)
    now = frames(100, {range(40, 50): {"ratio_reject_rate": 0.9, "in_frame_twin_rate": 0.3}})
    g = gate(evaluate(now, ruleset), fail_on="never", baseline=base)
    assert any("repetitive_structure on 10.0% of frames, was 0.0%" in r for r in g.reasons)


def test_baseline_without_verdict_columns_is_evaluated(tmp_path, ruleset) -> None:
    d = tmp_path / "raw"
    d.mkdir()
    frames(100, {range(40, 50): {"ratio_reject_rate": 0.9, "in_frame_twin_rate": 0.3}}).to_parquet(d / "frames.parquet")
    same = frames(100, {range(40, 50): {"ratio_reject_rate": 0.9, "in_frame_twin_rate": 0.3}})
    assert gate(evaluate(same, ruleset), fail_on="never", baseline=d).exit_code == 0
    more = frames(100, {range(40, 60): {"ratio_reject_rate": 0.9, "in_frame_twin_rate": 0.3}})
    assert gate(evaluate(more, ruleset), fail_on="never", baseline=d).exit_code == 1


def test_baseline_of_another_recording_is_refused(tmp_path, ruleset) -> None:
    base = _save(tmp_path, "base", frames(100), ruleset, recording="dock.mcap")
    now = frames(100)
    now.attrs["input"] = "/logs/aisle7.mcap"
    with pytest.raises(ConfigError, match="same recording"):
        gate(evaluate(now, ruleset), baseline=base)
    # the manifest that analyze attaches to its table is read the same way
    now = frames(100)
    now.attrs["manifest"] = {"input": {"path": "/logs/aisle7.mcap", "backend": "mcap"}}
    with pytest.raises(ConfigError, match=r"made from dock\.mcap, not aisle7\.mcap"):
        gate(evaluate(now, ruleset), baseline=base)
    now.attrs["manifest"] = {"input": {"path": "/logs/dock.mcap"}}
    assert gate(evaluate(now, ruleset), baseline=base).exit_code == 0


def test_missing_baseline_is_a_config_error(tmp_path, failing) -> None:
    with pytest.raises(ConfigError):
        gate(failing, baseline=tmp_path / "nowhere")


# --- reporters ----------------------------------------------------------------------------------

def test_junit_has_one_case_per_rule_and_failures_list_episodes(tmp_path, failing) -> None:
    g = gate(failing)
    path = write_junit(tmp_path / "report.xml", failing, g)
    root = ET.parse(path).getroot()
    cases = root.findall(".//testcase")
    rule_ids = [r.id for r in failing.ruleset.rules]
    assert len(cases) == len(rule_ids) + 1           # + the run-level gate case
    failed = [c for c in cases if c.find("failure") is not None]
    assert len(failed) == 1 and failed[0].get("name").startswith("FD-DET-001")
    assert "frames 30-33" in failed[0].find("failure").text
    assert root.get("failures") == "1"


def test_junit_gate_case_fails_on_run_level_reasons(tmp_path, failing) -> None:
    g = gate(failing, fail_on="never", max_fraction={"fail": 0.01})
    root = ET.parse(write_junit(tmp_path / "r.xml", failing, g)).getroot()
    gate_case = root.find(".//testcase[@classname='frontdiag.gate']")
    assert gate_case.find("failure") is not None
    assert root.get("failures") == "1"


def test_json_summary_is_plain_json(failing) -> None:
    data = to_json(failing, gate(failing))
    text = json.dumps(data)                      # must not raise on numpy / NaN
    assert "NaN" not in text
    assert data["gate"]["exit_code"] == 1
    assert data["conditions"]["detection_failure"] == {"frames": 4, "share": 0.04, "episodes": 1}
    assert data["verdicts"] == {"ok": 96, "warn": 0, "fail": 4}
    assert data["episodes"][0]["rules"] == ["FD-DET-001"]


def test_episodes_parquet_round_trips(tmp_path, failing, ruleset) -> None:
    path = write_episodes(tmp_path, failing)
    back = pd.read_parquet(path)
    assert len(back) == 1 and back.loc[0, "condition"] == "detection_failure"
    assert list(back.loc[0, "rules"]) == ["FD-DET-001"]
    empty = evaluate(frames(10), ruleset)
    assert pd.read_parquet(write_episodes(tmp_path / "e", empty)).empty


def test_console_summary_lists_episodes_worst_first_with_commands(warn_only, ruleset) -> None:
    res = evaluate(frames(100, {range(10, 20): {"ratio_reject_rate": 0.85, "in_frame_twin_rate": 0.3},
                                range(60, 63): {"n_keypoints": 90}}), ruleset)
    buf = io.StringIO()
    con = Console(file=buf, width=200, color_system=None)
    render_console_summary(con, res, gate(res), lambda e: reanalyse_command("run.mcap", e))
    out = buf.getvalue()
    assert out.index("detection_failure [fail]") < out.index("repetitive_structure [warn]")
    assert "frontdiag analyze run.mcap --start 1.5 --end 2.6 --camera-topic /camera/image_raw" \
        in out
    assert "gate failed" in out


def test_reanalyse_command_clamps_at_the_start_and_keeps_its_result() -> None:
    ep = {"start_t_rel_s": 0.1, "end_t_rel_s": 0.4, "sensor": "camera", "topic": "/cam",
          "rule": "FD-DET-001"}
    assert reanalyse_command("x.bag", ep) == ("frontdiag analyze x.bag --start 0.0 --end 0.9 "
                                              "--camera-topic /cam "
                                              "--out frontdiag-episodes/FD-DET-001-0.0s")
    # beside the run's own result, never onto it
    assert reanalyse_command("x.bag", ep, out_base="res").endswith("--out res/FD-DET-001-0.0s")
