"""Measured mode on hand-made analyze result directories with a known tail."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from frontdiag.budget.measured import longest_run, measured_report
from frontdiag.budget.model import Workload
from frontdiag.budget.targets import load_target, targets_dir
from frontdiag.cli import main

PERIOD_NS = 33_333_333


def _result_dir(tmp_path, fmt: str = "parquet", manifest: dict | None = None):
    n = 60
    rng = np.random.default_rng(0)
    cam = pd.DataFrame({
        "sensor": "camera", "t_ns": np.arange(n) * PERIOD_NS, "status": "ok",
        "ms_decode": 1.0, "ms_detect": rng.uniform(8, 10, n), "ms_match": 3.0,
        "ms_geometry": 4.0, "ms_photometric": 0.5})
    cam.loc[5, "status"] = "insufficient_input"
    cam.loc[[20, 21, 22], "ms_geometry"] = 40.0  # three consecutive frames over the period
    cam.loc[40, "ms_match"] = 50.0  # one isolated miss
    stages = [c for c in cam if c.startswith("ms_")]
    cam["ms_total"] = cam[stages].sum(axis=1) + 0.2
    lidar = pd.DataFrame({"sensor": "lidar", "t_ns": np.arange(20) * 100_000_000,
                          "status": "ok", "ms_lidar_preprocess": 5.0,
                          "ms_lidar_register": 20.0})
    lidar["ms_total"] = 25.0
    df = pd.concat([cam, lidar], ignore_index=True).sample(frac=1.0, random_state=1)
    d = tmp_path / "result"
    d.mkdir()
    if fmt == "parquet":
        df.to_parquet(d / "frames.parquet", index=False)
    else:
        df.to_csv(d / "frames.csv", index=False)
    if manifest is not None:
        (d / "manifest.json").write_text(json.dumps(manifest))
    return d


def test_longest_run() -> None:
    assert longest_run(np.array([0, 1, 1, 0, 1, 1, 1, 0], bool)) == (3, 4)
    assert longest_run(np.zeros(4, bool)) == (0, None)


@pytest.mark.parametrize("fmt", ["parquet", "csv"])
def test_known_tail_with_identity_projection(tmp_path, fmt: str) -> None:
    orin = load_target("orin-nano")
    report = measured_report(_result_dir(tmp_path, fmt), Workload(), orin, orin, "same file")
    cam, lidar = report.sensors
    assert cam.sensor == "camera" and cam.frames == 60
    assert cam.period_ms == pytest.approx(33.333, abs=0.01)
    # the machine is the target: the projection is the identity
    assert cam.frame.ratio == pytest.approx(1.0)
    assert cam.frame.target.max == pytest.approx(cam.frame.here.max)
    assert cam.misses_here == cam.misses_target == 4
    assert cam.longest_miss_run == 3
    assert cam.longest_miss_run_start_ns == 20 * PERIOD_NS
    assert cam.cascade and any("crosses" in n for n in report.notes)
    assert cam.statuses == {"ok": 59, "insufficient_input": 1}
    assert cam.frame.here.p50 == pytest.approx(17.7, abs=1.0)
    assert {s.column for s in cam.stages} >= {"ms_detect", "ms_geometry"}
    assert lidar.misses_target == 0 and not lidar.cascade
    assert "estimate" in report.method.lower()


def test_projection_scales_with_the_coefficients(tmp_path) -> None:
    orin = load_target("orin-nano")
    from frontdiag.budget.targets import Coefficient, Target

    twice_as_slow = Target("slow", "", "calibrated", {
        k: Coefficient(k, c.value * 2, "measured", "test") for k, c in orin.coefficients.items()})
    report = measured_report(_result_dir(tmp_path), Workload(), orin, twice_as_slow, "test")
    cam = report.sensors[0]
    assert cam.frame.ratio == pytest.approx(0.5)
    assert cam.frame.target.p50 == pytest.approx(cam.frame.here.p50 / 2)
    assert cam.misses_target < cam.misses_here


def test_manifest_rate_is_used(tmp_path) -> None:
    orin = load_target("orin-nano")
    d = _result_dir(tmp_path, manifest={"inputs": {"camera": {"rate_hz": 15, "width": 640,
                                                               "height": 480}}})
    cam = measured_report(d, Workload(), orin, orin, "same").sensors[0]
    assert cam.period_ms == pytest.approx(66.67, abs=0.01)
    assert cam.misses_target == 0


def test_cli_gates(tmp_path, capsys, monkeypatch) -> None:
    monkeypatch.setenv("COLUMNS", "200")
    d = _result_dir(tmp_path)
    machine = str(targets_dir() / "orin-nano.toml")
    base = ["budget", "--from", str(d), "--target", "orin-nano", "--machine", machine]
    assert main([*base, "--max-p999-ms", "100"]) == 0
    out = capsys.readouterr().out
    assert "ESTIMATE" in out and "Longest run of consecutive misses" in out
    assert main([*base, "--max-p999-ms", "20"]) == 1
    assert main([*base, "--max-util", "0.2"]) == 1
    capsys.readouterr()
    assert main([*base, "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["estimate"] is True and data["sensors"][0]["longest_miss_run"] == 3
    assert main(["budget", "--from", str(tmp_path / "missing"), "--machine", machine]) == 2
    assert main([*base, "--what-if", "matching=brute"]) == 2


def test_the_result_directory_may_be_given_as_the_argument(tmp_path, capsys, monkeypatch) -> None:
    # `budget RESULT_DIR`, as `explain`, `report` and `eval` take it, is `budget --from RESULT_DIR`
    monkeypatch.setenv("COLUMNS", "200")
    d = _result_dir(tmp_path)
    machine = str(targets_dir() / "orin-nano.toml")
    assert main(["budget", "--from", str(d), "--machine", machine, "--json"]) == 0
    by_option = json.loads(capsys.readouterr().out)
    assert main(["budget", str(d), "--machine", machine, "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == by_option
    assert by_option["estimate"] is True
    assert main(["budget", str(d), "--from", str(d), "--machine", machine, "--json"]) == 0
    capsys.readouterr()
    other = tmp_path / "other"
    assert main(["budget", str(d), "--from", str(other), "--machine", machine]) == 2
    assert "two result directories" in capsys.readouterr().err


def test_calibrates_and_caches_when_no_machine_given(tmp_path, capsys, monkeypatch) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    d = _result_dir(tmp_path)
    args = ["budget", "--from", str(d), "--repeats", "1", "--json"]
    assert main(args) == 0
    first = json.loads(capsys.readouterr().out)
    assert "calibrated in this run" in first["machine_note"]
    assert (tmp_path / "cache" / "frontdiag" / "budget-machine.toml").is_file()
    assert main(args) == 0
    assert "cached calibration" in json.loads(capsys.readouterr().out)["machine_note"]
    # a cache that cannot be used is calibrated again, and the note says why
    cache = tmp_path / "cache" / "frontdiag" / "budget-machine.toml"
    cache.write_text(cache.read_text().replace("opencv = ", "opencv = \"0.0\"\nold_opencv = ", 1))
    assert main(args) == 0
    note = json.loads(capsys.readouterr().out)["machine_note"]
    assert "made with another opencv ('0.0' against" in note and "calibrated in this run" in note
    cache.write_text("not toml [")
    assert main(args) == 0
    note = json.loads(capsys.readouterr().out)["machine_note"]
    assert note.startswith("the cache could not be read (") and "calibrated in this run" in note


def test_bad_result_dirs(tmp_path) -> None:
    orin = load_target("orin-nano")
    from frontdiag.errors import RecordingError

    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(RecordingError, match="no frames"):
        measured_report(empty, Workload(), orin, orin, "")
    pd.DataFrame({"sensor": ["camera"]}).to_csv(empty / "frames.csv", index=False)
    with pytest.raises(RecordingError, match="ms_total"):
        measured_report(empty, Workload(), orin, orin, "")
