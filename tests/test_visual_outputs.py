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


def _annotations_by_typestore(ann: Any, t_ns: int) -> bytes:
    """The frame's ImageAnnotations built as message objects and serialised by rosbags (as
    diagnostics.mcap was written before the direct encoder): the oracle for its bytes."""
    from frontdiag.report.mcap_ import KP_CLASSES, DiagnosticsWriter

    ts = DiagnosticsWriter(Path("unused.mcap")).ts
    T = ts.types
    P2, Pts, Txt = (T["foxglove_msgs/msg/Point2"], T["foxglove_msgs/msg/PointsAnnotation"],
                    T["foxglove_msgs/msg/TextAnnotation"])

    def color(name: str) -> Any:
        return T["foxglove_msgs/msg/Color"](*COLORS[name])

    stamp = T["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
    points, texts = [], []
    rows, cols = ann.grid_counts.shape if ann.grid_counts.ndim == 2 else (0, 0)
    w, h = float(ann.width), float(ann.height)
    if rows and cols and w and h:
        seg = []
        for i in range(1, cols):
            seg += [P2(w * i / cols, 0.0), P2(w * i / cols, h)]
        for j in range(1, rows):
            seg += [P2(0.0, h * j / rows), P2(w, h * j / rows)]
        points.append(Pts(stamp, 4, seg, color("grid"), [], color("text_bg"), 1.0))
    if len(ann.flow_cur):
        seg = []
        for (x0, y0), (x1, y1) in zip(ann.flow_ref.tolist(), ann.flow_cur.tolist(), strict=True):
            seg += [P2(x0, y0), P2(x1, y1)]
        points.append(Pts(stamp, 4, seg, color("flow"), [], color("text_bg"), 1.0))
    for state, name in KP_CLASSES:
        sel = ann.xy[ann.state == state]
        if len(sel):
            points.append(Pts(stamp, 1, [P2(x, y) for x, y in sel.tolist()], color(name), [],
                              color(name), 4.0))
    if rows and cols and w and h:
        size = max(10.0, min(w / cols, h / rows) / 4)
        for j in range(rows):
            for i in range(cols):
                texts.append(Txt(stamp, P2(w * i / cols + 3, h * j / rows + size + 2),
                                 str(int(ann.grid_counts[j, i])), size, color("text"),
                                 color("text_bg")))
    msg = T["foxglove_msgs/msg/ImageAnnotations"]([], points, texts)
    return bytes(ts.serialize_cdr(msg, "foxglove_msgs/msg/ImageAnnotations"))


def test_annotations_are_encoded_byte_for_byte_as_rosbags_would(analysed: tuple[Path, Path]
                                                                ) -> None:
    """The camera annotations are CDR-encoded directly (whole float64 arrays, not one
    message object per keypoint); every byte is what rosbags' serialiser gives for the same
    message: with and without flow, grid or keypoints of a state, counts of 1 to 4 digits
    (strings of every length modulo 4), odd sizes and stamps; and every frame of the
    analysed recording."""
    from frontdiag.records import CameraAnnotation
    from frontdiag.report.mcap_ import image_annotations_cdr

    rng = np.random.default_rng(7)
    cases = []
    for case in range(12):
        n = int(rng.integers(0, 300)) if case else 0
        w, h = (int(rng.integers(17, 1300)), int(rng.integers(9, 900))) if case != 3 else (0, 0)
        state = rng.integers(0, 4 if case % 2 else 2, n).astype(np.uint8)
        xy = (rng.random((n, 2)) * [w or 1, h or 1]).astype(np.float32)
        grid = (rng.integers(0, 10 ** (1 + case % 4), (6, 8)) if case != 5
                else np.zeros(0, np.int64))
        m = int(rng.integers(0, n + 1)) if case % 3 else 0
        ann = CameraAnnotation(w, h, xy, state, grid, ref_frame=case - 1,
                               flow_ref=(rng.random((m, 2)) * 500).astype(np.float32),
                               flow_cur=(rng.random((m, 2)) * 500).astype(np.float32))
        cases.append((ann, int(rng.integers(0, 2**31 * 10**9))))  # Time.sec is an int32
    for ann, t_ns in cases:
        assert image_annotations_cdr(ann, t_ns) == _annotations_by_typestore(ann, t_ns)
    # and the file: each message as written decodes, and encodes again to the same bytes
    _, out = analysed
    raw = _raw_messages(out / "diagnostics.mcap", "/frontdiag/camera/annotations")
    assert raw
    from frontdiag.report.mcap_ import DiagnosticsWriter

    ts = DiagnosticsWriter(Path("unused.mcap")).ts
    for data in raw:
        msg = ts.deserialize_cdr(data, "foxglove_msgs/msg/ImageAnnotations")
        assert bytes(ts.serialize_cdr(msg, "foxglove_msgs/msg/ImageAnnotations")) == data


def _raw_messages(path: Path, topic: str) -> list[bytes]:
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        return [bytes(m.data) for _, c, m in make_reader(fh).iter_messages(log_time_order=True)
                if c.topic == topic]


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


def _render(page_path: Path, shot: Path) -> tuple[list[str], list[str], list[int], int]:
    """Console errors, requests beyond the file system, drawn marks per plot and the plot count
    of ``page_path`` opened in headless Chromium; a screenshot is written to ``shot``."""
    pw = pytest.importorskip("playwright.sync_api")
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
            page.screenshot(path=str(shot), full_page=False)
        finally:
            browser.close()
    return errors, requests, drawn, n


@pytest.mark.skipif(not CHROMIUM.exists(), reason="Debian's chromium is not installed")
def test_report_renders_in_headless_chromium(analysed: tuple[Path, Path],
                                             tmp_path: Path) -> None:
    """No console error, no network request, every plot drawn; a screenshot is kept."""
    _, out = analysed
    page_path = tmp_path / "report.html"
    assert main(["report", str(out), "-o", str(page_path), "-q"]) == 0
    errors, requests, drawn, n = _render(page_path, tmp_path / "report.png")
    assert errors == []
    assert requests == []
    assert len(drawn) == n >= 4
    assert all(k > 0 for k in drawn), drawn
    assert (tmp_path / "report.png").stat().st_size > 10_000


@pytest.mark.skipif(not CHROMIUM.exists(), reason="Debian's chromium is not installed")
def test_a_fleets_pages_share_one_plotly_and_render(analysed: tuple[Path, Path],
                                                    tmp_path: Path) -> None:
    """A fleet's report writes plotly.js once beside the recordings' folders; each page loads
    it from there (no copy of its own, no network) and draws every plot."""
    import shutil

    rec, _ = analysed
    logs = tmp_path / "logs"
    logs.mkdir()
    for name in ("a.mcap", "b.mcap"):
        shutil.copy(rec, logs / name)
    fleet = tmp_path / "fleet"
    assert main(["analyze", str(logs), "--out", str(fleet), "-q", "--fail-on", "never"]) == 0
    assert main(["report", str(fleet), "-q"]) == 0
    shared = fleet / "plotly.min.js"
    assert shared.stat().st_size > 1_000_000
    for name in ("a", "b"):
        text = (fleet / name / "report.html").read_text()
        assert "<script src='../plotly.min.js'></script>" in text
        assert len(text) < shared.stat().st_size  # the page does not carry its own copy
    errors, requests, drawn, n = _render(fleet / "a" / "report.html", tmp_path / "a.png")
    assert errors == [] and requests == []
    assert len(drawn) == n >= 4 and all(k > 0 for k in drawn), drawn


def test_a_long_series_is_drawn_as_its_envelope() -> None:
    from frontdiag.report.html import envelope

    v = np.sin(np.arange(100_000) / 500.0)
    v[73_519] = 9.0  # a one-row spike
    v[20_000:30_000] = np.nan  # a stretch with no reading
    pos = envelope(v, 4000)
    assert len(pos) <= 4000 and np.all(np.diff(pos) > 0)
    assert 73_519 in pos  # the spike survives
    assert np.isnan(v[pos][(pos >= 20_100) & (pos < 29_900)]).all()  # the gap stays a gap
    assert np.nanmax(v[pos]) == 9.0 and np.nanmin(v[pos]) == np.nanmin(v)
    short = np.arange(50.0)
    assert envelope(short, 4000).tolist() == list(range(50))  # short series: every row


def test_episodes_closer_than_a_pixel_are_one_shaded_stretch() -> None:
    from frontdiag.report.html import episode_spans

    eps = pd.DataFrame({
        "start_t_rel_s": [1.0, 1.3, 10.0, 10.0, 50.0, 99.0],
        "end_t_rel_s": [1.2, 1.3, 12.0, 11.0, 50.0, 99.0],
        "severity": ["warn", "warn", "warn", "fail", "warn", "warn"],
        "condition": ["exposure_step", "exposure_step", "pure_rotation", "planar_degeneracy",
                      "exposure_step", "exposure_step"]})
    spans = episode_spans(eps, 0.0, 100.0)  # 0.05 s: a 2000th of the plot's width
    warn = sorted((x0, x1, c) for x0, x1, s, c in spans if s == "warn")
    fail = [(x0, x1, c) for x0, x1, s, c in spans if s == "fail"]
    # 1.2 and 1.3 lie 0.1 s apart minus the 0.025 s each one-frame episode is widened by
    assert [w[2] for w in warn] == [["exposure_step"], ["exposure_step"], ["pure_rotation"],
                                    ["exposure_step"], ["exposure_step"]]
    assert fail == [(10.0, 11.0, ["planar_degeneracy"])]  # another severity stays apart
    assert warn[1][0] == pytest.approx(1.275) and warn[3][:2] == pytest.approx((49.975, 50.025))
    # on a plot of an hour the first two are under a pixel apart: one stretch, one name
    spans = episode_spans(eps, 0.0, 3600.0)
    assert sorted((round(x0, 3), c) for x0, _, s, c in spans if s == "warn")[0] \
        == (1.0, ["exposure_step"])
    assert len([s for s in spans if s[2] == "warn"]) == 4


def test_a_long_result_is_plotted_in_a_bounded_size(analysed: tuple[Path, Path],
                                                    tmp_path: Path) -> None:
    """An hour of rows and hundreds of episodes: every plot keeps at most MAX_PLOT_POINTS
    points a line and one shape per stretch it can show (Plotly's add_vrect per episode took
    minutes here), and the report is written."""
    import shutil

    from frontdiag.report.html import (
        MAX_LABELLED_SPANS,
        MAX_PLOT_POINTS,
        load_run,
        metric_figure,
        plotted_metrics,
    )
    from frontdiag.report.thresholds import rule_thresholds

    _, out = analysed
    long = tmp_path / "long"
    shutil.copytree(out, long)
    table = pd.read_parquet(out / "frames.parquet")
    eps = pd.read_parquet(out / "episodes.parquet")
    span_s = float(table["t_rel_s"].max()) + 2.0  # copies 2 s apart: far more than a pixel
    n_frames = int(table["frame"].max()) + 1
    copies = 150
    tables, episodes = [], []
    for i in range(copies):
        t = table.copy()
        t["frame"] += i * n_frames
        t["t_ns"] += int(i * span_s * 1e9)
        t["t_rel_s"] += i * span_s
        if i:  # each copy a stretch of its own, as after a pause: its episodes stay its own
            t.loc[t.index[t["sensor"] == "camera"][0], "status"] = "after_gap"
        tables.append(t)
        e = eps.copy()
        for c in ("start_frame", "end_frame"):
            e[c] += i * n_frames
        for c in ("start_t_ns", "end_t_ns"):
            e[c] += int(i * span_s * 1e9)
        for c in ("start_t_rel_s", "end_t_rel_s"):
            e[c] += i * span_s
        episodes.append(e)
    pd.concat(tables, ignore_index=True).to_parquet(long / "frames.parquet")
    pd.concat(episodes, ignore_index=True).to_parquet(long / "episodes.parquet")
    run = load_run(long)
    cam = run.table[run.table["sensor"] == "camera"]
    topic = str(cam["topic"].iloc[0])
    assert len(cam) > MAX_PLOT_POINTS
    n_eps = int(((run.verdicts.episodes["sensor"] == "camera")).sum())
    assert n_eps > MAX_LABELLED_SPANS
    ths = rule_thresholds(run.ruleset)
    metric = plotted_metrics(run.table, "camera", ths)[0]
    fig = metric_figure(run, run, "camera", topic, metric, ths)
    for trace in fig.data:
        assert len(trace.x) <= MAX_PLOT_POINTS
    rects = [sh for sh in fig.layout.shapes if sh.type == "rect"]
    assert len(rects) == n_eps  # apart on the plot: one shaded stretch each
    assert not [a for a in fig.layout.annotations if a.textangle == -90]  # too many to name
    # the line's extremes are the table's
    line = np.array([y for y in fig.data[1].y if y is not None], dtype=float)
    vals = cam[metric].to_numpy(dtype=float, na_value=np.nan)
    assert line.max() == pytest.approx(np.nanmax(vals), rel=1e-5)
    assert line.min() == pytest.approx(np.nanmin(vals), rel=1e-5)
    assert main(["report", str(long), "-o", str(tmp_path / "long.html"), "-q"]) == 0
    assert "so no spike is lost" in (tmp_path / "long.html").read_text()
