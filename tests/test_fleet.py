"""Fleet runs: one result folder per recording, a summary, resume, errors, Dask."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest
from recording_factory import write_recording

from frontdiag.api import AnalysisOptions
from frontdiag.cli import main
from frontdiag.fleet import (
    SUMMARY_COLUMNS,
    discover,
    largest_first,
    plan_tasks,
    run_dask,
    run_local,
)

STABLE = [c for c in SUMMARY_COLUMNS if c not in ("seconds", "status", "path")]


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("logs")
    for i in range(3):
        write_recording(d / f"r{i}.mcap", "mcap", n=12, seed=i, shift=1 + i)
    (d / "bad.mcap").write_bytes(b"not a recording")
    return d


def _summary(out: Path) -> pd.DataFrame:
    return pd.read_parquet(out / "fleet_summary.parquet")


def test_fleet_cli_writes_a_folder_each_resumes_and_reports_the_bad_one(
        logs: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    code = main(["analyze", str(logs), "--out", str(out), "--jobs", "2", "--json"])
    assert code == 2  # the bad recording: the worst exit code
    doc = json.loads(capsys.readouterr().out)
    by = {r["recording"]: r for r in doc["recordings"]}
    assert set(by) == {"bad", "r0", "r1", "r2"}
    assert by["bad"]["status"] == "error" and "unknown container" in by["bad"]["error"]
    for name in ("r0", "r1", "r2"):
        assert by[name]["status"] == "ok" and by[name]["frames"] == 12
        assert by[name]["coverage"] == 1.0
        assert by[name]["ok"] + by[name]["warn"] + by[name]["fail"] == 12
        assert (out / name / "frames.parquet").exists()
        assert (out / name / "episodes.parquet").exists()
        assert by[name]["exit_code"] in (0, 1)
        frames = pd.read_parquet(out / name / "frames.parquet")
        lost = frames["status"].isin(["too_few_matches", "essential_failed", "no_features"])
        assert by[name]["no_pose"] == int(lost.sum())
    summary = _summary(out)
    assert list(summary.columns) == SUMMARY_COLUMNS and len(summary) == 4
    # a second run skips the current results; a changed recording is analysed again
    write_recording(logs / "r1.mcap", "mcap", n=14, seed=1)
    code = main(["analyze", str(logs / "r*.mcap"), "--out", str(out), "--json"])
    by2 = {r["recording"]: r for r in json.loads(capsys.readouterr().out)["recordings"]}
    assert [by2[n]["status"] for n in ("r0", "r1", "r2")] == ["skipped", "ok", "skipped"]
    assert by2["r1"]["frames"] == 14
    assert code == max(by2[n]["exit_code"] for n in by2)
    for n in ("r0", "r2"):
        assert {k: by2[n][k] for k in STABLE} == {k: by[n][k] for k in STABLE}


def test_discover_reads_folders_and_globs(logs: Path) -> None:
    assert [p.name for p in discover([logs])] == ["bad.mcap", "r0.mcap", "r1.mcap", "r2.mcap"]
    assert [p.name for p in discover([str(logs / "r[02].mcap")])] == ["r0.mcap", "r2.mcap"]
    with pytest.raises(Exception, match="no such file"):
        discover([logs / "nope*.mcap"])


def test_a_folder_of_separate_bags_is_a_fleet_and_split_parts_are_one_recording(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`rosbag record --split` names its parts NAME_0.bag, NAME_1.bag, ...: such a folder is one
    recording read end to end. A folder of differently named bags, or of bags beside other
    recordings, holds separate recordings: each is analysed on its own (it was read as one
    chain before)."""
    from frontdiag.errors import RecordingError
    from frontdiag.io.readers import plan, split_parts

    split = tmp_path / "split"
    split.mkdir()
    write_recording(split / "run_2024-05-01_0.bag", "bag", n=6)
    write_recording(split / "run_2024-05-01_1.bag", "bag", n=6, seed=1)
    (split / "notes.txt").write_text("not a recording")
    assert split_parts(split) and discover([split]) == [split.resolve()]
    killed = tmp_path / "killed"  # the recorder was killed while writing the third part
    killed.mkdir()
    for i in range(3):
        write_recording(killed / f"run_{i}.bag", "bag", n=4, seed=i)
    (killed / "run_2.bag").rename(killed / "run_2.bag.active")
    assert split_parts(killed) and discover([killed]) == [killed.resolve()]
    assert [f.name for f in plan(killed).files] == ["run_0.bag", "run_1.bag", "run_2.bag.active"]
    assert [f.name for f in plan(split).files] == ["run_2024-05-01_0.bag", "run_2024-05-01_1.bag"]

    fleet = tmp_path / "fleet"
    fleet.mkdir()
    write_recording(fleet / "aisle.bag", "bag", n=6)
    write_recording(fleet / "dock.bag", "bag", n=6, seed=1)
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    write_recording(mixed / "run_0.bag", "bag", n=6)
    write_recording(mixed / "other.mcap", "mcap", n=6)
    gap = tmp_path / "gap"
    gap.mkdir()
    write_recording(gap / "run_0.bag", "bag", n=6)
    write_recording(gap / "run_2.bag", "bag", n=6)
    for folder, names in ((fleet, ["aisle.bag", "dock.bag"]),
                          (mixed, ["other.mcap", "run_0.bag"]), (gap, ["run_0.bag", "run_2.bag"])):
        assert not split_parts(folder)
        assert [p.name for p in discover([folder])] == names
        with pytest.raises(RecordingError, match="separate recordings"):
            plan(folder)
    out = tmp_path / "out"
    assert main(["analyze", str(fleet), "--out", str(out)]) in (0, 1)
    assert sorted(_summary(out)["recording"]) == ["aisle", "dock"]
    assert (out / "aisle" / "frames.parquet").exists()
    capsys.readouterr()
    assert main(["analyze", str(fleet)]) == 2  # several recordings need --out
    assert "--out" in capsys.readouterr().err
    # the fleet's --out folder handed to a command that reads one result: say which to pass
    (fleet / "labels.csv").write_text("t_start_ns,t_end_ns,condition\n")
    # a glob (or the shell's logs/*) also catches side files: left out, and said so
    skipped: list[Path] = []
    assert [p.name for p in discover([str(fleet / "*")], skipped)] == ["aisle.bag", "dock.bag"]
    assert [p.name for p in skipped] == ["labels.csv"]
    assert main(["analyze", str(fleet / "*"), "--out", str(out)]) in (0, 1)
    assert "left out 1 file(s) that are not recordings: labels.csv" in capsys.readouterr().err
    for cmd in (["explain", str(out), "--frame", "1"], ["analyze", str(fleet / "aisle.bag"),
                                                          "--baseline", str(out)]):
        assert main(cmd) == 2
        err = capsys.readouterr().err
        assert "fleet run's folder (2 recordings)" in err and str(out / "aisle") in err, cmd
    # eval reads a fleet's folder itself (each recording against its own labels): none here
    assert main(["eval", str(out)]) == 2
    assert "no recording of this fleet has labels beside it" in capsys.readouterr().err


def test_the_largest_recordings_are_handed_out_first(tmp_path: Path) -> None:
    # longest-processing-time first: a large recording started last would run alone at the end
    d = tmp_path / "in"
    d.mkdir()
    for name, n in (("a", 6), ("b", 20), ("c", 6), ("d", 12)):
        write_recording(d / f"{name}.mcap", "mcap", n=n, seed=1)
    write_recording(d / "e", "ros2-db3", n=30, seed=1)  # a bag folder: the files inside it
    tasks = plan_tasks([d / "a.mcap", d / "b.mcap", d / "c.mcap", d / "d.mcap", d / "e"],
                       tmp_path / "out", AnalysisOptions())
    order = largest_first(tasks)
    assert [tasks[i].out.name for i in order] == ["e", "b", "d", "a", "c"]  # a, c: equal sizes
    # handed out in that order, the rows still come back in the order of the recordings
    rows = run_local(tasks, jobs=2)
    assert [r["recording"] for r in rows] == ["a", "b", "c", "d", "e"]


def test_dask_local_cluster_gives_the_local_summary(logs: Path, tmp_path: Path) -> None:
    pytest.importorskip("dask.distributed")
    opts = AnalysisOptions()
    local = run_local(plan_tasks([logs], tmp_path / "a", opts), jobs=1)
    dask = run_dask(plan_tasks([logs], tmp_path / "b", opts), "local", 2,
                    cluster_kwargs={"processes": False})
    assert [{k: r[k] for k in STABLE} for r in dask] == \
        [{k: r[k] for k in STABLE} for r in local]
    a = pd.read_parquet(tmp_path / "a" / "r0" / "frames.parquet")
    b = pd.read_parquet(tmp_path / "b" / "r0" / "frames.parquet")
    cols = [c for c in a.columns if not c.startswith("ms_")]
    pd.testing.assert_frame_equal(a[cols], b[cols])


def test_ctrl_c_stops_the_fleet_and_keeps_what_was_done(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from frontdiag.camera import frontend

    logs = tmp_path / "logs"
    logs.mkdir()
    for i in range(3):
        write_recording(logs / f"r{i}.mcap", "mcap", n=12, seed=i, shift=1 + i)
    real = frontend.CameraFrontend.process
    calls = {"n": 0}

    def process(self, frame):  # type: ignore[no-untyped-def]
        calls["n"] += 1
        if calls["n"] == 12 + 5:  # the 5th frame of the second recording
            raise KeyboardInterrupt
        return real(self, frame)

    monkeypatch.setattr(frontend.CameraFrontend, "process", process)
    out = tmp_path / "out"
    code = main(["analyze", str(logs), "--out", str(out), "--jobs", "1", "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert code == 130 and doc["exit_code"] == 130
    assert doc["interrupted"] is True and doc["not_analysed"] == 1
    by = {r["recording"]: r for r in doc["recordings"]}
    assert set(by) == {"r0", "r1"}  # r2 was never started
    assert by["r0"]["status"] == "ok" and by["r0"]["frames"] == 12
    assert by["r1"]["error"] == "interrupted" and by["r1"]["gate"] == "incomplete"
    assert 0 < by["r1"]["frames"] < 12  # the frames before Ctrl-C were kept
    assert len(_summary(out)) == 2
    assert not (out / "r2" / "frames.parquet").exists()
    # the same command again goes on: r0 skipped, r1 analysed again, r2 analysed
    monkeypatch.setattr(frontend.CameraFrontend, "process", real)
    code = main(["analyze", str(logs), "--out", str(out), "--jobs", "1", "--json"])
    doc = json.loads(capsys.readouterr().out)
    by = {r["recording"]: r for r in doc["recordings"]}
    assert doc["interrupted"] is False and code in (0, 1)
    assert [by[n]["status"] for n in ("r0", "r1", "r2")] == ["skipped", "ok", "ok"]
    assert by["r1"]["frames"] == 12


def test_eval_of_a_fleet_scores_each_recording_against_its_labels_and_pools_them(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`frontdiag eval FLEET_OUT`: each recording against the labels beside it, pooled by
    summing counts (a long recording weighs by its frames); recordings without labels are
    listed, not scored. Every condition is scored on every recording, so a condition's false
    alarms count all healthy frames of the fleet."""
    import jsonschema

    from frontdiag.scoring import pool, read_frames, read_labels, score

    logs = tmp_path / "logs"
    logs.mkdir()
    for i, n in enumerate((10, 14, 8)):
        write_recording(logs / f"r{i}.mcap", "mcap", n=n, seed=i, shift=1 + i)
    from recording_factory import DT, T0

    (logs / "r0.mcap.labels.csv").write_text(
        f"t_start_ns,t_end_ns,condition\n{T0},{T0 + 9 * DT},healthy\n")
    (logs / "r1.mcap.labels.csv").write_text(
        f"t_start_ns,t_end_ns,condition\n{T0 + DT},{T0 + 13 * DT},healthy\n"
        f"{T0 + 5 * DT},{T0 + 7 * DT},exposure_step\n")
    out = tmp_path / "out"
    assert main(["analyze", str(logs), "--out", str(out)]) in (0, 1)
    capsys.readouterr()
    code = main(["eval", str(out), "--json"])
    doc = json.loads(capsys.readouterr().out)
    schema = json.loads((Path(__file__).resolve().parents[1] / "docs" / "schemas" /
                         "eval.json").read_text())
    jsonschema.Draft202012Validator(schema).validate(doc)
    assert [r["recording"] for r in doc["recordings"]] == ["r0", "r1"]
    assert doc["not_scored"] == ["r2 (no r2.mcap.labels.csv beside it)"]
    singles = [score(read_frames(out / n), read_labels(logs / f"{n}.mcap.labels.csv"))
               for n in ("r0", "r1")]
    pooled = pool(singles)
    assert doc["healthy_frames"] == pooled.healthy_frames == 10 + 13 - 3
    assert doc["false_alarms"] == pooled.false_alarms
    exp = next(c for c in doc["conditions"] if c["condition"] == "exposure_step")
    assert exp["episodes"] == 1 and exp["healthy_frames"] == doc["healthy_frames"]
    assert code == (1 if doc["gate"]["reasons"] else 0)
    assert main(["eval", str(out), "--min-recall", "1.1"]) == 2  # a share is checked first
    capsys.readouterr()
    assert main(["eval", str(out), "--labels", str(logs / "r0.mcap.labels.csv")]) == 2
    assert "each recording is scored against its own" in capsys.readouterr().err
    assert main(["eval", str(out)]) in (0, 1)
    text = capsys.readouterr().out
    assert "against the labels of 2 recordings (pooled)" in text
    assert "not scored: r2 (no r2.mcap.labels.csv beside it)" in text


def test_report_of_a_fleet_writes_an_index_and_a_page_each(
        logs: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`frontdiag report FLEET_OUT`: NAME/report.html for every finished recording and one
    index page linking them, a row per recording (the bad one without a link); names are
    HTML-escaped."""
    odd = tmp_path / "odd"
    odd.mkdir()
    write_recording(odd / "a<b>&c.mcap", "mcap", n=8)
    out = tmp_path / "out"
    main(["analyze", str(logs), str(odd / "a<b>&c.mcap"), "--out", str(out)])
    capsys.readouterr()
    assert main(["report", str(out), "--no-thumbnails"]) == 0
    assert "over 4 recordings" in capsys.readouterr().out
    page = (out / "index.html").read_text()
    for name in ("r0", "r1", "r2"):
        assert (out / name / "report.html").stat().st_size > 10_000
        assert f"<a href='{name}/report.html'>{name}</a>" in page
    assert "<td>bad<br>" in page and "unknown container" in page  # listed, not linked
    assert "a&lt;b&gt;&amp;c" in page and "a<b>" not in page
    assert main(["report", str(out), "--target", "orin-nano"]) == 2
    assert "fleet run's folder" in capsys.readouterr().err


def test_junit_of_a_fleet_has_one_suite_per_recording(logs: Path, tmp_path: Path) -> None:
    """`analyze logs/ --out OUT --junit fleet.xml`: one test suite per recording, each the one
    `--junit` writes for that recording alone; the recording that could not be analysed is a
    suite with an error case; the totals are the suites' sums. The file is checked before
    anything is analysed."""
    import xml.etree.ElementTree as ET

    out, xml = tmp_path / "out", tmp_path / "fleet.xml"
    code = main(["analyze", str(logs), "--out", str(out), "--junit", str(xml), "-q"])
    assert code == 2  # the bad recording
    root = ET.parse(xml).getroot()
    suites = {s.get("name"): s for s in root.findall("testsuite")}
    assert set(suites) == {"bad", "r0", "r1", "r2"}
    bad = suites["bad"].find("testcase/error")
    assert bad is not None and "unknown container" in bad.get("message", "")
    alone = tmp_path / "r0.xml"
    main(["analyze", str(logs / "r0.mcap"), "--junit", str(alone), "-q"])
    single = ET.parse(alone).getroot().find("testsuite")
    assert single is not None
    assert [c.get("name") for c in suites["r0"]] == [c.get("name") for c in single]
    for k in ("tests", "failures", "errors", "skipped"):
        assert int(root.get(k)) == sum(int(s.get(k)) for s in suites.values())
    before = (logs / "r1.mcap").read_bytes()
    assert main(["analyze", str(logs), "--out", str(tmp_path / "o2"), "--junit",
                 str(logs / "r1.mcap"), "-q"]) == 2  # would overwrite an input
    assert (logs / "r1.mcap").read_bytes() == before and not (tmp_path / "o2").exists()


def test_info_on_a_folder_lists_one_line_per_recording(
        logs: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`frontdiag info FOLDER` before a fleet run: each recording's reader, duration and chosen
    topics on one line, the unreadable one with its error (exit 2); --json holds each
    recording's own `info` document."""
    import jsonschema

    assert main(["info", str(logs)]) == 2
    text = capsys.readouterr().out
    assert "4 recordings" in text and "/cam/image_raw (20.0)" in text
    assert "unknown container" in text
    assert main(["info", str(logs), "--json"]) == 2
    doc = json.loads(capsys.readouterr().out)
    schema = json.loads((Path(__file__).resolve().parents[1] / "docs" / "schemas" /
                         "info-fleet.json").read_text())
    jsonschema.Draft202012Validator(schema).validate(doc)
    assert [Path(r["path"]).name for r in doc["recordings"]] == ["r0.mcap", "r1.mcap", "r2.mcap"]
    assert [Path(e["path"]).name for e in doc["errors"]] == ["bad.mcap"]
    assert doc["recordings"][0]["analyze_would_use"]["camera"] == "/cam/image_raw"


def test_the_console_summary_says_how_many_were_skipped_and_only_when_some_were(
        tmp_path: Path) -> None:
    """The line under the fleet table counts the recordings skipped because their result was
    current and names the flag that analyses them again; a run that skipped none says nothing
    about skipping."""
    from rich.console import Console

    from frontdiag.cli.fleet_ import render_summary

    def row(name: str, status: str) -> dict[str, object]:
        return {"recording": name, "status": status, "frames": 12, "coverage": 1.0, "ok": 12,
                "warn": 0, "fail": 0, "no_pose": 0, "episodes": 0, "gate": "passed",
                "seconds": 0.5}

    def text(rows: list[dict[str, object]]) -> str:
        con = Console(record=True, width=200)
        render_summary(con, rows, tmp_path / "fleet_summary.parquet")
        return con.export_text()

    fresh = text([row("r0", "ok"), row("r1", "ok")])
    assert "skipped" not in fresh and "fleet_summary.parquet" in fresh
    again = text([row("r0", "skipped"), row("r1", "ok"), row("r2", "skipped")])
    assert "2 skipped: their results were current" in again and "--force" in again


def test_a_result_folder_is_not_taken_for_a_recording(
        logs: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # analyze's --out holds diagnostics.mcap, which alone would read as a one-file bag folder
    res = tmp_path / "my run"
    assert main(["analyze", str(logs / "r0.mcap"), "--out", str(res), "-q",
                 "--fail-on", "never"]) == 0
    capsys.readouterr()
    for cmd in (["analyze", str(res)], ["info", str(res)],
                ["analyze", str(res), str(logs / "r1.mcap"), "--out", str(tmp_path / "f")]):
        assert main(cmd) == 2, cmd
        err = " ".join(capsys.readouterr().err.split())
        assert "a frontdiag result folder" in err and "not a recording" in err
        # what to run instead, quoted for the shell, and the recording it came from
        assert f"frontdiag explain '{res}'" in err
        assert f"frontdiag analyze {logs / 'r0.mcap'}" in err
    # a glob that also matches result folders leaves them out, as it does notes and labels
    skipped: list[Path] = []
    assert discover([str(tmp_path / "*"), str(logs / "r1.mcap")], skipped) \
        == [(logs / "r1.mcap").resolve()]
    assert res in skipped
    # a fleet's --out is named as a fleet's results
    fleet_out = tmp_path / "fleet"
    assert main(["analyze", str(logs / "r0.mcap"), str(logs / "r1.mcap"), "--out",
                 str(fleet_out), "-q", "--fail-on", "never"]) == 0
    capsys.readouterr()
    assert main(["analyze", str(fleet_out)]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "a fleet's results" in err and f"frontdiag report {fleet_out}" in err


def test_a_fleet_written_into_its_own_folder_resumes(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    # the folder of recordings holds the results too: it stays a folder of recordings
    d = tmp_path / "runs"
    d.mkdir()
    for i in range(2):
        write_recording(d / f"r{i}.mcap", "mcap", n=8, seed=i, shift=1 + i)
    for _ in range(2):
        assert main(["analyze", str(d), "--out", str(d), "-q", "--fail-on", "never"]) == 0
    capsys.readouterr()
    assert sorted(_summary(d)["recording"]) == ["r0", "r1"]
    assert [p.name for p in discover([d])] == ["r0.mcap", "r1.mcap"]
    # one recording's result written into the same folder: its diagnostics.mcap is not one
    assert main(["analyze", str(d / "r0.mcap"), "--out", str(d), "-q", "--fail-on", "never"]) == 0
    capsys.readouterr()
    assert (d / "diagnostics.mcap").is_file()
    assert [p.name for p in discover([d])] == ["r0.mcap", "r1.mcap"]


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_fleet_reports_each_recordings_frames_as_they_go(tmp_path: Path, jobs: int) -> None:
    """A fleet of a few long recordings shows its frames moving, not only each recording as it
    ends: every recording under way reports its frames analysed against its frames expected,
    never backwards (in a worker, through shared counters read every PROGRESS_POLL_S)."""
    from frontdiag.api import AnalysisOptions
    from frontdiag.fleet import plan_tasks, run_local

    logs = tmp_path / "logs"
    logs.mkdir()
    for i in range(2):
        write_recording(logs / f"r{i}.mcap", "mcap", n=240, seed=i, shift=1 + i)
    tasks = plan_tasks([logs], tmp_path / "out", AnalysisOptions())
    seen: dict[int, list[tuple[int, int | None]]] = {}
    rows = run_local(tasks, jobs, on_frames=lambda i, d, e: seen.setdefault(i, []).append((d, e)))
    assert [r["frames"] for r in rows] == [240, 240]
    assert sorted(seen) == [0, 1]
    for reports in seen.values():
        done = [d for d, _ in reports]
        assert done == sorted(done) and all(e == 240 for _, e in reports)
        assert len([d for d in done if 0 < d < 240]) >= (3 if jobs > 1 else 239)
