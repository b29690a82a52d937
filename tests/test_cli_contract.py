"""The output contract of the commands: nothing cut off a terminal, gate reasons under -q,
interrupted runs never pass, checks that did not run say so, results never replaced silently."""

from __future__ import annotations

import io
import json
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
from recording_factory import write_recording
from rich.console import Console
from test_verdicts_support import frames

from frontdiag.cli import main
from frontdiag.cli._render import fmt_value
from frontdiag.lidar.spectrum import describe_direction, full_vector, weak_axis
from frontdiag.report import render_console_summary, write_junit
from frontdiag.verdicts import evaluate, gate, load_ruleset

LONG = "/sick_lms_1xx/scan_front_left_with_a_rather_long_namespace/image_raw"


def run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(args)
    cap = capsys.readouterr()
    return code, cap.out, cap.err


@pytest.fixture(scope="module")
def ruleset():
    return load_ruleset()


def test_info_off_a_terminal_keeps_every_topic_and_type_whole(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("COLUMNS", raising=False)
    log = write_recording(tmp_path / "run.mcap", "mcap", n=3, topic=LONG)
    code, out, _ = run(["info", str(log)], capsys)
    assert code == 0
    assert LONG in out and "sensor_msgs/msg/CameraInfo" in out
    assert "…" not in out


def test_quiet_keeps_the_gates_reasons_on_stderr(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    # the tiny fixture slides a textured plane: planar and feature-starved, so rules fire
    log = write_recording(tmp_path / "plane.mcap", "mcap", n=6, shift=4)
    code, out, err = run(["analyze", str(log), "-q", "--fail-on", "warn"], capsys)
    assert code == 1
    assert out == ""
    assert "gate failed" in err and "FD-" in err


def _at_frame(monkeypatch: pytest.MonkeyPatch, n: int, action: Any) -> dict[str, int]:
    """Make the camera frontend call ``action()`` when it is handed its n-th frame."""
    from frontdiag.camera import frontend

    real = frontend.CameraFrontend.process
    calls = {"n": 0}

    def process(self, frame):  # type: ignore[no-untyped-def]
        calls["n"] += 1
        if calls["n"] == n:
            action()
        return real(self, frame)

    monkeypatch.setattr(frontend.CameraFrontend, "process", process)
    return calls


def _ctrl_c() -> None:
    raise KeyboardInterrupt


def test_interrupted_json_is_marked_and_never_passes(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    log = write_recording(tmp_path / "run.mcap", "mcap", n=6)
    calls = _at_frame(monkeypatch, 4, _ctrl_c)
    code, out, _ = run(["analyze", str(log), "--json", "--fail-on", "never"], capsys)
    assert code == 130
    data = json.loads(out)
    assert data["interrupted"] is True
    assert data["verdicts"]["gate"]["passed"] is False
    assert data["verdicts"]["gate"]["exit_code"] == 130
    calls["n"] = 0
    code, out, err = run(["analyze", str(log), "--fail-on", "never"], capsys)
    assert code == 130
    assert "gate passed" not in out and "gate not passed" in out
    assert "nothing saved" in err


def test_a_run_check_without_rows_is_not_evaluated(ruleset) -> None:
    lidar_only = frames(40)
    lidar_only["sensor"] = "lidar"
    res = evaluate(lidar_only, ruleset)
    finding = next(f for f in res.run_findings if f.condition == "exposure_step")
    assert not finding.evaluated and not finding.fired
    buf = io.StringIO()
    render_console_summary(Console(file=buf, width=200, color_system=None), res, gate(res))
    line = next(x for x in buf.getvalue().splitlines() if finding.rule in x)
    assert "not evaluated" in line and " ok" not in line


def test_summary_numbers_keep_their_digits_and_sign() -> None:
    assert fmt_value("sig", 0.456) == "0.456"
    assert fmt_value("sig", 2412.7) == "2413"
    assert fmt_value("sig", 1.952) == "1.95"
    assert fmt_value("{:.3f}", -1e-12) == "0.000"
    assert fmt_value("{:+.1f}", -0.01) == "+0.0" or fmt_value("{:+.1f}", -0.01) == "0.0"
    assert fmt_value("{:+.1f}", -3.0) == "-3.0"


def test_weak_axis_is_categorical_and_the_vector_is_kept() -> None:
    v = np.array([0.02, -0.01, 0.03, 0.95, 0.2, 0.01])  # mostly forward translation
    assert weak_axis(v) == "x"
    assert describe_direction(v).startswith("translation along")
    planar = np.array([0.9, 0.1, 0.3])  # (yaw, x, y)
    assert weak_axis(planar, planar=True) == "yaw"
    full = full_vector(planar, planar=True)
    assert full.shape == (6,) and full[0] == full[1] == full[5] == 0.0
    assert np.isclose(np.linalg.norm(full), 1.0)


def test_lidar_episodes_name_the_weak_direction(ruleset) -> None:
    n = 40
    t = pd.DataFrame({"frame": np.arange(n), "t_ns": np.arange(n) * 100_000_000,
                      "t_rel_s": np.arange(n) * 0.1, "sensor": "lidar", "topic": "/points",
                      "status": "ok", "n_points": 20000.0, "n_points_used": 5000.0,
                      "icp_fitness": 0.99, "lidar_eig_min": 2400.0, "lidar_cond": 35.0,
                      "lidar_weak_axis": "z", "lidar_weak_dir": "translation along z (up)"})
    t.loc[10:25, ["lidar_eig_min", "lidar_cond"]] = [12.0, 2000.0]
    t.loc[10:25, "lidar_weak_axis"] = "x"
    t.loc[10:25, "lidar_weak_dir"] = "translation along x (forward)"
    res = evaluate(t, ruleset)
    ep = res.episodes[res.episodes["condition"] == "registration_degeneracy"].iloc[0]
    assert ep["weak_axis"] == "x"
    assert "translation along x (forward)" in ep["summary"]


def test_a_result_is_not_replaced_without_force(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    log = write_recording(tmp_path / "run.mcap", "mcap", n=3)
    out = tmp_path / "res"
    code, stdout, _ = run(["analyze", str(log), "--out", str(out), "--fail-on", "never"], capsys)
    assert code == 0
    for name in ("frames.parquet", "manifest.json", "episodes.parquet"):
        assert str(out / name) in stdout  # every file written is listed
    before = (out / "manifest.json").read_text()
    code, _, err = run(["analyze", str(log), "--out", str(out), "-q"], capsys)
    assert code == 2 and "--force" in err and "already holds a result" in err
    assert (out / "manifest.json").read_text() == before
    code, _, _ = run(["analyze", str(log), "--out", str(out), "-q", "--force",
                      "--fail-on", "never"], capsys)
    assert code == 0


def test_without_out_it_says_nothing_was_saved(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    log = write_recording(tmp_path / "run.mcap", "mcap", n=3)
    code, out, _ = run(["analyze", str(log), "--fail-on", "never"], capsys)
    assert code == 0 and "nothing saved" in out and "--out DIR" in out


def test_junit_suite_is_the_recording_and_warn_findings_are_not_passes(tmp_path: Path,
                                                                       ruleset) -> None:
    res = evaluate(frames(100, {range(10, 20): {"ratio_reject_rate": 0.85, "in_frame_twin_rate": 0.3}}), ruleset)
    g = gate(res, fail_on="fail")
    root = ET.parse(write_junit(tmp_path / "r.xml", res, g, suite="aisle7.mcap")).getroot()
    assert root.find("testsuite").get("name") == "aisle7.mcap"
    rep = next(c for c in root.iter("testcase") if c.get("name").startswith("FD-REP"))
    skipped = rep.find("skipped")
    assert skipped is not None and "not gated" in skipped.get("message")
    assert rep.find("failure") is None
    assert int(root.find("testsuite").get("skipped")) >= 1


def test_library_warnings_are_console_lines_not_log_records(
        capsys: pytest.CaptureFixture[str]) -> None:
    import logging

    from frontdiag.cli import ConsoleWarnings, install_console_warnings

    install_console_warnings()
    logging.getLogger("frontdiag.io.readers").warning("%s: index missing; reading sequentially",
                                                      "run[1].bag")
    ConsoleWarnings.flush()
    err = capsys.readouterr().err
    assert err.strip() == "warning: run[1].bag: index missing; reading sequentially"
    # a fatal error about the same file supersedes its warnings: one line, the error
    logging.getLogger("frontdiag.io.readers").warning("%s has no summary section", "/d/cut.mcap")
    ConsoleWarnings.flush(superseded_by="/d/cut.mcap: damaged after 50 messages")
    assert capsys.readouterr().err == ""


def test_info_on_a_damaged_recording_exits_2_after_its_report(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from recording_factory import cut_recording

    cut = cut_recording(tmp_path, "mcap", "run.mcap", n=60)
    code, out, err = run(["info", str(cut)], capsys)
    assert code == 2
    assert "cut_run.mcap" in out and "damaged" in out  # the report is still printed
    assert "cut_run.mcap" in err and err.startswith("error:")
    assert len(err.strip().splitlines()) <= 2  # the one-line error and its hint
    code, out, _ = run(["info", str(cut), "--json"], capsys)
    assert code == 2 and json.loads(out)["fault"]


def test_every_command_prints_through_the_non_truncating_console() -> None:
    # a bare rich Console() lays out for 80 columns off a terminal and cuts names with "…"
    cli = Path(__file__).resolve().parents[1] / "frontdiag" / "cli"
    offenders = [p.name for p in cli.glob("*.py")
                 if p.name != "_console.py" and "Console(" in p.read_text().replace(
                     "make_console(", "")]
    assert offenders == []


def test_sigterm_ends_the_run_like_ctrl_c_and_keeps_the_frames(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import os
    import signal

    log = write_recording(tmp_path / "run.mcap", "mcap", n=8)
    # a CI timeout, `timeout`, a supervisor
    _at_frame(monkeypatch, 5, lambda: os.kill(os.getpid(), signal.SIGTERM))
    before = signal.getsignal(signal.SIGTERM)
    code, out, _ = run(["analyze", str(log), "--json", "--out", str(tmp_path / "res")], capsys)
    assert code == 130
    data = json.loads(out)
    assert data["interrupted"] is True and data["verdicts"]["gate"]["passed"] is False
    kept = pd.read_parquet(tmp_path / "res" / "frames.parquet")
    assert 3 <= len(kept) < 8
    assert signal.getsignal(signal.SIGTERM) is before  # the handler is not left behind
