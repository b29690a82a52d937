"""Score frontdiag's verdicts on the real-data validation recordings, pooled per condition.

    python validation/score.py                      # the dev half, in /work/valdata/dev
    python validation/score.py --split report       # the reported half (never tune on it)
    python validation/score.py --split all --json   # both halves, machine-readable
    python validation/score.py --split report --markdown   # the README's table
    python validation/score.py --data DIR --per-recording
    python validation/score.py --overrides try.toml   # a threshold change, tried on dev
    python validation/score.py --video 23           # every camera re-encoded as H.264 video
    python validation/score.py --downscale 2        # every picture shrunk by 2
    python validation/score.py --stride 2           # every 2nd frame: half the frame rate

Runs ``frontdiag analyze`` (the Python API, default rules) on every recording of the chosen
half listed in ``validation/manifest.json`` and built by ``validation/build.py``, scores each
against its ``<recording>.labels.csv`` with ``frontdiag eval``'s scorer (``frontdiag.scoring``),
and prints the pooled table in the format of ``sample_logs/score.py``: per condition, episodes
found / episodes (episode recall), frame precision, frame recall, F1, and false alarms on
healthy frames; then the overall false-alarm rate. Every condition is scored on every
recording, so a condition's false alarms count all healthy frames of the half.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
if str(HERE.parent) not in sys.path:
    sys.path.insert(0, str(HERE.parent))

from frontdiag.conditions import CONDITIONS  # noqa: E402
from frontdiag.errors import ConfigError  # noqa: E402
from frontdiag.scoring import (  # noqa: E402
    EvalReport,
    format_markdown,
    format_pooled,
    normalise_frames,
    pool,
    read_labels,
    score,
)
from frontdiag.sim.run import labels_path_for  # noqa: E402
from validation.build import DEFAULT_OUT, MANIFEST, load_manifest, output_path  # noqa: E402

CAMERA_CONDITIONS = tuple(c for c in CONDITIONS if c != "registration_degeneracy")

SINGLE_FRAME = ("detection_failure", "feature_clustering")
"""Labels of one frame alone (validation/README.md, "Labels"); the others compare a frame with
the one before it."""
HELD_OVER_A_GAP = ("pure_rotation", "planar_degeneracy", "repetitive_structure")
"""Two-frame labels that hold between frames n apart when they hold between every pair of
neighbours in between (a turn, a plane, a repeated pattern that lasts)."""


EXPOSURE_STEP_CHANGE = 0.10
"""validation/README.md's exposure criterion: the same surfaces at least 10 % brighter or darker
is a step; 6-10 % is left unlabelled (neither a step nor healthy)."""
EXPOSURE_UNLABELLED_CHANGE = 0.06


def _gap_change(measured: dict[int, float | None] | None, k: int) -> float | None:
    """|ratio - 1| of the pair (k - n, k) as the label aid measured it (validation/label_aid.py,
    the manifest's ``gap_brightness``: gaps not listed measured under 6 %), or None where the
    recording has no measurement for this stride or the pair gave no reading."""
    if measured is None:
        return None
    if k not in measured:
        return 0.0
    r = measured[k]
    return None if r is None else abs(float(r) - 1.0)


def frame_labels(rec: dict[str, Any]) -> list[set[str]]:
    """Each frame's set of labels, from the manifest's ``[first, last, condition]`` intervals
    (frames after the last interval are not listed)."""
    count = max((int(b) for _, b, _ in rec["labels"]), default=-1) + 1
    per: list[set[str]] = [set() for _ in range(count)]
    for a, b, cond in rec["labels"]:
        for i in range(int(a), int(b) + 1):
            per[i].add(str(cond))
    return per


def stride_labels(rec: dict[str, Any], frames: Any, n: int) -> Any:
    """Labels for the rows of a run at ``--stride n``, from the manifest's frame labels: each
    analysed frame k is compared with frame k - n, so its two-frame labels are those of the
    frames k - n + 1 .. k together. A frame alone (``SINGLE_FRAME``) keeps its own labels;
    ``HELD_OVER_A_GAP`` and ``healthy`` hold where every frame of the gap carries them. The
    exposure of a gap is measured on the pair itself where the manifest has the label aid's
    ``gap_brightness`` for stride n (a ramp of 3-5 % a frame is under the step line between
    neighbours and over it across the gap): at least 10 % brighter or darker is a step, 6-10 %
    leaves the row neither a step nor healthy. Without a measurement, an exposure step anywhere
    in a gap whose every frame is labelled is a step. The first row, which has no frame
    before it, keeps only single-frame labels and healthy. Consecutive rows with the same
    label form one interval (one episode), as the manifest's own labels do."""
    import pandas as pd

    per = frame_labels(rec)
    count = len(per)
    listed = rec.get("gap_brightness", {}).get(str(n))
    measured = None if listed is None else {int(k): r for k, r in listed}
    rows: list[tuple[int, int, str]] = []
    open_: dict[str, list[int]] = {}  # label -> [start, end] of the run the last row continued
    first = True
    for k, t in zip(frames["frame"].to_numpy(), frames["t_ns"].to_numpy(), strict=True):
        k = int(k)
        own = per[k] if k < count else set()
        labs = {c for c in own if c in SINGLE_FRAME}
        if first:
            labs |= own & {"healthy"}
            first = False
        else:
            gap = [per[i] if i < count else set() for i in range(max(k - n + 1, 0), k + 1)]
            labs |= {c for c in HELD_OVER_A_GAP if all(c in g for g in gap)}
            change = _gap_change(measured, k)
            if change is None:  # not measured: from the frames' own labels
                if all(gap) and any("exposure_step" in g for g in gap):
                    labs.add("exposure_step")
                if all("healthy" in g for g in gap):
                    labs.add("healthy")
            else:  # the README's exposure criterion, on the pair itself
                if change >= EXPOSURE_STEP_CHANGE:
                    labs.add("exposure_step")
                if change < EXPOSURE_UNLABELLED_CHANGE and all("healthy" in g for g in gap):
                    labs.add("healthy")
        for c in [c for c in open_ if c not in labs]:
            a, b = open_.pop(c)
            rows.append((a, b, c))
        for c in labs:
            open_.setdefault(c, [int(t), int(t)])[1] = int(t)
    rows += [(a, b, c) for c, (a, b) in open_.items()]
    return pd.DataFrame(sorted(rows), columns=["t_start_ns", "t_end_ns", "condition"])


def recordings(manifest: dict[str, Any], split: str, data: Path) -> list[tuple[str, Path]]:
    """(name, built path) of every recording of ``split`` (``dev``, ``report`` or ``all``)."""
    out = []
    for rec in manifest["recordings"]:
        if split in ("all", rec["split"]):
            out.append((rec["name"], output_path(data, rec)))
    return out


def score_recording(path: Path, conditions: Sequence[str] = CAMERA_CONDITIONS,
                    overrides: Path | None = None, video_crf: int | None = None,
                    downscale: int = 1, stride: int = 1,
                    rec: dict[str, Any] | None = None) -> EvalReport:
    """Analyse one built recording with the default rules (thresholds changed by an
    ``overrides`` file, the format of ``frontdiag analyze --overrides``) and score it; with
    ``video_crf``, its camera re-encoded as H.264 at that CRF (validation/video.py); with
    ``downscale``, its pictures shrunk by that factor before the frontend sees them (as
    ``frontdiag analyze --downscale``; the intrinsics scale with them); with ``stride``, every
    ``stride``-th frame only (``frontdiag analyze --stride``), scored against the labels
    :func:`stride_labels` derives from the manifest entry ``rec``."""
    import tempfile

    from frontdiag.api import analyze

    if not path.exists():
        raise ConfigError(f"recording not found: {path}",
                          hint="build the validation set first: python validation/build.py")
    labels = read_labels(labels_path_for(path))
    if video_crf is not None:
        from validation.video import to_h264

        with tempfile.TemporaryDirectory() as tmp:
            video = to_h264(path, Path(tmp) / f"{path.name}.h264.mcap", crf=video_crf)
            frames = normalise_frames(
                analyze(video, rules_overrides=str(overrides) if overrides else None,
                        downscale=downscale),
                source=str(path))
        return score(frames, labels, conditions=conditions)
    table = analyze(path, rules_overrides=str(overrides) if overrides else None,
                    downscale=downscale, stride=stride)
    if stride > 1:
        if rec is None:
            raise ConfigError("--stride needs the recording's manifest entry")
        labels = stride_labels(rec, table, stride)
    frames = normalise_frames(table, source=str(path))
    return score(frames, labels, conditions=conditions)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="validation/score.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--split", choices=("dev", "report", "all"), default="dev",
                    help="which half to score (default dev)")
    ap.add_argument("--data", type=Path, default=DEFAULT_OUT,
                    help="where build.py wrote the recordings (default /work/valdata)")
    ap.add_argument("--manifest", type=Path, default=MANIFEST)
    ap.add_argument("--only", nargs="*", default=None, help="recording names to score")
    ap.add_argument("--per-recording", action="store_true",
                    help="also print each recording's own table")
    ap.add_argument("--json", action="store_true", help="print JSON instead of tables")
    ap.add_argument("--markdown", action="store_true",
                    help="print the pooled table as Markdown, as the README shows it")
    ap.add_argument("--overrides", type=Path, default=None,
                    help="a rule-overrides TOML (as for frontdiag analyze --overrides), to try "
                         "a threshold on the dev half")
    ap.add_argument("--video", type=int, default=None, metavar="CRF",
                    help="score each recording's camera re-encoded as H.264 video at this "
                         "CRF (23: a camera streaming at a few Mbit/s; higher is coarser)")
    ap.add_argument("--stride", type=int, default=1, metavar="N",
                    help="score every N-th frame only (as frontdiag analyze --stride), against "
                         "labels derived for that rate: do the verdicts hold at 1/N the rate?")
    ap.add_argument("--downscale", type=int, default=1, metavar="N",
                    help="score with every camera's pictures shrunk by N (as frontdiag "
                         "analyze --downscale): do the verdicts hold at another resolution?")
    a = ap.parse_args(argv)
    manifest = load_manifest(a.manifest)
    entries = {r["name"]: r for r in manifest["recordings"]}
    if a.stride > 1 and a.video is not None:
        raise ConfigError("--stride and --video together are not supported")
    recs = recordings(manifest, a.split, a.data)
    if a.only:
        missing = set(a.only) - {n for n, _ in recs}
        if missing:
            raise ConfigError(f"not in the {a.split} half: {', '.join(sorted(missing))}")
        recs = [(n, p) for n, p in recs if n in a.only]
    if not recs:
        raise ConfigError(f"no recordings in the {a.split} half of {a.manifest}")
    reports: dict[str, EvalReport] = {}
    for i, (name, path) in enumerate(recs, 1):
        print(f"[{i}/{len(recs)}] {name}", file=sys.stderr)
        reports[name] = score_recording(path, overrides=a.overrides, video_crf=a.video,
                                        downscale=a.downscale, stride=a.stride,
                                        rec=entries[name])
    pooled = pool(reports.values())
    if a.json:
        print(json.dumps({"split": a.split, "pooled": pooled.as_dict(),
                          "recordings": {n: r.as_dict() for n, r in reports.items()}},
                         indent=1))
        return 0
    if a.per_recording:
        for name, rep in reports.items():
            print(f"== {name}")
            print(format_pooled(pool([_labelled_only(rep)])) + "\n")
    video = "" if a.video is None else f", as H.264 video at CRF {a.video}"
    if a.downscale > 1:
        video += f", pictures shrunk {a.downscale}x"
    if a.stride > 1:
        video += f", every {a.stride}th frame"
    print(f"== {a.split}: {len(recs)} recordings, {pooled.frames} frames{video}")
    print(format_markdown(pooled) if a.markdown else format_pooled(_labelled_only(pooled)))
    return 0


def _labelled_only(rep: EvalReport) -> EvalReport:
    """Rows for conditions that were labelled or flagged (the others are all zeros)."""
    keep = [c for c in rep.conditions if c.episodes or c.frames_flagged]
    return EvalReport(conditions=keep, frames=rep.frames, labelled_frames=rep.labelled_frames,
                      healthy_frames=rep.healthy_frames, false_alarms=rep.false_alarms,
                      unknown_predicted=rep.unknown_predicted)


if __name__ == "__main__":
    from frontdiag.errors import FrontdiagError

    try:
        raise SystemExit(main())
    except FrontdiagError as exc:
        hint = f" ({exc.hint})" if exc.hint else ""
        print(f"score.py: {exc}{hint}", file=sys.stderr)
        raise SystemExit(2) from None
