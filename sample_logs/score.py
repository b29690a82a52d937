"""Analyse recordings, score the verdicts against their labels, and show what was measured.

    python sample_logs/score.py                       # every sample log
    python sample_logs/score.py run1.mcap run2.bag    # any recordings with .labels.csv beside
    python sample_logs/score.py --simulate 13 320x240 [--seconds 6] [--rate 30] [--keep DIR]
                                                      # every scenario freshly simulated
    python sample_logs/score.py --video 23 [...]      # each camera re-encoded as H.264 first
                                                      # (validation/video.py; camera only)

Prints, per condition over all recordings: episodes found, frame precision/recall/F1 and false
alarms on healthy frames (the `frontdiag eval` numbers, summed); then the median [p10, p90] of
the key metrics per constructed label, so a scene can be checked against the reference numbers
independently of any rule.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from frontdiag.api import analyze  # noqa: E402
from frontdiag.conditions import CONDITION_SENSORS, HEALTHY  # noqa: E402
from frontdiag.errors import ConfigError  # noqa: E402
from frontdiag.scoring import (  # noqa: E402
    format_pooled,
    normalise_frames,
    pool,
    read_labels,
    score,
)
from frontdiag.sim.run import labels_path_for  # noqa: E402

CAMERA_METRICS = ("n_keypoints", "keypoint_fill", "entropy_norm", "entropy_inliers_norm",
                  "pose_info_cond", "ratio_reject_rate", "h_over_e",
                  "parallax_med_deg", "d_mean_intensity", "photo_residual_med")
LIDAR_METRICS = ("lidar_eig_min", "lidar_cond")


def _truth(t: int, sensor: str, labels: pd.DataFrame) -> str:
    inside = [c for a, b, c in labels.itertuples(index=False)
              if a <= t <= b and sensor in CONDITION_SENSORS[c]]
    if len(inside) > 1 and HEALTHY in inside:
        inside.remove(HEALTHY)
    return ";".join(inside) or "-"


def _q(s: pd.Series) -> str:
    s = s.dropna()
    if s.empty:
        return "—"
    return f"{s.median():.2f} [{s.quantile(0.1):.2f}, {s.quantile(0.9):.2f}]"


def simulate_all(seed: int, size: str, seconds: float | None, out: Path,
                 rate_hz: float = 15.0) -> list[Path]:
    """Every scenario at this seed, size and camera rate, with a 16x512 LiDAR, in ``out``."""
    from frontdiag.sim.lidar import LidarSpec
    from frontdiag.sim.run import SimOptions, simulate
    from frontdiag.sim.scenarios import SCENARIOS

    w, h = (int(v) for v in size.lower().split("x"))
    recs = []
    for name in SCENARIOS:
        opts = SimOptions(seconds=seconds, seed=seed, width=w, height=h, rate_hz=rate_hz,
                          lidar=LidarSpec(beams=16, columns=512))
        rec = out / f"s{seed}_{w}x{h}_{name}.mcap"
        simulate(name, rec, "mcap", opts)
        print(f"simulated {rec.name}", file=sys.stderr)
        recs.append(rec)
    return recs


CAMERA_CONDITIONS = tuple(c for c, s in CONDITION_SENSORS.items()
                          if s == ("camera",))


def _as_video(rec: Path, crf: int) -> pd.DataFrame:
    """The table of ``rec``'s camera re-encoded as H.264 (validation/video.py): the video
    recording holds the camera and its calibration only, so only camera conditions are
    scored."""
    import tempfile

    from validation.video import to_h264

    with tempfile.TemporaryDirectory() as tmp:
        video = to_h264(rec, Path(tmp) / f"{rec.name}.h264.mcap", crf=crf)
        return normalise_frames(analyze(video), source=str(rec))


def main(argv: list[str], video_crf: int | None = None) -> int:
    if argv[:1] in (["-h"], ["--help"]):
        print(__doc__)
        return 0
    if "--video" in argv:  # anywhere on the line: the camera re-encoded as H.264 at this CRF
        at = argv.index("--video")
        if at + 1 >= len(argv) or not argv[at + 1].isdigit():
            raise ConfigError("--video takes a CRF (an integer, e.g. 23)")
        return main(argv[:at] + argv[at + 2:], video_crf=int(argv[at + 1]))
    if argv[:1] == ["--simulate"]:
        import argparse
        import tempfile

        ap = argparse.ArgumentParser(prog="score.py --simulate")
        ap.add_argument("seed", type=int)
        ap.add_argument("size", help="WxH, e.g. 320x240")
        ap.add_argument("--seconds", type=float, default=None,
                        help="length of every scenario (default: each scenario's own)")
        ap.add_argument("--rate", type=float, default=15.0, help="camera rate, Hz (default 15)")
        ap.add_argument("--keep", type=Path, default=None, help="write the recordings here")
        a = ap.parse_args(argv[1:])
        if a.keep is not None:
            a.keep.mkdir(parents=True, exist_ok=True)
            return main([str(p) for p in simulate_all(a.seed, a.size, a.seconds, a.keep, a.rate)],
                        video_crf)
        with tempfile.TemporaryDirectory() as tmp:
            return main([str(p) for p in simulate_all(a.seed, a.size, a.seconds, Path(tmp), a.rate)],
                        video_crf)
    recs = [Path(a) for a in argv] or sorted(
        p for p in HERE.iterdir()
        if p.suffix in (".mcap", ".bag") or (p.is_dir() and (p / "metadata.yaml").exists()))
    reports = []
    rows = []
    for rec in recs:
        if not rec.exists():
            raise ConfigError(f"recording not found: {rec}")
        labels = read_labels(labels_path_for(rec))
        if video_crf is None:
            frames = normalise_frames(analyze(rec), source=str(rec))
            rep = score(frames, labels)
        else:
            frames = _as_video(rec, video_crf)
            rep = score(frames, labels, conditions=CAMERA_CONDITIONS)
        reports.append(rep)
        frames["label"] = [_truth(t, s, labels) for t, s in zip(frames["t_ns"], frames["sensor"],
                                                                strict=True)]
        rows.append(frames)
        print(f"{rec.name}: {len(frames)} rows, {rep.false_alarms}/{rep.healthy_frames} "
              "false alarms", file=sys.stderr)
    if video_crf is not None:
        print(f"camera re-encoded as H.264 at CRF {video_crf}; camera conditions only")
    print(format_pooled(pool(reports)) + "\n")
    table = pd.concat(rows, ignore_index=True)
    for sensor, metrics in (("camera", CAMERA_METRICS), ("lidar", LIDAR_METRICS)):
        part = table[table["sensor"] == sensor]
        if part.empty:
            continue
        print(f"{sensor}: median [p10, p90] per constructed label ('-' = unlabelled)")
        for label, g in part.groupby("label"):
            vals = []
            for m in metrics:
                if m not in g:
                    continue
                col = g[m].abs() if m == "d_mean_intensity" else g[m]
                vals.append(f"{m} {_q(col)}")
            print(f"  {label} (n={len(g)}): " + "; ".join(vals))
    return 0


if __name__ == "__main__":
    from frontdiag.errors import FrontdiagError

    try:
        raise SystemExit(main(sys.argv[1:]))
    except FrontdiagError as exc:
        print(f"score.py: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
