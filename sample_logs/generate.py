"""Regenerate every sample log, its labels and this folder's README.md.

    python sample_logs/generate.py            # from the repository root

Deterministic: fixed seeds, so the same code writes the same bytes of image data. Sizes are kept
small (all together under 25 MB): 640x480 JPEG CompressedImage, a few seconds each, a 16-beam
LiDAR only where the scene is about it (and in the main demo).
"""

from __future__ import annotations

import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from frontdiag.sim.lidar import LidarSpec  # noqa: E402
from frontdiag.sim.run import SimOptions, labels_path_for, simulate  # noqa: E402
from frontdiag.sim.scenarios import SCENARIOS  # noqa: E402

SEED = 7
LIDAR = LidarSpec(beams=16, columns=256)


@dataclass(frozen=True)
class Log:
    file: str
    scenario: str
    fmt: str
    seconds: float
    rate: float = 10.0
    lidar: bool = False


LOGS = (
    Log("healthy_loop.mcap", "healthy_loop", "mcap", 3.0, lidar=True),
    Log("label_bank.bag", "label_bank", "bag", 4.0),
    Log("repetitive_aisle", "repetitive_aisle", "db3", 3.0),
    Log("planar_approach.mcap", "planar_approach", "mcap", 3.0),
    Log("side_wall.mcap", "side_wall", "mcap", 3.0),
    Log("dock_door.bag", "dock_door", "bag", 4.0),
    Log("dock_corridor.mcap", "dock_corridor", "mcap", 3.0, lidar=True),
    Log("parked_panning", "parked_panning", "db3", 4.0),
    Log("lights_out.mcap", "lights_out", "mcap", 4.0),
    Log("blank_wall.bag", "blank_wall", "bag", 2.0),
    Log("mixed.mcap", "mixed", "mcap", 16.0),
)

CONTAINER = {"mcap": "plain MCAP (ROS 2 cdr)", "bag": "ROS 1 bag", "db3": "ROS 2 bag (sqlite3)"}


def _size(p: Path) -> int:
    if p.is_dir():
        return sum(f.stat().st_size for f in p.rglob("*") if f.is_file())
    return p.stat().st_size


def main() -> int:
    rows = []
    total = 0
    for log in LOGS:
        out = HERE / log.file
        if out.is_dir():
            shutil.rmtree(out)
        elif out.exists():
            out.unlink()
        opts = SimOptions(seconds=log.seconds, seed=SEED, width=640, height=480,
                          rate_hz=log.rate, lidar=LIDAR if log.lidar else None,
                          compressed="jpeg", jpeg_quality=75)
        res = simulate(log.scenario, out, log.fmt, opts)
        size = _size(out) + _size(labels_path_for(out))
        total += size
        counts: dict[str, int] = {}
        for _, _, c in res.labels:
            counts[c] = counts.get(c, 0) + 1
        rows.append((log, res, size, counts))
        print(f"{log.file:24s} {res.frames:4d} frames {res.scans:4d} scans "
              f"{size / 1e6:5.2f} MB  {counts}")
    print(f"total {total / 1e6:.2f} MB")
    _readme(rows, total)
    return 0


def _readme(rows: list, total: int) -> None:
    lines = [
        "# sample_logs",
        "",
        "Small labelled recordings written by `frontdiag simulate`, one per scenario, in all "
        "three containers. Each has its labels beside it as `<recording>.labels.csv` "
        "(`t_start_ns,t_end_ns,condition`, inclusive intervals of header stamps; frames outside "
        "every interval are unlabelled). Camera: `/camera/image_raw/compressed` (JPEG, mono, "
        "640x480) with `/camera/camera_info`; `/odom`, `/ground_truth`, `/imu/data`, `/tf`; "
        "a 16-beam LiDAR on `/lidar/points` where the table says so.",
        "",
        "Run the main job on the demo log:",
        "",
        "```",
        "frontdiag analyze sample_logs/healthy_loop.mcap --out results/",
        "frontdiag eval results/ --labels sample_logs/healthy_loop.mcap.labels.csv",
        "```",
        "",
        "| file | container | scenario | what it shows | frames | LiDAR scans | label intervals | size |",
        "|---|---|---|---|---:|---:|---|---:|",
    ]
    for log, res, size, counts in rows:
        sc = SCENARIOS[log.scenario]
        labs = ", ".join(f"{k} ×{v}" for k, v in sorted(counts.items()))
        lines.append(f"| `{log.file}` | {CONTAINER[log.fmt]} | `{log.scenario}` | "
                     f"{sc.summary}; {sc.shows} | {res.frames} | {res.scans} | {labs} | "
                     f"{size / 1e6:.2f} MB |")
    lines += [
        "",
        f"Total: {total / 1e6:.1f} MB. Camera at 10 Hz, seed {SEED}. `repetitive_aisle` and "
        "`parked_panning` are ROS 2 bag folders.",
        "",
        "A condition label overrides `healthy` on the sensors that can show it (see "
        "`frontdiag/conditions.py`): in `dock_corridor` the interval is both "
        "`registration_degeneracy` (LiDAR rows) and `healthy` (camera rows).",
        "",
        "Regenerate (deterministic; a few minutes on one core):",
        "",
        "```",
        "python sample_logs/generate.py",
        "```",
        "",
        "Analyse every sample log, score the verdicts against the labels and print the key "
        "metrics per constructed label (works on any recordings with labels beside them):",
        "",
        "```",
        "python sample_logs/score.py [RECORDING ...]",
        "```",
        "",
        "Scenario details, the labelling rules and how to make longer or larger recordings: "
        "`docs/simulate.md`.",
        "",
    ]
    (HERE / "README.md").write_text("\n".join(lines))


if __name__ == "__main__":
    raise SystemExit(main())
