"""What a perception engineer looks at: diagnostics.mcap, the HTML report, the annotated frame.

One short simulated recording with a camera and a LiDAR (a blank aisle with one bank of labels:
the camera's keypoints cluster, so there are episodes to draw) is analysed once for the module.
"""

from __future__ import annotations

import collections
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from frontdiag.cli import main
from frontdiag.metrics import METRICS
from frontdiag.report.mcap_ import COLORS, MAX_USED_POINTS


@pytest.fixture(scope="module")
def analysed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    tmp = tmp_path_factory.mktemp("visual")
    rec = tmp / "label_bank.mcap"
    assert main(["simulate", "label_bank", "-o", str(rec), "--seconds", "2.5",
                 "--size", "320x240", "--lidar", "16x360", "-q"]) == 0
    out = tmp / "result"
    assert main(["analyze", str(rec), "--out", str(out), "--fail-on", "never", "-q"]) == 0
    return rec, out


def _decoded(path: Path) -> list[tuple[str, str, int, Any]]:
    """Every message through the mcap package's reader and its ROS 2 decoder."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out = []
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages(
                log_time_order=True):
            out.append((channel.topic, schema.name, message.log_time, decoded))
    return out


def _recording_log_times(rec: Path) -> dict[str, list[int]]:
    from mcap.reader import make_reader

    times: dict[str, list[int]] = collections.defaultdict(list)
    with open(rec, "rb") as fh:
        for _, channel, message in make_reader(fh).iter_messages(log_time_order=True):
            times[channel.topic].append(message.log_time)
    return times


def _stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def test_diagnostics_mcap_decodes_every_channel_on_the_recordings_clock(
        analysed: tuple[Path, Path]) -> None:
    rec, out = analysed
    table = pd.read_parquet(out / "frames.parquet")
    episodes = pd.read_parquet(out / "episodes.parquet")
    msgs = _decoded(out / "diagnostics.mcap")
    by_topic: dict[str, list[tuple[str, int, Any]]] = collections.defaultdict(list)
    for topic, schema, log_time, decoded in msgs:
        by_topic[topic].append((schema, log_time, decoded))
    cams = table[table["sensor"] == "camera"]
    lids = table[table["sensor"] == "lidar"]
    assert len(cams) and len(lids)
    assert len(by_topic["/diagnostics"]) == len(table)
    assert len(by_topic["/frontdiag/camera/metrics"]) == len(cams)
    assert len(by_topic["/frontdiag/lidar/metrics"]) == len(lids)
    assert len(by_topic["/frontdiag/camera/annotations"]) == len(cams)
    assert len(by_topic["/frontdiag/lidar/used_points"]) == len(lids)
    assert 0 < len(by_topic["/frontdiag/lidar/weak_direction"]) <= len(lids)
    assert len(by_topic["/rosout"]) == len(episodes) > 0

    # the recording's clock: log time of the source message, header stamp of the row
    rec_times = _recording_log_times(rec)
    for sensor, rows in (("camera", cams), ("lidar", lids)):
        topic = str(rows["topic"].iloc[0])
        want_log = [rec_times[topic][int(f)] for f in rows["frame"]]
        got = by_topic[f"/frontdiag/{sensor}/metrics"]
        assert [lt for _, lt, _ in got] == want_log
        assert [_stamp_ns(m.header) for _, _, m in got] == rows["t_ns"].tolist()
        assert [int(m.frame) for _, _, m in got] == rows["frame"].tolist()
    ann = by_topic["/frontdiag/camera/annotations"]
    cam_topic = str(cams["topic"].iloc[0])
    assert [lt for _, lt, _ in ann] == [rec_times[cam_topic][int(f)] for f in cams["frame"]]
    # the annotation's stamp is the image's header stamp (how the Image panel pairs them)
    stamps = [int(m.texts[0].timestamp.sec) * 1_000_000_000 + int(m.texts[0].timestamp.nanosec)
              for _, _, m in ann]
    assert stamps == cams["t_ns"].tolist()


def test_diagnostic_status_names_rules_and_carries_every_metric_with_its_unit(
        analysed: tuple[Path, Path]) -> None:
    _, out = analysed
    table = pd.read_parquet(out / "frames.parquet")
    diags = [m for t, _, _, m in _decoded(out / "diagnostics.mcap") if t == "/diagnostics"]
    level = {"ok": 0, "warn": 1, "fail": 2}
    fired_rows = 0
    for (_, row), msg in zip(table.iterrows(), diags, strict=True):
        (status,) = msg.status
        assert status.level == level[row["verdict"]]
        assert status.hardware_id == row["topic"]
        for rule in row["rules"]:
            assert rule in status.message
        fired_rows += bool(len(row["rules"]))
        values = {kv.key: kv.value for kv in status.values}
        for name in ("n_keypoints", "entropy_norm", "ms_total") if row["sensor"] == "camera" \
                else ("lidar_eig_min", "lidar_cond", "ms_total"):
            v = float(row[name])
            text = values[name]
            assert text.endswith(METRICS[name].unit)
            if np.isfinite(v):
                assert float(text.split()[0]) == pytest.approx(v, rel=1e-5)
    assert fired_rows > 0


def test_metrics_are_plottable_fields_with_rule_thresholds(analysed: tuple[Path, Path]) -> None:
    _, out = analysed
    table = pd.read_parquet(out / "frames.parquet")
    cams = table[table["sensor"] == "camera"].reset_index(drop=True)
    metrics = [m for t, _, _, m in _decoded(out / "diagnostics.mcap")
               if t == "/frontdiag/camera/metrics"]
    got = np.array([m.entropy_norm for m in metrics], dtype=float)
    np.testing.assert_array_equal(got, cams["entropy_norm"].to_numpy(dtype=float))
    # FD rules read entropy_norm; each threshold is a constant field beside the metric
    thr = metrics[0].thresholds
    names = [f for f in dir(thr) if "entropy_norm" in f and not f.startswith("_")]
    assert names, "no entropy_norm threshold field"
    assert all(0.0 < getattr(thr, f) < 1.0 for f in names)


def test_annotations_are_what_the_frontend_computed(analysed: tuple[Path, Path]) -> None:
    _, out = analysed
    table = pd.read_parquet(out / "frames.parquet")
    cams = table[table["sensor"] == "camera"].reset_index(drop=True)
    anns = [m for t, _, _, m in _decoded(out / "diagnostics.mcap")
            if t == "/frontdiag/camera/annotations"]
    seen_inliers = False
    for (_, row), ann in zip(cams.iterrows(), anns, strict=True):
        kinds = {}
        for p in ann.points:
            if p.type == 1:  # POINTS: one annotation per keypoint state, coloured by state
                kinds[(p.outline_color.r, p.outline_color.g)] = len(p.points)
        assert sum(kinds.values()) == int(row["n_keypoints"])
        cells = [int(t.text) for t in ann.texts]
        assert len(cells) == 48 and sum(cells) == int(row["n_keypoints"])
        inl = row["inliers_e"]
        if np.isfinite(inl) and inl > 0:
            seen_inliers = True
            green = COLORS["inlier"][:2]
            assert kinds.get(green, 0) == int(inl)
            flow = [p for p in ann.points if p.type == 4 and p.outline_color.g == COLORS["flow"][1]
                    and p.outline_color.a == COLORS["flow"][3]]
            assert len(flow) == 1 and len(flow[0].points) == 2 * int(inl)
    assert seen_inliers


def test_lidar_used_points_and_weak_direction(analysed: tuple[Path, Path]) -> None:
    _, out = analysed
    table = pd.read_parquet(out / "frames.parquet")
    lids = table[table["sensor"] == "lidar"].reset_index(drop=True)
    msgs = _decoded(out / "diagnostics.mcap")
    clouds = [m for t, _, _, m in msgs if t == "/frontdiag/lidar/used_points"]
    for (_, row), cloud in zip(lids.iterrows(), clouds, strict=True):
        n = int(row["n_points_used"])
        assert cloud.width == (n if n <= MAX_USED_POINTS else len(range(0, n, -(-n // MAX_USED_POINTS))))
        assert len(cloud.data) == 12 * cloud.width
    words = [m.markers[1].text for t, _, _, m in msgs if t == "/frontdiag/lidar/weak_direction"]
    assert set(w.removeprefix("weakest: ") for w in words) <= set(lids["lidar_weak_dir"])


def test_explain_png_draws_the_frame_with_its_annotations(
        analysed: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import cv2

    _, out = analysed
    table = pd.read_parquet(out / "frames.parquet")
    cams = table[(table["sensor"] == "camera") & (table["inliers_e"] > 0)]
    frame = int(cams["frame"].iloc[len(cams) // 2])
    png = tmp_path / "frame.png"
    assert main(["explain", str(out), "--frame", str(frame), "--topic",
                 str(cams["topic"].iloc[0]), "--png", str(png)]) == 0
    assert "picture:" in capsys.readouterr().out
    img = cv2.imread(str(png))
    w = int(cams["width"].iloc[0])
    assert img is not None and img.shape[1] >= w
    # the inliers are drawn in their colour (BGR), on top of the frame
    b, g, r = (int(c * 255) for c in COLORS["inlier"][2::-1])
    green = np.all(np.abs(img.astype(int) - (b, g, r)) < 8, axis=2)
    assert green.sum() > 20
    # a LiDAR row has no picture: one line, exit 2
    lid = int(table[table["sensor"] == "lidar"]["frame"].iloc[0])
    topic = str(table[table["sensor"] == "lidar"]["topic"].iloc[0])
    code = main(["explain", str(out), "--frame", str(lid), "--topic", topic, "--png",
                 str(tmp_path / "l.png")])
    assert code == 2 and "LiDAR" in capsys.readouterr().err


def test_report_is_one_offline_html_with_every_plot(analysed: tuple[Path, Path],
                                                    tmp_path: Path) -> None:
    import re

    _, out = analysed
    page_path = tmp_path / "report.html"
    assert main(["report", str(out), "-o", str(page_path), "--baseline", str(out), "-q"]) == 0
    page = page_path.read_text()
    # nothing fetched: no external script, stylesheet, font or image outside the inlined
    # scripts (plotly.js's own text names web addresses; the browser test shows none is fetched)
    markup = re.sub(r"<script\b.*?</script>", "", page, flags=re.S)
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:)?//""", markup)
    assert "@import" not in markup and "url(" not in markup
    assert "<script src" not in page and "<link" not in page
    assert page.index("id='summary'") < page.index("id='metrics'") < page.index("id='episodes'")
    n_plots = len(re.findall(r'class="plotly-graph-div"', page))
    assert n_plots >= 4
    from frontdiag.report.html import MAX_EPISODES

    eps = pd.read_parquet(out / "episodes.parquet").head(MAX_EPISODES)
    n_cam = int((eps["sensor"] == "camera").sum())
    assert n_cam > 0
    assert page.count("data:image/jpeg;base64,") == n_cam  # each camera episode's worst frame


CHROMIUM = Path("/usr/bin/chromium")


@pytest.mark.skipif(not CHROMIUM.exists(), reason="Debian's chromium is not installed")
def test_report_renders_in_headless_chromium(analysed: tuple[Path, Path],
                                             tmp_path: Path) -> None:
    """No console error, no network request, every plot drawn; a screenshot is kept."""
    pw = pytest.importorskip("playwright.sync_api")
    _, out = analysed
    page_path = tmp_path / "report.html"
    assert main(["report", str(out), "-o", str(page_path), "-q"]) == 0
    errors: list[str] = []
    requests: list[str] = []
    with pw.sync_playwright() as p:
        browser = p.chromium.launch(
            executable_path=str(CHROMIUM), headless=True,
            args=["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update",
                  "--disable-sync"])
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda exc: errors.append(str(exc)))
            page.on("request", lambda r: requests.append(r.url)
                    if not r.url.startswith(("file:", "data:", "blob:", "about:")) else None)
            page.goto(page_path.as_uri(), wait_until="load")
            n = page.evaluate("JSON.parse(document.getElementById('frontdiag-meta').text).plots")
            page.wait_for_function(
                f"document.querySelectorAll('.plotly-graph-div .main-svg').length >= {n}")
            drawn = page.evaluate("""() => [...document.querySelectorAll('.plotly-graph-div')]
                .map(d => d.querySelectorAll('.scatterlayer path.js-line, .scatterlayer .point')
                .length)""")
            page.screenshot(path=str(tmp_path / "report.png"), full_page=False)
        finally:
            browser.close()
    assert errors == []
    assert requests == []
    assert len(drawn) == n >= 4
    assert all(k > 0 for k in drawn), drawn
    assert (tmp_path / "report.png").stat().st_size > 10_000
