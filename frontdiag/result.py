"""The typed Python API: ``frontdiag.analyze(path, ...)`` with the CLI's option names.

    import frontdiag
    res = frontdiag.analyze("run.mcap", intrinsics=(615, 615, 320, 240), max_frames=300)
    res.gate.passed, res.gate.reasons          # what `analyze --fail-on fail` would decide
    df = res.to_pandas()                       # the per-frame table (frames.parquet)
    res.episodes                               # episodes.parquet, worst first
    res.manifest["topics"]                     # manifest.json
    res.save("results/")                       # the files `analyze --out results/` writes

Every keyword is the CLI option of the same name (``--camera-topic`` -> ``camera_topic``,
``--no-lidar`` -> ``no_lidar``, ``--rules`` -> ``rules``); nothing the CLI does needs the CLI.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import pandas as pd

if TYPE_CHECKING:
    from frontdiag.api import Analysis
    from frontdiag.verdicts import GateResult, Verdicts

log = logging.getLogger(__name__)

Intrinsics4 = tuple[float, float, float, float]


@dataclass
class Result:
    """One analysis: the table, its episodes and gate, and the manifest describing it."""

    table: pd.DataFrame
    """One row per analysed camera frame or LiDAR scan (the columns of frames.parquet)."""
    episodes: pd.DataFrame
    """Runs of one condition per topic, worst first (empty without rules)."""
    gate: GateResult | None
    """Exit code and reasons of the CI gate (None with ``no_rules=True``)."""
    manifest: dict[str, Any]
    notes: list[str] = field(default_factory=list)
    fault: str | None = None
    """Damage met part-way: the rows before it are kept and this names the file and where."""
    interrupted: bool = False
    verdicts: Verdicts | None = None
    analysis: Analysis | None = None

    def to_pandas(self) -> pd.DataFrame:
        """The per-frame table (a copy is not made; the manifest is in ``.attrs``)."""
        return self.table

    @property
    def passed(self) -> bool:
        return self.gate is None or self.gate.passed

    def save(self, out: Path | str, csv: bool = False, force: bool = False) -> list[Path]:
        """Write the result directory `analyze --out` writes; returns the files written."""
        from frontdiag.output import prepare_out_dir, refuse_overwrite, write_manifest, write_table

        out_dir = Path(out)
        refuse_overwrite(out_dir, force)
        inputs = [Path(self.manifest["input"]["path"])] if self.manifest.get("input") else []
        out_dir = prepare_out_dir(out_dir, inputs)
        written = list(write_table(out_dir, self.table, csv=csv))
        written.append(write_manifest(out_dir, self.manifest))
        if self.verdicts is not None and self.analysis is not None:
            from frontdiag.report import write_episodes, write_rules_snapshot

            written.append(write_episodes(out_dir, self.verdicts))
            written.append(write_rules_snapshot(out_dir, self.analysis.ruleset))
        return written


def _intrinsics_text(value: str | Sequence[float] | None) -> str | None:
    if value is None or isinstance(value, str):
        return value
    vals = [float(v) for v in value]
    if len(vals) != 4:
        from frontdiag.errors import ConfigError

        raise ConfigError(f"intrinsics {tuple(value)!r}: expected (fx, fy, cx, cy)")
    return ",".join(repr(v) for v in vals)


def analyze(
    log_path: Path | str,
    *,
    camera_topic: str | None = None,
    lidar_topic: str | None = None,
    odom_topic: str | None = None,
    no_camera: bool = False,
    no_lidar: bool = False,
    intrinsics: Intrinsics4 | Sequence[float] | str | None = None,
    camera_info: Path | str | None = None,
    start: float | None = None,
    end: float | None = None,
    max_frames: int | None = None,
    stride: int = 1,
    config: Path | str | None = None,
    features: int | None = None,
    ratio: float | None = None,
    no_mutual: bool = False,
    ransac_iters: int | None = None,
    lidar_backend: Literal["auto", "small_gicp", "open3d"] | None = None,
    rules: Path | str | None = None,
    no_default_rules: bool = False,
    overrides: Path | str | None = None,
    select: Sequence[str] | None = None,
    ignore: Sequence[str] | None = None,
    no_rules: bool = False,
    fail_on: Literal["warn", "fail", "never"] = "fail",
    max_fraction: dict[str, float] | None = None,
    baseline: Path | str | None = None,
    jobs: int = 1,
) -> Result:
    """Re-run the camera and LiDAR frontends on a recording and judge the result.

    The keywords are ``frontdiag analyze``'s options with dashes as underscores; intrinsics
    may be a tuple ``(fx, fy, cx, cy)``. Damage part-way through the recording keeps the rows
    before it (``Result.fault``); bad input or options raise
    :class:`frontdiag.errors.FrontdiagError` (a one-line message naming the file or option).
    """
    from frontdiag.api import AnalysisOptions, run_analysis
    from frontdiag.config import load_config

    cfg = load_config(Path(config) if config is not None else None, {
        "camera": {"n_features": features, "ratio": ratio,
                   "mutual": False if no_mutual else None, "ransac_max_iters": ransac_iters},
        "lidar": {"backend": lidar_backend}})
    rules_dir, extra = None, None
    if rules is not None:
        rules_dir, extra = (str(rules), None) if no_default_rules else (None, [str(rules)])
    opts = AnalysisOptions(
        camera_topic=camera_topic, lidar_topic=lidar_topic, odom_topic=odom_topic,
        use_camera=not no_camera, use_lidar=not no_lidar, intrinsics=_intrinsics_text(intrinsics),
        camera_info_file=str(camera_info) if camera_info is not None else None,
        start_s=start, end_s=end, max_frames=max_frames, stride=stride,
        camera_params=cfg.camera_params(), lidar_params=cfg.lidar_params(),
        rules=not no_rules, rules_dir=rules_dir, rules_extra=extra,
        rules_overrides=str(overrides) if overrides is not None else None,
        select=list(select) if select else None, ignore=list(ignore) if ignore else None,
        jobs=jobs)
    analysis = run_analysis(Path(log_path), opts)
    gate_result = None
    episodes = pd.DataFrame()
    if analysis.verdicts is not None:
        from frontdiag.verdicts import gate

        gate_result = gate(analysis.verdicts, fail_on=fail_on, max_fraction=max_fraction,
                           baseline=Path(baseline) if baseline is not None else None)
        episodes = analysis.verdicts.episodes
        if analysis.interrupted or analysis.fault is not None:
            from dataclasses import replace

            why = "interrupted" if analysis.interrupted else f"input damaged ({analysis.fault})"
            gate_result = replace(gate_result, exit_code=130 if analysis.interrupted else 2,
                                  reasons=[*gate_result.reasons, why], incomplete=why)
    if analysis.fault is not None:
        log.warning("%s", analysis.fault)
    return Result(table=analysis.table, episodes=episodes, gate=gate_result,
                  manifest=analysis.manifest, notes=list(analysis.notes),
                  fault=None if analysis.fault is None else str(analysis.fault),
                  interrupted=analysis.interrupted, verdicts=analysis.verdicts,
                  analysis=analysis)
