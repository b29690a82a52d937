"""One analysed camera frame as a picture: the evidence for its verdict.

The pixels are re-read from the recording named in ``manifest.json`` (just that message, by its
log time); the annotations (keypoints by inlier state, the 8x6 entropy grid with its counts, the
inliers' flow from the reference keyframe) are read back from ``diagnostics.mcap``, where
``analyze`` wrote what the frontend computed. Nothing is recomputed. Used by
``frontdiag explain --png`` and by the thumbnails of ``frontdiag report``.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from frontdiag.io.images import is_video_message
from frontdiag.records import (
    KP_INLIER,
    KP_OUTLIER,
    KP_TRACKED,
    KP_UNTRACKED,
    CameraAnnotation,
)
from frontdiag.report.mcap_ import COLORS, DIAGNOSTICS_FILE, KP_CLASSES, TOPIC_ANNOTATIONS

log = logging.getLogger(__name__)

_KP_LABEL = {KP_INLIER: "E inlier", KP_OUTLIER: "E outlier", KP_TRACKED: "matched, untested",
             KP_UNTRACKED: "no match to reference"}
_KP_NAME = dict(KP_CLASSES)


def _bgr(name: str) -> tuple[int, int, int]:
    r, g, b, _ = COLORS[name]
    return int(b * 255), int(g * 255), int(r * 255)


@dataclass(frozen=True)
class FrameEvidence:
    """What one picture needs: pixels (None when the recording is not at hand), annotation
    (None when the result has no diagnostics.mcap), and a note saying what is missing."""

    gray: np.ndarray | None
    annotation: CameraAnnotation | None
    notes: tuple[str, ...] = ()


def row_log_ns(row: Mapping[str, Any], manifest: Mapping[str, Any]) -> int | None:
    """The recording's log time of a row: start + t_rel_s (exact to the nanosecond for any
    recording shorter than a century, float64 holds 15-16 digits)."""
    start = (manifest.get("input") or {}).get("start_ns")
    t_rel = row.get("t_rel_s")
    try:
        t = float(t_rel)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return None
    if start is None or t != t:
        return None
    return int(start) + round(t * 1e9)


def annotation_from_message(msg: Any, width: int, height: int) -> CameraAnnotation:
    """Back from a decoded foxglove_msgs/ImageAnnotations to the frontend's record."""
    by_color = {COLORS[name][:3]: state for state, name in KP_CLASSES}
    xy: list[np.ndarray] = []
    state: list[np.ndarray] = []
    flow = np.zeros((0, 2), np.float32)
    for p in msg.points:
        c = (p.outline_color.r, p.outline_color.g, p.outline_color.b)
        pts = np.array([(q.x, q.y) for q in p.points], np.float32).reshape(-1, 2)
        if p.type == 1 and c in by_color:
            xy.append(pts)
            state.append(np.full(len(pts), by_color[c], np.uint8))
        elif p.type == 4 and c != COLORS["grid"][:3]:  # line lists: the grid, and the flow
            flow = pts
    counts = np.array([int(t.text) for t in msg.texts], np.int64)
    grid = counts.reshape(6, 8) if counts.size == 48 else np.zeros((0, 0), np.int64)
    return CameraAnnotation(
        width, height, np.concatenate(xy) if xy else np.zeros((0, 2), np.float32),
        np.concatenate(state) if state else np.zeros(0, np.uint8), grid, -1,
        flow[0::2], flow[1::2])


def read_annotation(result_dir: Path, log_ns: int, t_ns: int, width: int,
                    height: int) -> CameraAnnotation | None:
    """The ImageAnnotations written for the frame logged at ``log_ns`` with stamp ``t_ns``."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    path = Path(result_dir) / DIAGNOSTICS_FILE
    if not path.is_file():
        return None
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for _, _, _, msg in reader.iter_decoded_messages(
                topics=[TOPIC_ANNOTATIONS], starting_at=log_ns - 1_000_000,
                ending_at=log_ns + 1_000_000):
            stamps = [p.timestamp for p in msg.points] + [t.timestamp for t in msg.texts]
            if not stamps or int(stamps[0].sec) * 1_000_000_000 + int(stamps[0].nanosec) == t_ns:
                return annotation_from_message(msg, width, height)
    return None


def read_pixels(manifest: Mapping[str, Any], topic: str, log_ns: int) -> np.ndarray | None:
    """The grey image the frontend saw, re-read from the recording (None if it is gone)."""
    from frontdiag.errors import FrontdiagError
    from frontdiag.io.images import GrayConverter
    from frontdiag.io.readers import open_recording

    path = (manifest.get("input") or {}).get("path")
    if not path or not Path(path).exists():
        return None
    try:
        with open_recording(Path(path)) as rec:
            # shrunk (--downscale) as the run shrank them
            downscale = int((manifest.get("selection") or {}).get("downscale") or 1)
            for raw in rec.messages([topic], log_ns, log_ns):
                msg = rec.deserialize(raw)
                if is_video_message(msg, raw.msgtype):
                    return _video_picture(rec, topic, log_ns, downscale)
                # 16-bit pictures mapped to 8 bits as the run mapped them
                mono16 = ((manifest.get("counts") or {}).get(topic) or {}).get("conversion")
                gray, _ = GrayConverter.mapped(topic, mono16, downscale)(msg, raw.msgtype)
                return gray
    except (FrontdiagError, OSError, ValueError) as exc:
        log.info("cannot re-read %s at %d from %s: %s", topic, log_ns, path, exc)
    return None


VIDEO_LOOKBACK_S = (2.0, 10.0, 60.0, None)
"""How far before a video picture decoding starts, tried in turn until it reaches a keyframe
(None: from the start of the recording)."""


def _video_picture(rec: Any, topic: str, log_ns: int, downscale: int = 1) -> np.ndarray | None:
    """The picture of a video topic logged at ``log_ns``: decoded from a keyframe before it,
    found by starting further back each time none was met."""
    from frontdiag.io.images import GrayConverter

    for back in VIDEO_LOOKBACK_S:
        start = None if back is None else max(log_ns - int(back * 1e9), 0)
        conv = GrayConverter(topic, downscale=downscale)
        gray = None
        for raw in rec.messages([topic], start, log_ns):
            try:
                out, _ = conv(rec.deserialize(raw), raw.msgtype)
            except Exception:  # before the keyframe, or a damaged picture
                continue
            if raw.log_ns == log_ns:
                gray = out
        if gray is not None or start is None or start == 0:
            return gray
    return None


def evidence(result_dir: Path, row: Mapping[str, Any],
             manifest: Mapping[str, Any]) -> FrameEvidence:
    """Pixels and annotation of one camera row of a result directory."""
    log_ns = row_log_ns(row, manifest)
    if log_ns is None:
        return FrameEvidence(None, None, ("the row has no log time (t_rel_s) to find it by",))
    width, height = _size(row)
    ann = read_annotation(result_dir, log_ns, int(row["t_ns"]), width, height)
    gray = read_pixels(manifest, str(row["topic"]), log_ns)
    notes = []
    if ann is None:
        notes.append(f"no annotations ({DIAGNOSTICS_FILE} missing or without this frame; "
                     "rerun `frontdiag analyze LOG --out DIR`)")
    if gray is None:
        notes.append("recording not found at the path in manifest.json: annotations on grey")
    return FrameEvidence(gray, ann, tuple(notes))


def _size(row: Mapping[str, Any]) -> tuple[int, int]:
    try:
        return int(row["width"]), int(row["height"])
    except (KeyError, TypeError, ValueError):
        return 640, 480


def render(ev: FrameEvidence, row: Mapping[str, Any], lines: Sequence[str] = (),
           min_width: int = 960) -> np.ndarray:
    """BGR picture: the frame (dimmed so the marks read), grid with counts, flow, keypoints,
    then a caption with the verdict and the given lines."""
    w, h = _size(row)
    if ev.gray is not None:
        h, w = ev.gray.shape[:2]
        base = cv2.cvtColor(ev.gray, cv2.COLOR_GRAY2BGR)
    else:
        base = np.full((h, w, 3), 40, np.uint8)
    s = max(1.0, min_width / max(w, 1))
    img = cv2.resize(base, (round(w * s), round(h * s)), interpolation=cv2.INTER_AREA
                     if s < 1 else cv2.INTER_LINEAR)
    img = cv2.convertScaleAbs(img, alpha=0.75)
    ann = ev.annotation
    font = cv2.FONT_HERSHEY_SIMPLEX
    if ann is not None:
        _draw_grid(img, ann, s, font)
        for (x0, y0), (x1, y1) in zip(ann.flow_ref.tolist(), ann.flow_cur.tolist(), strict=True):
            cv2.line(img, (round(x0 * s), round(y0 * s)), (round(x1 * s), round(y1 * s)),
                     _bgr("flow"), 1, cv2.LINE_AA)
        r = max(2, round(2.2 * s))
        for state in (KP_UNTRACKED, KP_TRACKED, KP_OUTLIER, KP_INLIER):  # inliers on top
            color = _bgr(_KP_NAME[state])
            for x, y in ann.xy[ann.state == state].tolist():
                c = (round(x * s), round(y * s))
                if state == KP_UNTRACKED:
                    cv2.circle(img, c, r, color, 1, cv2.LINE_AA)
                else:
                    cv2.circle(img, c, r, color, -1, cv2.LINE_AA)
    return np.vstack([img, _caption(img.shape[1], ev, row, lines, font)])


def _draw_grid(img: np.ndarray, ann: CameraAnnotation, s: float, font: int) -> None:
    if ann.grid_counts.ndim != 2 or not ann.grid_counts.size:
        return
    rows, cols = ann.grid_counts.shape
    H, W = img.shape[:2]
    grid = _bgr("grid")
    for i in range(1, cols):
        x = round(W * i / cols)
        cv2.line(img, (x, 0), (x, H), grid, 1, cv2.LINE_AA)
    for j in range(1, rows):
        y = round(H * j / rows)
        cv2.line(img, (0, y), (W, y), grid, 1, cv2.LINE_AA)
    total = max(int(ann.grid_counts.sum()), 1)
    scale = 0.45 * max(1.0, W / 1280)
    for j in range(rows):
        for i in range(cols):
            n = int(ann.grid_counts[j, i])
            x0, y0 = round(W * i / cols) + 4, round(H * j / rows) + round(18 * scale / 0.45)
            text = str(n)
            (tw, th), _ = cv2.getTextSize(text, font, scale, 1)
            cv2.rectangle(img, (x0 - 2, y0 - th - 3), (x0 + tw + 2, y0 + 3), (0, 0, 0), -1)
            # empty cells in red: where the entropy is lost; crowded cells (over 2x the mean)
            # in amber
            color = (80, 80, 255) if n == 0 else (60, 200, 255) if n > 2 * total / (rows * cols) \
                else (255, 255, 255)
            cv2.putText(img, text, (x0, y0), font, scale, color, 1, cv2.LINE_AA)


def _caption(width: int, ev: FrameEvidence, row: Mapping[str, Any], lines: Sequence[str],
             font: int) -> np.ndarray:
    verdict = str(row.get("verdict", "") or "")
    head_color = {"fail": (60, 60, 235), "warn": (40, 190, 250), "ok": (90, 200, 90)}.get(
        verdict, (230, 230, 230))
    head = (f"frame {row.get('frame')}  {row.get('topic', '')}  t = "
            f"{float(row.get('t_rel_s', float('nan'))):.2f} s  verdict {verdict.upper() or '-'}")
    legend = []
    ann = ev.annotation
    if ann is not None:
        for state in (KP_INLIER, KP_OUTLIER, KP_TRACKED, KP_UNTRACKED):
            n = int(np.count_nonzero(ann.state == state))
            if n:
                legend.append((f"{_KP_LABEL[state]} {n}", _bgr(_KP_NAME[state])))
        legend.append((f"flow to reference {len(ann.flow_cur)}", _bgr("flow")))
    body = [*lines, *ev.notes]
    scale = 0.55
    lh = 24
    height = 16 + lh * (2 + len(body)) + 8
    cap = np.full((height, width, 3), 24, np.uint8)
    y = 16 + 14
    cv2.putText(cap, head, (12, y), font, 0.65, head_color, 1, cv2.LINE_AA)
    y += lh
    x = 12
    for text, color in legend:
        cv2.circle(cap, (x + 6, y - 5), 6, color, -1, cv2.LINE_AA)
        cv2.putText(cap, text, (x + 18, y), font, scale, (230, 230, 230), 1, cv2.LINE_AA)
        x += 18 + cv2.getTextSize(text, font, scale, 1)[0][0] + 22
    for line in body:
        y += lh
        cv2.putText(cap, _ascii(line), (12, y), font, scale, (220, 220, 220), 1, cv2.LINE_AA)
    return cap


def _ascii(text: str) -> str:
    """OpenCV's Hershey fonts draw ASCII only."""
    table = {"✔": "+", "✘": "-", "→": "->", "λ": "lambda", "Δ": "d", "°": " deg", "≤": "<=",
             "≥": ">=", "×": "x", "–": "-", "—": "-", "·": "-"}
    return "".join(table.get(ch, ch if ord(ch) < 128 else "?") for ch in text)


def verdict_lines(result: Any, position: int, max_lines: int = 8) -> list[str]:
    """The fired rules of a row with the clauses that made them fire (from explain_row)."""
    from frontdiag.verdicts.explain import explain_row

    out: list[str] = []
    for e in explain_row(result, position):
        if not e.fired:
            continue
        r = e.rule
        out.append(f"{r.id} {r.condition} [{r.severity}]: {r.title}")
        for c in e.clauses:
            if c.holds:
                out.append(f"   {c.metric} = {c.value:.4g} {c.unit}  ({c.test})")
        out.extend(f"   {line}" for line in e.check_lines[:2])
    if not out:
        out.append("no rule fired on this frame")
    return out[:max_lines]


def encode_png(img: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise ValueError("PNG encoding failed")
    return bytes(buf)


def encode_jpeg(img: np.ndarray, width: int = 640, quality: int = 80) -> bytes:
    if img.shape[1] > width:
        img = cv2.resize(img, (width, round(img.shape[0] * width / img.shape[1])),
                         interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return bytes(buf)


def explain_lines(data: Mapping[str, Any], max_lines: int = 8) -> list[str]:
    """verdict_lines from `frontdiag explain`'s document (its fired rules and clauses)."""
    out: list[str] = []
    for r in data.get("rules", []):
        if r.get("state") != "fired":
            continue
        out.append(f"{r['id']} {r['condition']} [{r['severity']}]: {r['title']}")
        for c in r.get("clauses", []):
            if c.get("holds"):
                v = c.get("value")
                vs = f"{v:.4g}" if isinstance(v, int | float) else str(v)
                out.append(f"   {c['metric']} = {vs} {c.get('unit', '')}  ({c['test']})")
        out.extend(f"   {line}" for line in r.get("check", [])[:2])
    return (out or ["no rule fired on this frame"])[:max_lines]


def explain_png(out: Path, result_dir: Path, data: Mapping[str, Any]) -> list[str]:
    """Write the picture of the row `frontdiag explain` described (``data``) to ``out``;
    returns the notes (what could not be drawn)."""
    from frontdiag.errors import ConfigError
    from frontdiag.output import read_manifest, read_table

    if str(data.get("sensor", "camera")) != "camera":
        raise ConfigError(f"--png draws camera frames; frame {data.get('frame')} on "
                          f"{data.get('topic')} is a LiDAR scan",
                          hint="pick a camera frame (see the `topic` column)")
    table = read_table(result_dir)
    sel = table[(table["topic"].astype(str) == str(data["topic"]))
                & (table["frame"] == int(data["frame"]))]
    if sel.empty:
        raise ConfigError(f"{result_dir}: no row for frame {data['frame']} on {data['topic']}")
    row = {str(k): v for k, v in sel.iloc[0].to_dict().items()}
    row["verdict"] = data.get("verdict", "")
    ev = evidence(result_dir, row, read_manifest(result_dir))
    if ev.gray is None and ev.annotation is None:
        raise ConfigError(f"{result_dir}: nothing to draw for frame {data['frame']}: "
                          + "; ".join(ev.notes))
    Path(out).write_bytes(encode_png(render(ev, row, explain_lines(data))))
    return list(ev.notes)
