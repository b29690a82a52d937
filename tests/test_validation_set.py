"""The real-data validation set's build and scoring scripts (validation/).

The recordings themselves are not in the repository: the build is tested on tiny images this
test writes; one test scores two built recordings when /work/valdata is there.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from frontdiag.errors import ConfigError  # noqa: E402
from frontdiag.io.readers import open_recording  # noqa: E402
from frontdiag.scoring import (  # noqa: E402
    ConditionScore,
    EvalReport,
    format_pooled,
    pool,
    read_labels,
    score,
)
from validation import build  # noqa: E402

VALDATA = Path("/work/valdata")


def _texture(seed: int, w: int = 96, h: int = 64) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return cv2.resize(rng.integers(0, 255, (h // 4, w // 4), dtype=np.uint8), (w, h),
                      interpolation=cv2.INTER_NEAREST)


def _source_tree(tmp: Path) -> dict:
    """A plain-file 'repository' owner/name with 4 PNG frames and a times file."""
    base = tmp / "src" / "owner+name"
    (base / "seq").mkdir(parents=True, exist_ok=True)
    files = []
    for i in range(4):
        ok, buf = cv2.imencode(".png", _texture(i))
        assert ok
        p = base / "seq" / f"{1000 + i}.000000500.png"
        p.write_bytes(buf.tobytes())
        files.append({"path": f"seq/{p.name}",
                      "sha256": hashlib.sha256(buf.tobytes()).hexdigest()})
    (base / "times.txt").write_text("0.0\n0.1\n0.25\n0.3\n")
    cam = {"fx": 80.0, "fy": 80.0, "cx": 48.0, "cy": 32.0}
    recs = [
        {"name": "seq_bag", "source": "s", "split": "dev", "container": "bag",
         "encoding": "mono8", "frames": {"files": files},
         "stamps": {"kind": "filename_seconds"}, "camera": cam,
         "labels": [[1, 2, "pure_rotation"], [3, 3, "healthy"]]},
        {"name": "seq_db3", "source": "s", "split": "report", "container": "ros2-db3",
         "encoding": "source", "frames": {"files": files},
         "stamps": {"kind": "times_txt", "path": "times.txt", "t0_ns": 5_000_000_000},
         "camera": cam, "labels": [[0, 3, "healthy"]]},
    ]
    return {"version": 1, "sources": {"s": {"repo": "owner/name", "commit": "0" * 40}},
            "recordings": recs}


def _write(tmp: Path, manifest: dict) -> Path:
    p = tmp / "manifest.json"
    p.write_text(json.dumps(manifest))
    return p


def test_build_writes_containers_and_labels_in_header_stamps(tmp_path: Path) -> None:
    m = _write(tmp_path, _source_tree(tmp_path))
    out = tmp_path / "out"
    assert build.main(["--src", str(tmp_path / "src"), "--out", str(out),
                       "--manifest", str(m)]) == 0
    bag = out / "dev" / "seq_bag.bag"
    db3 = out / "report" / "seq_db3"
    assert bag.is_file() and (db3 / "metadata.yaml").is_file()
    # filename stamps are parsed exactly (no float rounding of 1000.000000500 s)
    lab = read_labels(out / "dev" / "seq_bag.bag.labels.csv")
    assert list(lab.itertuples(index=False, name=None)) == [
        (1001_000000500, 1002_000000500, "pure_rotation"),
        (1003_000000500, 1003_000000500, "healthy")]
    lab2 = read_labels(out / "report" / "seq_db3.labels.csv")
    assert lab2.iloc[0].tolist() == [5_000_000_000, 5_300_000_000, "healthy"]
    # the container holds one image and one CameraInfo per frame, stamped as labelled
    with open_recording(bag) as rec:
        topics = {t.topic: t.count for t in rec.topics}
    assert topics == {"/camera/image_raw": 4, "/camera/camera_info": 4}


def test_build_refuses_changed_source_and_bad_labels(tmp_path: Path) -> None:
    man = _source_tree(tmp_path)
    man["recordings"][0]["frames"]["files"][2]["sha256"] = "f" * 64
    with pytest.raises(ConfigError, match="sha256"):
        build.main(["--src", str(tmp_path / "src"), "--out", str(tmp_path / "o"),
                    "--manifest", str(_write(tmp_path, man)), "--only", "seq_bag"])
    man = _source_tree(tmp_path)
    man["recordings"][1]["labels"] = [[2, 4, "healthy"]]  # 4 frames: 0..3
    with pytest.raises(ConfigError, match="outside"):
        build.load_manifest(_write(tmp_path, man))
    man["recordings"][1]["labels"] = [[0, 1, "standing_still"]]
    with pytest.raises(ConfigError, match="unknown condition"):
        build.load_manifest(_write(tmp_path, man))
    man["recordings"][1]["labels"] = []
    man["recordings"][1]["split"] = "test"
    with pytest.raises(ConfigError, match="split"):
        build.load_manifest(_write(tmp_path, man))


def test_fill_hashes_adds_only_missing(tmp_path: Path) -> None:
    man = _source_tree(tmp_path)
    want = man["recordings"][0]["frames"]["files"][0]["sha256"]
    for rec in man["recordings"]:
        for e in rec["frames"]["files"]:
            e.pop("sha256", None)
    n = build.fill_hashes(man, tmp_path / "src")
    assert n == 4 + 1  # the shared file list once, and the second recording's times.txt
    assert man["recordings"][0]["frames"]["files"][0]["sha256"] == want
    assert build.fill_hashes(man, tmp_path / "src") == 0


def test_the_committed_manifest_is_consistent() -> None:
    m = build.load_manifest()
    names = [r["name"] for r in m["recordings"]]
    assert len(names) == len(set(names))
    for rec in m["recordings"]:
        entries = [rec["frames"]] if rec["frames"].get("kind") == "video" \
            else rec["frames"]["files"]
        assert all(len(e.get("sha256", "")) == 64 for e in entries), rec["name"]
        assert m["sources"][rec["source"]]["licence"]
        assert len(m["sources"][rec["source"]]["commit"]) == 40


def _cs(cond: str, **kw: int) -> ConditionScore:
    base = dict.fromkeys(("episodes", "episodes_found", "frames_labelled", "frames_flagged",
                          "true_positives", "false_positives", "healthy_frames",
                          "false_alarms"), 0)
    base.update(kw)
    return ConditionScore(cond, ("camera",), **base)


def test_pool_sums_counts_and_recomputes_ratios() -> None:
    a = EvalReport([_cs("pure_rotation", episodes=1, episodes_found=1, frames_labelled=10,
                        true_positives=9, false_positives=1, healthy_frames=20,
                        false_alarms=1)], frames=30, labelled_frames=30, healthy_frames=20,
                   false_alarms=1)
    b = EvalReport([_cs("feature_clustering", episodes=2, frames_labelled=4),
                    _cs("pure_rotation", episodes=1, frames_labelled=30, true_positives=3,
                        false_positives=3, healthy_frames=10)],
                   frames=40, labelled_frames=34, healthy_frames=10, false_alarms=0)
    p = pool([a, b])
    assert [c.condition for c in p.conditions] == ["feature_clustering", "pure_rotation"]
    rot = p.conditions[1]
    assert (rot.episodes, rot.episodes_found, rot.frames_labelled) == (2, 1, 40)
    assert rot.precision == pytest.approx(12 / 16)
    assert rot.recall == pytest.approx(12 / 40)
    assert (p.frames, p.healthy_frames, p.false_alarms) == (70, 30, 1)
    text = format_pooled(p)
    assert "pure_rotation" in text and "1/2" in text and "1/30" in text


def test_pool_of_one_scored_recording_equals_its_report() -> None:
    frames = pd.DataFrame({"t_ns": np.arange(10), "conditions": [[]] * 5 + [["exposure_step"]] * 5})
    labels = pd.DataFrame({"t_start_ns": [0, 5], "t_end_ns": [4, 9],
                           "condition": ["healthy", "exposure_step"]})
    rep = score(frames, labels)
    assert pool([rep]).as_dict() == rep.as_dict()


@pytest.mark.skipif(not (VALDATA / "dev" / "weir_panorama.mcap").exists(),
                    reason="validation recordings not built (python validation/build.py)")
def test_score_built_recordings() -> None:
    from validation import score as vscore

    m = build.load_manifest()
    by = {r["name"]: r for r in m["recordings"]}
    for name in ("weir_panorama", "pencil_left"):
        rep = vscore.score_recording(build.output_path(VALDATA, by[name]))
        labelled = {c for _, _, c in by[name]["labels"]} - {"healthy"}
        got = {c.condition: c for c in rep.conditions}
        for cond in labelled:
            want = sum(1 for *_, c in by[name]["labels"] if c == cond)
            assert got[cond].episodes == want, (name, cond)
        assert rep.frames == build.expected_frames(by[name])


@pytest.mark.skipif(not (VALDATA / "dev" / "udacity_highway.bag").exists(),
                    reason="validation recordings not built (python validation/build.py)")
def test_score_reads_a_recording_at_half_resolution(capsys) -> None:
    """--downscale reaches the frontend: the highway's pictures are read at 480x270 (its frames
    all scored), and the table says so."""
    from validation import score as vscore

    assert vscore.main(["--only", "udacity_highway", "--downscale", "2"]) == 0
    out = capsys.readouterr().out
    assert "1 recordings, 110 frames, pictures shrunk 2x" in out
    from frontdiag.api import analyze

    df = analyze(VALDATA / "dev" / "udacity_highway.bag", downscale=2, max_frames=2)
    assert set(df["width"]) == {480} and set(df["height"]) == {270}


@pytest.mark.skipif(shutil.which("git") is None, reason="git not installed")
@pytest.mark.parametrize("bare", [True, False])
def test_source_reads_a_git_directory_at_the_manifest_commit(tmp_path: Path, bare: bool) -> None:
    work = tmp_path / "w"
    work.mkdir()
    (work / "a.txt").write_text("first\n")
    git = ["git", "-C", str(work), "-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run([*git, "init", "-q"], check=True)
    subprocess.run([*git, "add", "a.txt"], check=True)
    subprocess.run([*git, "commit", "-qm", "one"], check=True)
    first = subprocess.run([*git, "rev-parse", "HEAD"], check=True, capture_output=True,
                           text=True).stdout.strip()
    (work / "a.txt").write_text("second\n")
    subprocess.run([*git, "commit", "-qam", "two"], check=True)
    root = tmp_path / "src"
    (root / "o+n").mkdir(parents=True)
    if bare:
        subprocess.run(["git", "clone", "-q", "--bare", str(work), str(root / "o+n" / "repo")],
                       check=True)
    else:
        shutil.copytree(work, root / "o+n" / "repo")
    src = build.Source("o/n", first, root)
    assert src.read("a.txt") == b"first\n"
    with pytest.raises(ConfigError, match=r"cannot read missing\.txt"):
        src.read("missing.txt")
    with pytest.raises(ConfigError, match="not found"):
        build.Source("o/other", first, root).read("a.txt")


def test_build_checks_the_output_directory_before_reading_sources(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    m = _write(tmp_path, _source_tree(tmp_path))
    with pytest.raises(ConfigError, match="cannot write to --out"):
        build.main(["--src", str(tmp_path / "nowhere"), "--out", str(blocker / "out"),
                    "--manifest", str(m)])


@pytest.mark.parametrize("gain", [0.8, 1.0, 1.17])
def test_label_aid_reads_the_gain_between_two_views(gain: float) -> None:
    """The exposure labels' aid reads the brightness ratio of the same surfaces: a textured
    view whose two halves move by different shifts (two depths, so that a fundamental matrix
    is defined), scaled by a known gain, reads that gain."""
    from validation import label_aid

    rng = np.random.default_rng(3)
    base = cv2.GaussianBlur(rng.uniform(0, 1, (480, 640)).astype(np.float32), (0, 0), 2.0)
    base = 40 + 160 * (base - base.min()) / (base.max() - base.min())
    a = np.clip(base, 0, 255).astype(np.uint8)
    shifted = np.vstack([np.roll(base, (5, 9), axis=(0, 1))[:240],
                         np.roll(base, (5, 2), axis=(0, 1))[240:]])
    b = np.clip(shifted * gain, 0, 255).astype(np.uint8)
    ratio, n = label_aid.pair_ratio(a, b)
    assert n >= 30
    assert ratio == pytest.approx(gain, abs=0.02)


def test_label_aid_leaves_out_clipped_patches() -> None:
    """With lines that saturate in both frames across most of the view, a gain of 1.10 reads
    1.10 with the patches touching them left out (the default) and low when they are kept
    (`--with-clipped`: their clipped pixels stay at 255)."""
    from validation import label_aid

    rng = np.random.default_rng(5)
    base = cv2.GaussianBlur(rng.uniform(0, 1, (480, 640)).astype(np.float32), (0, 0), 2.0)
    base = 40 + 150 * (base - base.min()) / (base.max() - base.min())
    base[:300:8, :] = 400.0  # bright lines over the top of the view: saturated in both frames
    a = np.clip(base, 0, 255).astype(np.uint8)
    shifted = np.vstack([np.roll(base, (5, 9), axis=(0, 1))[:240],
                         np.roll(base, (5, 2), axis=(0, 1))[240:]])
    b = np.clip(shifted * 1.10, 0, 255).astype(np.uint8)
    kept, n = label_aid.pair_ratio(a, b, unclipped=False)
    left_out, n2 = label_aid.pair_ratio(a, b)
    assert n >= 30 and n2 == n
    assert left_out == pytest.approx(1.10, abs=0.02)
    assert kept < left_out - 0.01
    # where fewer than MIN_UNCLIPPED patches are free of clipping, every patch is read: a
    # view saturated almost everywhere gives the same reading either way
    base[:470:2, :] = 400.0
    a = np.clip(base, 0, 255).astype(np.uint8)
    shifted = np.vstack([np.roll(base, (5, 9), axis=(0, 1))[:240],
                         np.roll(base, (5, 2), axis=(0, 1))[240:]])
    b = np.clip(shifted * 1.10, 0, 255).astype(np.uint8)
    assert label_aid.pair_ratio(a, b) == label_aid.pair_ratio(a, b, unclipped=False)


def test_label_aid_check_names_each_kind_of_disagreement() -> None:
    """`label_aid.py --check`: a step the labels miss, a step label under the 10 % line, a
    healthy label at 6 % or more; agreement, an unlabelled 6-10 % frame and a frame without a
    reading (too few matches) say nothing."""
    from validation import label_aid

    rec = {"labels": [[0, 3, "healthy"], [4, 4, "exposure_step"], [5, 5, "healthy"],
                      [6, 6, "exposure_step"]]}
    ratios = [(1, 1.01, 500), (2, 1.12, 500), (3, 1.07, 500), (4, 1.15, 500), (5, 0.95, 500),
              (6, 1.08, 500), (7, 1.08, 500), (8, 1.30, 10)]
    out = label_aid.label_disagreements(rec, ratios)
    assert out == ["frame 2: +12.0%, a step, labelled ['healthy']",
                   "frame 3: +7.0%, labelled healthy",
                   "frame 6: +8.0%, under the step line, labelled exposure_step"]


@pytest.mark.skipif(not (VALDATA / "dev" / "zed_lab").exists(),
                    reason="validation recordings not built (python validation/build.py)")
def test_a_hand_held_walk_at_30_hz_is_not_read_as_rotation() -> None:
    """The dev half's hand-held ZED2: keyframe intervals of 1-4 frames fit a rotation within
    the noise, but over 0.33 s the camera's translation shows (FD-ROT-001's span reading), so
    none of its healthy frames reads pure_rotation; the fixed camera over people walking still
    reads standing still on every frame."""
    from validation import score as vscore

    m = build.load_manifest()
    by = {r["name"]: r for r in m["recordings"]}
    rep = vscore.score_recording(build.output_path(VALDATA, by["zed_lab"]))
    rot = next(c for c in rep.conditions if c.condition == "pure_rotation")
    assert rot.healthy_frames == 71 and rot.false_alarms == 0
    still = vscore.score_recording(build.output_path(VALDATA, by["people_fixed_camera"]))
    rot = next(c for c in still.conditions if c.condition == "pure_rotation")
    assert rot.episodes_found == rot.episodes == 1 and rot.recall == 1.0


@pytest.mark.skipif(not (VALDATA / "dev" / "bracket_night_street.mcap").exists(),
                    reason="validation recordings not built (python validation/build.py)")
def test_a_black_night_street_is_a_detection_failure() -> None:
    """The dev half's night-street bracket: the last two shots are black (under 1 % of the
    pixels above 20 grey levels) yet keep 730-778 features from lamps and noise; FD-DET-003
    reads them, and none of the eight shots before them."""
    from frontdiag.api import analyze

    m = build.load_manifest()
    rec = next(r for r in m["recordings"] if r["name"] == "bracket_night_street")
    frames = analyze(build.output_path(VALDATA, rec))
    black = frames["rules"].map(lambda r: "FD-DET-003" in r).tolist()
    assert black == [False] * 8 + [True] * 2
    assert (frames["keypoint_fill"].iloc[8:] >= 0.3).all()


def test_a_recording_as_h264_video_keeps_its_stamps_and_calibration(tmp_path: Path) -> None:
    """validation/video.py (score.py --video): the same frames as Foxglove CompressedVideo,
    stamped as before (so the labels still apply), with the calibration."""
    from recording_factory import write_recording

    from frontdiag.api import analyze
    from validation.video import to_h264

    src = write_recording(tmp_path / "src.mcap", "mcap", n=12)
    video = to_h264(src, tmp_path / "v.mcap", crf=18, keyint=5)
    a, b = analyze(src), analyze(video)
    assert b["t_ns"].tolist() == a["t_ns"].tolist()
    assert b.attrs["manifest"]["topics"]["camera"] == "/camera/video"
    assert b.attrs["manifest"]["intrinsics"]["K"] == a.attrs["manifest"]["intrinsics"]["K"]
    assert np.abs(b["mean_intensity"] - a["mean_intensity"]).max() < 1.0


def test_stride_labels_read_each_gap_as_a_whole() -> None:
    """At --stride 2 frame k is compared with frame k - 2: a turn or a plane holds only where
    both frames of the gap carry it, a step anywhere in a fully labelled gap is a step, a
    healthy gap is healthy, a frame alone keeps its own single-frame labels, and the first row
    keeps only those and healthy. Runs of the same label are one episode."""
    from validation.score import stride_labels

    rec = {"labels": [[0, 3, "healthy"], [4, 4, "exposure_step"], [5, 7, "healthy"],
                      [8, 12, "pure_rotation"], [9, 9, "feature_clustering"],
                      [13, 13, "planar_degeneracy"]]}
    frames = pd.DataFrame({"frame": [0, 2, 4, 6, 8, 10, 12, 14],
                           "t_ns": [100 * k for k in (0, 2, 4, 6, 8, 10, 12, 14)]})
    got = stride_labels(rec, frames, 2)
    want = [(0, 200, "healthy"),            # frame 0 (first row), frame 2 (gap 1-2 healthy)
            (400, 400, "exposure_step"),    # gap 3-4: healthy then a step
            (600, 600, "healthy"),          # gap 5-6
            (1000, 1200, "pure_rotation")]  # gaps 9-10 and 11-12; gap 7-8 is half healthy
    assert list(got.itertuples(index=False, name=None)) == want
    # frame 9's clustering is a frame alone: it is read only where frame 9 is analysed
    odd = stride_labels(rec, pd.DataFrame({"frame": [1, 3, 5, 7, 9, 11, 13],
                                           "t_ns": [1, 3, 5, 7, 9, 11, 13]}), 2)
    conds = {c: (a, b) for a, b, c in odd.itertuples(index=False, name=None)}
    assert conds["feature_clustering"] == (9, 9)
    assert conds["pure_rotation"] == (9, 11)  # gaps 8-9 and 10-11
    assert "planar_degeneracy" not in conds    # gap 12-13: rotation, then a plane


def test_stride_labels_measure_the_exposure_of_each_gap_on_the_pair() -> None:
    """Where the manifest lists the label aid's brightness ratios across each gap, the README's
    criterion is read on the pair: a ramp of healthy frames 12 % over the gap is a step, 8 %
    is neither a step nor healthy, an unlisted gap (under 6 %) of healthy frames is healthy, and
    a step undone within its gap is no step; a pair with no reading falls back on the frames'
    own labels."""
    from validation.score import stride_labels

    rec = {"labels": [[0, 11, "healthy"], [12, 12, "exposure_step"], [13, 15, "healthy"]],
           "gap_brightness": {"2": [[4, 1.12], [6, 0.92], [8, None]]}}
    frames = pd.DataFrame({"frame": list(range(0, 16, 2)), "t_ns": list(range(0, 16, 2))})
    got = list(stride_labels(rec, frames, 2).itertuples(index=False, name=None))
    assert got == [(0, 2, "healthy"),          # frame 0 (first row), gap 1-2 unlisted
                   (4, 4, "exposure_step"),    # gap 3-4: healthy frames, 12 % brighter
                   (8, 10, "healthy"),         # gap 5-6 at 8 %: neither; 7-8 no reading
                   (14, 14, "healthy")]        # gap 13-14
    # gap 11-12 is unlisted (under 6 %): the step labelled at frame 12 does not show across
    # the pair, and the gap is not all healthy either, so frame 12 carries nothing
    assert all(c != "exposure_step" or a != 12 for a, _, c in got)
    # without measurements for this stride the frames' own labels decide, as before
    del rec["gap_brightness"]
    old = list(stride_labels(rec, frames, 2).itertuples(index=False, name=None))
    assert (12, 12, "exposure_step") in old and (4, 4, "exposure_step") not in old
