"""`frontdiag budget` through the CLI edge: output formats and the CI-gate exit codes."""

from __future__ import annotations

import json

import pytest

from frontdiag.cli import main


@pytest.fixture(autouse=True)
def _wide_terminal(monkeypatch) -> None:
    monkeypatch.setenv("COLUMNS", "200")


def test_default_table(capsys) -> None:
    assert main(["budget", "--target", "orin-nano"]) == 0
    out = capsys.readouterr().out
    for text in ("Undistort + pyramid", "2.85 Mpx", "8.6", "18.5", "33.3", "55.4", "14.9",
                 "Time (ms)", "rounds this stage to 2.2 ms"):
        assert text in out, text


def test_json(capsys) -> None:
    assert main(["budget", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    camera = data["baseline"]["sensors"][0]
    assert camera["sensor"] == "camera"
    assert 0.54 <= camera["utilisation"] <= 0.56
    assert [s["key"] for s in camera["stages"]] == ["pyramid", "fast", "describe", "match",
                                                     "ransac", "pnp"]


def test_what_if_markdown(capsys) -> None:
    assert main(["budget", "--markdown", "--what-if", "matching=brute",
                 "--what-if", "inlier-ratio=0.7"]) == 0
    out = capsys.readouterr().out
    assert "| Stage | baseline (ms) | matching=brute (ms) | inlier-ratio=0.7 (ms) |" in out
    assert "RANSAC iterations** | 218 | 218 | 38 |" in out


def test_lidar_options(capsys) -> None:
    assert main(["budget", "--lidar", "128x1800@10", "--icp", "point-to-point", "--json"]) == 0
    lidar = json.loads(capsys.readouterr().out)["baseline"]["sensors"][1]
    assert lidar["total_ms"] == pytest.approx(192, abs=0.5)


@pytest.mark.parametrize(("args", "code"), [
    (["--max-util", "0.6"], 0),
    (["--max-util", "0.5"], 1),
    (["--max-util", "0.6", "--what-if", "matching=brute,inlier-ratio=0.3"], 0),  # only baseline
    (["--lidar", "128x1800@10", "--icp", "point-to-point", "--max-util", "0.9"], 1),
    (["--lidar", "128x1800@10", "--max-util", "0.9"], 0),
    (["--max-util", "0"], 2),
    (["--max-p999-ms", "30"], 2),  # a tail needs measured timings
    (["--target", "no-such-board"], 2),
    (["--camera", "1280by720"], 2),
    (["--inlier-ratio", "1.5"], 2),
    (["--solver", "8pt"], 2),  # nobody gave orin-nano an 8-point coefficient
    (["--what-if", "warp=9"], 2),
    (["--json", "--markdown"], 2),
])
def test_exit_codes(args: list[str], code: int, capsys) -> None:
    assert main(["budget", *args]) == code


def test_unknown_target_lists_available(capsys) -> None:
    assert main(["budget", "--target", "no-such-board"]) == 2
    err = capsys.readouterr().err
    assert "orin-nano" in err and "no-such-board" in err


def test_list_targets(capsys) -> None:
    assert main(["budget", "--list-targets", "--json"]) == 0
    names = [t["name"] for t in json.loads(capsys.readouterr().out)["targets"]]
    assert "orin-nano" in names


def test_calibrate_writes_a_usable_target(tmp_path, capsys) -> None:
    out = tmp_path / "this-machine.toml"
    assert main(["budget", "--calibrate", "-o", str(out), "--repeats", "1",
                 "--name", "this-machine"]) == 0
    assert out.is_file()
    assert "this-machine" in out.read_text()
    capsys.readouterr()
    assert main(["budget", "--target", str(out), "--solver", "8pt", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["baseline"]["target"] == "this-machine"
    assert data["baseline"]["sensors"][0]["total_ms"] > 0
