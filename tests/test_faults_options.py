"""Bad options, output paths and calibrations: one line, exit 2, before the recording is read."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from recording_factory import T0, H, K, W, write_recording

from frontdiag.cli import main
from frontdiag.errors import ConfigError
from frontdiag.io.camera_info import camera_info_topic_for, checked
from frontdiag.io.writer import camera_info_msg
from frontdiag.records import Intrinsics


def run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main([*args, "--fail-on", "never"] if args[0] == "analyze" else args)
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def _one_error_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


@pytest.fixture
def rec(tmp_path: Path) -> Path:
    return write_recording(tmp_path / "run.mcap", "mcap", n=4)


@pytest.fixture
def never_read(monkeypatch: pytest.MonkeyPatch) -> None:
    """Fail the test if the recording is opened: the checks must come first."""
    import frontdiag.api

    def boom(*a: object, **k: object) -> None:
        raise AssertionError("the recording was opened before the options were checked")

    monkeypatch.setattr(frontdiag.api, "open_recording", boom)


@pytest.mark.parametrize("opt", [
    ["--start", "nan"], ["--end", "inf"], ["--start", "-1"], ["--start", "3", "--end", "2"],
    ["--features", "2147483648"], ["--ransac-iters", "2147483648"], ["--intrinsics", ""],
    ["--intrinsics", "nan,500,320,240"], ["--intrinsics", "500,500,inf,240"],
    ["--stride", "0"],
])
def test_bad_numeric_options_are_refused_up_front(rec: Path, opt: list[str], never_read: None,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(["analyze", str(rec), *opt], capsys)
    assert code == 2
    assert opt[0] in _one_error_line(err)


def test_start_beyond_the_end_names_the_duration(rec: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    for start in ("1000", "1e300"):
        code, _, err = run(["analyze", str(rec), "--start", start], capsys)
        assert code == 2
        line = _one_error_line(err)
        assert "0.150 s long" in line and str(rec) in line  # 4 frames at 20 Hz


def test_end_beyond_the_end_reads_to_the_end(rec: Path, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    code, _, _ = run(["analyze", str(rec), "--end", "1e300", "--out", str(tmp_path / "o")], capsys)
    assert code == 0
    import pandas as pd

    assert len(pd.read_parquet(tmp_path / "o" / "frames.parquet")) == 4


def _out_cases(tmp_path: Path, rec: Path) -> list[tuple[list[str], Path]]:
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    blocked = tmp_path / "blocked"
    (blocked / "frames.parquet").mkdir(parents=True)
    return [
        (["--out", str(a_file / "res")], a_file),
        (["--out", str(a_file)], a_file),
        (["--out", str(blocked), "--force"], blocked / "frames.parquet"),
        (["--junit", str(rec)], rec),  # would overwrite the recording
        (["--junit", str(a_file / "r.xml")], a_file),
        (["--junit", str(tmp_path)], tmp_path),
        (["--out", str(rec)], rec),
    ]


def test_bad_output_locations_are_refused_before_reading(
        rec: Path, tmp_path: Path, never_read: None, capsys: pytest.CaptureFixture[str]) -> None:
    before = rec.read_bytes()
    for opt, named in _out_cases(tmp_path, rec):
        code, _, err = run(["analyze", str(rec), *opt], capsys)
        assert code == 2, opt
        assert str(named) in _one_error_line(err), opt
    assert rec.read_bytes() == before


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_out_is_refused_before_reading(rec: Path, tmp_path: Path, never_read: None,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        for opt in (["--out", str(ro)], ["--out", str(ro / "sub")], ["--junit", str(ro / "j.xml")]):
            code, _, err = run(["analyze", str(rec), *opt], capsys)
            assert code == 2 and str(ro) in _one_error_line(err)
    finally:
        ro.chmod(0o700)


def test_a_write_failure_after_the_analysis_is_exit_2_naming_the_path(
        rec: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    import frontdiag.output

    def full_disk(*a: object, **k: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(frontdiag.output, "write_manifest", full_disk)
    code, _, err = run(["analyze", str(rec), "--out", str(tmp_path / "o")], capsys)
    assert code == 2
    line = _one_error_line(err)
    assert str(tmp_path / "o") in line and "No space left" in line


def test_markup_in_paths_and_topics_is_printed_verbatim(tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    folder = tmp_path / "[/]" / "[cam1]"
    folder.mkdir(parents=True)
    rec = write_recording(folder / "run.mcap", "mcap", n=3, topic="/[cam1]/image_raw")
    code, out, err = run(["analyze", str(rec), "--out", str(folder / "o")], capsys)
    assert code == 0, err
    assert "[cam1]" in out and str(folder) in out
    code, out, err = run(["info", str(rec)], capsys)
    assert code == 0 and "/[cam1]/image_raw" in out
    code, _, err = run(["analyze", str(rec), "--camera-topic", "/[/]"], capsys)
    assert code == 2 and "/[/]" in _one_error_line(err)


def _intr(D: list[float], model: str, K_: np.ndarray = K) -> Intrinsics:
    return Intrinsics(K=K_, D=np.asarray(D, float), model=model, source="CameraInfo on /c")


@pytest.mark.parametrize("D,model", [
    ([0.1, 0.01, 0.0, 0.0, 0.0, 0.3], "plumb_bob"), (list(np.linspace(0.1, 1, 1000)), "plumb_bob"),
    ([0.1, 0.2, 0.3], "rational_polynomial"), ([0.1, 0.2], "equidistant"),
    ([0.1, 0.0, 0.0, 0.0, 0.0], "Brown Conrady"), ([np.nan] * 5, "plumb_bob"),
])
def test_unusable_calibrations_are_refused_naming_the_source(D: list[float], model: str) -> None:
    with pytest.raises(ConfigError, match="CameraInfo on /c"):
        checked(_intr(D, model))


def test_non_finite_k_is_refused() -> None:
    bad = K.copy()
    bad[0, 2] = np.inf
    with pytest.raises(ConfigError, match="NaN or infinite"):
        checked(_intr([], "plumb_bob", bad))


def test_usable_odd_calibrations_are_normalised() -> None:
    notes: list[str] = []
    zero = checked(_intr([0.0] * 5, "Brown Conrady"), notes)
    assert zero.model == "none" and zero.D.size == 0 and "Brown Conrady" in notes[0]
    padded = checked(_intr([0.1, 0.01, 0.001, 0.0, 0.0, 0.0], "plumb_bob"))
    assert padded.model == "plumb_bob" and padded.D.size == 5
    assert checked(_intr([0.1, 0.01, 0.0, 0.0], "fisheye")).model == "equidistant"


def _bad_info(w: Any, i: int, t: int) -> None:
    msg = camera_info_msg(K, W, H, T0, D=np.linspace(0.1, 1, 1000))
    w.write("/cam/camera_info", "sensor_msgs/msg/CameraInfo", msg, t)


def test_a_bad_recording_camera_info_is_exit_2_and_intrinsics_get_past_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rec = write_recording(tmp_path / "run.mcap", "mcap", n=4, with_info=False, extra=_bad_info)
    code, _, err = run(["analyze", str(rec)], capsys)
    assert code == 2
    line = _one_error_line(err)
    assert "/cam/camera_info" in line and "1000" in line
    yaml = tmp_path / "cam.yaml"
    yaml.write_text("camera_matrix: {rows: 3, cols: 3, data: [120, 0, 80, 0, 120, 60, 0, 0, 1]}\n"
                    "distortion_model: plumb_bob\ndistortion_coefficients: {data: [0, 0, 0, 0, 0]}\n")
    for i, opt in enumerate((["--intrinsics", "120,120,80,60"], ["--camera-info", str(yaml)])):
        code, _, err = run(["analyze", str(rec), *opt, "--out", str(tmp_path / f"o{i}")], capsys)
        assert code == 0, err


def test_realsense_layout_pairs_info_with_image() -> None:
    infos = ["/device_0/sensor_0/Depth_0/info/camera_info",
             "/device_0/sensor_1/Color_0/info/camera_info"]
    assert camera_info_topic_for("/device_0/sensor_1/Color_0/image/data", infos) == infos[1]


def test_an_unwritable_out_is_refused_before_reading(
        rec: Path, tmp_path: Path, never_read: None, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """The probe is what decides (a permission check would lie for root and ACLs)."""
    import frontdiag.output

    def denied(*a: object, **k: object) -> None:
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(frontdiag.output.tempfile, "mkstemp", denied)
    code, _, err = run(["analyze", str(rec), "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and "Permission denied" in _one_error_line(err)
