"""CI gating: turn verdicts into exit code 0 (pass) or 1 (gate failed) with the reasons.

Severity gates compare each finding's severity with --fail-on (warn / fail / never): frame
verdicts, run-level findings and the episode-length limits of rules/run.toml. Explicit gates
(--max-fraction, --baseline) apply whatever --fail-on says, because asking for them is the intent.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pandas as pd

from frontdiag.conditions import CONDITION_SENSORS, CONDITIONS
from frontdiag.errors import EXIT_GATE, EXIT_OK, ConfigError
from frontdiag.metrics import METRICS
from frontdiag.verdicts.checks import col
from frontdiag.verdicts.engine import Verdicts, evaluate
from frontdiag.verdicts.model import FRACTION_KEYS, SEVERITY_RANK

FailOn = Literal["warn", "fail", "never"]


@dataclass(frozen=True)
class GateResult:
    exit_code: int
    reasons: list[str]
    fail_on: str = "fail"
    failed_rules: list[str] = field(default_factory=list)
    """Rule IDs whose findings are at or above --fail-on (one JUnit failure each)."""
    incomplete: str | None = None
    """Why the run did not reach the end of the recording (interrupted, damaged input): such a
    run never passes, whatever its verdicts say."""

    @property
    def passed(self) -> bool:
        return self.exit_code == EXIT_OK


# Row statuses where the frontend estimated no motion: it lost track on that frame, whatever the
# rules name as the cause. The first frame of a sensor and a camera without intrinsics (whose
# pose is not computed by design) are not counted either way.
NO_POSE_STATUSES = frozenset({"too_few_matches", "essential_failed", "no_features",
                              "too_few_points", "low_overlap"})
NOT_POSED_BY_DESIGN = frozenset({"first_frame", "first_scan", "no_intrinsics"})


def no_pose_rows(table: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """(rows with no pose, rows where a pose was expected), from the ``status`` column; a
    frontend error on a row (``error: ...``) counts as no pose."""
    if "status" not in table or table.empty:
        none = np.zeros(len(table), dtype=bool)
        return none, ~none
    status = table["status"].astype(str)
    lost = (status.isin(NO_POSE_STATUSES) | status.str.startswith("error")).to_numpy()
    return lost, ~status.isin(NOT_POSED_BY_DESIGN).to_numpy()


@dataclass(frozen=True)
class NoPose:
    """The rows on which the frontend estimated no motion, as every report states them."""

    frames: int
    expected: int  # rows where a pose was expected
    unnamed: int  # of ``frames``, those with verdict ok: no rule named a cause
    statuses: dict[str, int]  # ``frames`` by status, most frequent first

    @property
    def share(self) -> float:
        return self.frames / self.expected if self.expected else 0.0

    @property
    def breakdown(self) -> str:
        """``too_few_matches 13, essential_failed 2``."""
        return ", ".join(f"{k} {v}" for k, v in self.statuses.items())

    def as_dict(self) -> dict[str, Any]:
        return {"frames": self.frames, "expected": self.expected, "unnamed": self.unnamed,
                "statuses": dict(self.statuses)}


def no_pose(table: pd.DataFrame) -> NoPose:
    """Count the rows with no pose (:func:`no_pose_rows`) of a table with verdicts."""
    lost, expected = no_pose_rows(table)
    if not lost.any():
        return NoPose(0, int(expected.sum()), 0, {})
    counts = table["status"].astype(str)[lost].value_counts()
    unnamed = lost & (table["verdict"].astype(str) == "ok").to_numpy() \
        if "verdict" in table else lost
    return NoPose(int(lost.sum()), int(expected.sum()), int(unnamed.sum()),
                  {str(k): int(v) for k, v in counts.items()})


def parse_max_fraction(items: list[str] | None) -> dict[str, float]:
    """`fail=0.02` style options (repeatable or comma-separated) -> {key: share}; the keys are
    a severity (share of rows at or above it) or ``nopose`` (share of rows with no pose)."""
    out: dict[str, float] = {}
    for item in items or []:
        for part in item.split(","):
            if not part.strip():
                continue
            key, sep, value = part.partition("=")
            key = key.strip()
            try:
                share = float(value)
            except ValueError:
                share = -1.0
            if not sep or key not in FRACTION_KEYS or not 0 <= share <= 1:
                raise ConfigError(f"--max-fraction {part!r}: expected warn=SHARE, fail=SHARE or "
                                  "nopose=SHARE with SHARE between 0 and 1 (e.g. fail=0.02, "
                                  "nopose=0.05)")
            out[key] = share
    return out


def _severity_reasons(result: Verdicts, threshold: int) -> tuple[list[str], list[str]]:
    reasons: list[str] = []
    failed: list[str] = []
    for rule in result.ruleset.frame_rules:
        k = result.rule_frames(rule.id)
        if k and SEVERITY_RANK[rule.severity] >= threshold:
            failed.append(rule.id)
            reasons.append(f"{rule.id} {rule.condition} [{rule.severity}]: {k} frame(s)")
    for f in result.run_findings:
        if f.fired and SEVERITY_RANK[f.severity] >= threshold:
            failed.append(f.rule)
            reasons.append(f"{f.rule} {f.condition} [{f.severity}]: {f.message}")
    eps = result.episodes
    for cond, limit in result.ruleset.run.episode_limits.items():
        if SEVERITY_RANK[limit.severity] < threshold or eps.empty:
            continue
        long = eps[(eps["condition"] == cond) & (eps["duration_s"] > limit.max_s)]
        for _, e in long.iterrows():
            reasons.append(f"episode limit: {cond} lasted {e['duration_s']:.1f} s > "
                           f"{limit.max_s:g} s ({e['topic']} {e['start_t_rel_s']:.2f}-"
                           f"{e['end_t_rel_s']:.2f} s)")
    return reasons, failed


def _fraction_reasons(result: Verdicts, limits: dict[str, float]) -> list[str]:
    n = len(result.table)
    if n == 0:
        return []
    rank = result.table["verdict"].map(SEVERITY_RANK).to_numpy()
    out = []
    for sev, limit in sorted(limits.items()):
        if sev == "nopose":
            lost = no_pose(result.table)
            if lost.share > limit:
                out.append(f"max-fraction: no pose on {lost.share:.1%} of {lost.expected} "
                           f"frames ({lost.breakdown}) > {limit:.1%}")
            continue
        share = float((rank >= SEVERITY_RANK[sev]).sum()) / n
        if share > limit:
            out.append(f"max-fraction: {share:.1%} of {n} frames at or above {sev} "
                       f"> {limit:.1%}")
    return out


def gate(result: Verdicts, fail_on: FailOn = "fail",
         max_fraction: dict[str, float] | None = None,
         baseline: Path | None = None) -> GateResult:
    """Decide the exit code of a run: 0 when no gate fails, 1 otherwise."""
    if fail_on not in ("warn", "fail", "never"):
        raise ConfigError(f"--fail-on {fail_on!r}: expected warn, fail or never")
    reasons: list[str] = []
    failed: list[str] = []
    if fail_on != "never":
        reasons, failed = _severity_reasons(result, SEVERITY_RANK[fail_on])
    limits = {k: v.value for k, v in result.ruleset.run.max_fraction.items()}
    limits.update(max_fraction or {})
    reasons += _fraction_reasons(result, limits)
    if baseline is not None:
        reasons += baseline_regressions(result, Path(baseline))
    return GateResult(EXIT_GATE if reasons else EXIT_OK, reasons, fail_on, failed)


# --- baseline -----------------------------------------------------------------------------------

def _read_result_table(result_dir: Path) -> pd.DataFrame:
    path = result_dir / "frames.parquet" if result_dir.is_dir() else result_dir
    if not path.exists():
        from frontdiag.output import result_dir_hint

        raise ConfigError(f"{result_dir}: no frames.parquet",
                          hint=result_dir_hint(result_dir, "pass the --out directory of an "
                                               "earlier `frontdiag analyze` run"))
    try:
        return pd.read_parquet(path)
    except Exception as exc:  # pyarrow raises several unrelated types for a damaged file
        raise ConfigError(f"{path}: cannot read the table ({exc})") from None


def _input_name(manifest: Any) -> str | None:
    """The recording's file name from a manifest ({"input": path or {"path": ...}})."""
    value = manifest.get("input") if isinstance(manifest, dict) else None
    if isinstance(value, dict):
        value = value.get("path") or value.get("name")
    return Path(str(value)).name if value else None


def _manifest_input(result_dir: Path) -> str | None:
    try:
        return _input_name(json.loads((result_dir / "manifest.json").read_text()))
    except (OSError, ValueError):
        return None


def _condition_share(table: pd.DataFrame, cond: str) -> float:
    sensors = CONDITION_SENSORS.get(cond, ("camera", "lidar"))
    rows = table[table["sensor"].isin(sensors)] if "sensor" in table.columns else table
    if len(rows) == 0 or "conditions" not in rows.columns:
        return 0.0
    return float(rows["conditions"].map(lambda c: cond in list(c)).mean())


def _metric_median(table: pd.DataFrame, metric: str) -> float:
    m = METRICS[metric]
    rows = table[table["sensor"] == m.sensor] if m.sensor != "any" and "sensor" in table.columns \
        else table
    v = col(rows, metric)
    return float(np.nanmedian(v)) if np.any(~np.isnan(v)) else float("nan")


def baseline_regressions(result: Verdicts, baseline_dir: Path) -> list[str]:
    """Regressions of this run against an earlier run of the same recording."""
    old = _read_result_table(baseline_dir)
    if "conditions" not in old.columns:
        old = evaluate(old, result.ruleset).table
    if baseline_dir.is_dir():
        attrs = result.table.attrs
        now_input = _input_name(attrs.get("manifest")) or _input_name(attrs)
        old_input = _manifest_input(baseline_dir)
        if now_input and old_input and now_input != old_input:
            raise ConfigError(f"--baseline {baseline_dir} was made from {old_input}, not "
                              f"{now_input}: compare runs of the same recording")
    cfg = result.ruleset.run.baseline
    out: list[str] = []
    for metric, tol in cfg.metric_median_rel_tol.items():
        before, now = _metric_median(old, metric), _metric_median(result.table, metric)
        if np.isnan(before) or np.isnan(now):
            continue
        scale = max(abs(before), 1e-9)
        change = (now - before) / scale
        better = METRICS[metric].better
        worse = -change if better == "higher" else change if better == "lower" else abs(change)
        if worse > tol.value:
            out.append(f"baseline: median {metric} {before:.4g} -> {now:.4g} "
                       f"({change:+.1%}, tolerance {tol.value:.0%})")
    for cond in CONDITIONS:
        before, now = _condition_share(old, cond), _condition_share(result.table, cond)
        if now - before > cfg.condition_share_abs_tol.value:
            out.append(f"baseline: {cond} on {now:.1%} of frames, was {before:.1%} "
                       f"(tolerance +{cfg.condition_share_abs_tol.value:.1%})")
    return out
