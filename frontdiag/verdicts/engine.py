"""Evaluate a ruleset over the per-frame table: per-row verdicts, episodes, run findings.

Rules see the rows of one (sensor, topic) in time order, because persistence windows and the
exposure-step check need neighbours. A frame hit survives persistence only where at least k of
some n consecutive rows containing it hit, which removes blips without stretching episodes.
Consecutive hits of one condition merge into an episode per topic; a gap of up to
`max_gap_frames` clean rows (rules/run.toml, default 1) does not split an episode.

Where the frontend started afresh (a gap in the recording, a change of image size: the row
statuses in ``RESTART_STATUSES``) the topic's rows fall into stretches that were never compared
with each other. Persistence windows and episodes stay inside one stretch: hits on both sides of
a 30 s pause are two episodes, and two hits before it and one after are not "3 of 5".
"""

from __future__ import annotations

import logging
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from frontdiag.conditions import CONDITIONS
from frontdiag.metrics import DEFAULT_FEATURE_BUDGET, keypoint_fill
from frontdiag.records import RESTART_STATUSES
from frontdiag.timing import median_rate_hz
from frontdiag.verdicts.checks import CHECKS, RunOutcome, col
from frontdiag.verdicts.loader import Ruleset
from frontdiag.verdicts.model import SEVERITY_RANK, Rule
from frontdiag.verdicts.operators import apply

log = logging.getLogger(__name__)

VERDICT_COLUMNS = ("conditions", "rules", "verdict")
_CLAUSE_PEAK = {"<": "min", "<=": "min", ">": "max", ">=": "max"}
_PEAK_WORD = {"absmax": "peak", "absdev1": "peak"}


@dataclass(frozen=True)
class RunFinding:
    rule: str
    condition: str
    severity: str
    fired: bool
    value: float
    message: str
    frames: list[int] = field(default_factory=list)
    evaluated: bool = True
    """False when the check could not run on this table (reported as "not evaluated")."""


@dataclass
class Verdicts:
    table: pd.DataFrame
    """The input plus `conditions` (list), `rules` (list) and `verdict` (ok / warn / fail)."""
    episodes: pd.DataFrame
    run_findings: list[RunFinding]
    ruleset: Ruleset
    hits: dict[str, np.ndarray]
    """Rule ID -> boolean per table row, after persistence."""
    notes: list[str] = field(default_factory=list)
    """Rows a rule's check declined to read, and why (one line per rule)."""

    def rule_frames(self, rule_id: str) -> int:
        return int(self.hits[rule_id].sum()) if rule_id in self.hits else 0


def topic_groups(table: pd.DataFrame, sensor: str) -> Iterator[tuple[str, np.ndarray]]:
    """(topic, positions in time order) for each topic of a sensor."""
    sensors = table["sensor"].astype(str).to_numpy() if "sensor" in table.columns \
        else np.full(len(table), "camera")
    topics = table["topic"].astype(str).to_numpy() if "topic" in table.columns \
        else np.full(len(table), "")
    t = col(table, "t_ns")
    order_key = t if not np.all(np.isnan(t)) else col(table, "frame")
    idx = np.flatnonzero(sensors == sensor)
    for topic in sorted(set(topics[idx])):
        pos = idx[topics[idx] == topic]
        yield topic, pos[np.argsort(order_key[pos], kind="stable")]


def restarts(rows: pd.DataFrame) -> np.ndarray:
    """Rows (of one topic, in time order) where the frontend started afresh: a gap in the
    recording or a change of image size. Each begins a stretch of its own."""
    if "status" not in rows.columns:
        return np.zeros(len(rows), dtype=bool)
    return rows["status"].astype(str).isin(RESTART_STATUSES).to_numpy()


def stretches(breaks: np.ndarray | None, m: int) -> list[tuple[int, int]]:
    """[start, end) of the stretches of m rows that ``breaks`` (True where a stretch begins)
    cut them into; one stretch without breaks."""
    starts = [0] if breaks is None else sorted({0, *np.flatnonzero(breaks).tolist()})
    return [(a, b) for a, b in zip(starts, [*starts[1:], m], strict=True) if a < b]


def persist(raw: np.ndarray, k: int, n: int, breaks: np.ndarray | None = None) -> np.ndarray:
    """Keep raw[i] only where some window of n consecutive rows containing i holds >= k hits.

    A topic with fewer than n rows is one window, and the same share of it must hit,
    ceil(k * rows / n): 2 of 3 rows for k = 3 of n = 5. Keeping k there would make a condition
    that fills a short recording (three panorama shots) impossible to report at all.

    ``breaks`` (True where the frontend started afresh) cut the rows into stretches, and no
    window spans two: each stretch is read as a recording of its own, the short-recording
    share included.
    """
    m = len(raw)
    if breaks is not None and breaks[1:].any():
        out = np.zeros(m, dtype=bool)
        for a, b in stretches(breaks, m):
            out[a:b] = persist(raw[a:b], k, n)
        return out
    if m == 0:
        return raw.copy()
    if m < n:
        k = max(1, -(-k * m // n))
        n = m
    counts = np.convolve(raw.astype(int), np.ones(n, dtype=int), mode="valid")
    good = (counts >= k).astype(int)
    covered = np.convolve(good, np.ones(n, dtype=int), mode="full")[:m] > 0
    return raw & covered


def frame_rate(rows: pd.DataFrame) -> float:
    """Frames per second of one topic's rows, from their stamps (``median_rate_hz``)."""
    return median_rate_hz(col(rows, "t_ns"))


def rule_mask(rule: Rule, rows: pd.DataFrame) -> np.ndarray:
    """Raw hits of one frame rule over the rows of one topic (time order), before persistence."""
    masks = [apply(c.op, col(rows, c.metric), c.value, use_abs=c.abs) for c in rule.when]
    if masks:
        combined = np.logical_and.reduce(masks) if rule.combine == "all" \
            else np.logical_or.reduce(masks)
    else:
        combined = np.ones(len(rows), dtype=bool)
    if rule.check is not None:
        chk = CHECKS[rule.check]
        assert chk.frame is not None
        params = rule.param_values()
        combined = combined & np.asarray(chk.frame(rows, params), dtype=bool)
    return combined


def _unread_notes(table: pd.DataFrame, rules: tuple[Rule, ...]) -> list[str]:
    notes = []
    for rule in rules:
        chk = CHECKS.get(rule.check or "")
        if chk is None or chk.unread is None:
            continue
        params = rule.param_values()
        n, why = 0, ""
        for _topic, pos in topic_groups(table, rule.sensor):
            mask, why = chk.unread(table.iloc[pos], params)
            n += int(np.count_nonzero(mask))
        if n:
            notes.append(f"{rule.id} ({rule.condition}) did not read {n} row(s): {why}")
    return notes


def add_baselines(table: pd.DataFrame, rules: tuple[Rule, ...]) -> None:
    """Add the recording's own level of every metric a rule reads against it (in place): the
    checks' ``baseline`` columns, per topic in time order."""
    for rule in rules:
        chk = CHECKS.get(rule.check or "")
        if chk is None or chk.baseline is None:
            continue
        params = rule.param_values()
        for _topic, pos in topic_groups(table, rule.sensor):
            cols = chk.baseline(table.iloc[pos], params)
            for name in cols.columns:
                if name not in table.columns:
                    table[name] = np.nan
                table.loc[table.index[pos], name] = cols[name].to_numpy()


def _frame_hits(table: pd.DataFrame, rules: tuple[Rule, ...]) -> dict[str, np.ndarray]:
    hits = {r.id: np.zeros(len(table), dtype=bool) for r in rules}
    for rule in rules:
        for _topic, pos in topic_groups(table, rule.sensor):
            rows = table.iloc[pos]
            raw = rule_mask(rule, rows)
            if rule.persistence is not None:
                raw = persist(raw, *rule.persistence.window(frame_rate(rows)),
                              breaks=restarts(rows))
            hits[rule.id][pos] = raw
    return hits


def _peak(values: np.ndarray, how: str) -> float:
    v = values[~np.isnan(values)]
    if v.size == 0:
        return float("nan")
    if how == "min":
        return float(v.min())
    if how == "max":
        return float(v.max())
    if how == "absmax":
        return float(v[np.argmax(np.abs(v))])
    if how == "absdev1":
        return float(v[np.argmax(np.abs(v - 1.0))])
    return float(np.median(v))


# a normalised metric is reported with the raw count users recognise
_COMPANIONS = {"keypoint_fill": ("n_keypoints", "min")}


def peak_spec(rule: Rule) -> dict[str, str]:
    """Metric -> which extreme is worst, for the metrics a rule reads."""
    spec = {c.metric: ("absmax" if c.abs else _CLAUSE_PEAK.get(c.op, "median")) for c in rule.when}
    if rule.check is not None:
        spec.update(CHECKS[rule.check].peaks)
    out: dict[str, str] = {}
    for name, how in spec.items():
        if name in _COMPANIONS:
            companion, chow = _COMPANIONS[name]
            out.setdefault(companion, chow)
        out[name] = how
    return out


def _runs(hit: np.ndarray, max_gap: int, restart: np.ndarray | None = None
          ) -> list[tuple[int, int]]:
    """(first, last) index pairs of runs of True, bridging gaps of <= max_gap False values;
    a run never spans a ``restart`` row (it begins a new one)."""
    out: list[tuple[int, int]] = []
    for a, b in stretches(restart, len(hit)):
        idx = np.flatnonzero(hit[a:b]) + a
        if idx.size == 0:
            continue
        cut = np.flatnonzero(np.diff(idx) > max_gap + 1)
        starts = np.concatenate([[idx[0]], idx[cut + 1]])
        ends = np.concatenate([idx[cut], [idx[-1]]])
        out += zip(starts.tolist(), ends.tolist(), strict=True)
    return out


def _raw(table: pd.DataFrame, name: str) -> np.ndarray:
    """A column as stored (int64 t_ns stays exact); NaN-filled object array where absent."""
    if name not in table.columns:
        return np.full(len(table), np.nan, dtype=object)
    return table[name].to_numpy()


def _exact_int(values: np.ndarray, pos: int) -> int:
    """An integer cell without a float round trip (t_ns exceeds float precision); -1 if absent."""
    v = values[pos]
    return -1 if pd.isna(v) else int(v)


def _fmt(v: float) -> str:
    return f"{v:.3g}" if abs(v) < 1000 else f"{v:.0f}"


def _weak_direction(table: pd.DataFrame, rows: np.ndarray) -> tuple[str, str]:
    """The LiDAR's weakest axis over an episode's hit rows (the most common of the categorical
    ``lidar_weak_axis``) and the most common words for it; empty for camera episodes."""
    if "lidar_weak_axis" not in table.columns or len(rows) == 0:
        return "", ""
    # NA-safe: with pandas' arrow-backed strings astype(str) keeps NA and comparisons give NA
    axes = table["lidar_weak_axis"].iloc[rows]
    axes = axes[axes.notna().to_numpy()].astype(str)
    axes = axes[~axes.isin(["", "nan", "None"]).to_numpy()]
    counts = axes.value_counts()
    if counts.empty:
        return "", ""
    top = str(counts.index[0])
    if "lidar_weak_dir" not in table.columns:
        return top, top
    words = table["lidar_weak_dir"].loc[axes.index][(axes == top).to_numpy()]
    wc = words[words.notna().to_numpy()].astype(str).value_counts()
    return top, str(wc.index[0]) if not wc.empty else top


def _episodes(table: pd.DataFrame, rules: tuple[Rule, ...], hits: dict[str, np.ndarray],
              t_rel: np.ndarray, max_gap: int) -> pd.DataFrame:
    records = []
    frames, t_ns = _raw(table, "frame"), _raw(table, "t_ns")
    cache: dict[str, np.ndarray] = {}

    def metric(name: str) -> np.ndarray:
        if name not in cache:
            cache[name] = col(table, name)
        return cache[name]

    for cond in CONDITIONS:
        crules = [r for r in rules if r.condition == cond]
        if not crules:
            continue
        sensor = crules[0].sensor
        for topic, pos in topic_groups(table, sensor):
            hit = np.logical_or.reduce([hits[r.id][pos] for r in crules])
            for a, b in _runs(hit, max_gap, restarts(table.iloc[pos])):
                span = pos[a:b + 1]
                in_ep = span[hit[a:b + 1]]
                fired = [r for r in crules if hits[r.id][in_ep].any()]
                worst = max(fired, key=lambda r: (SEVERITY_RANK[r.severity], -fired.index(r)))
                peaks: dict[str, float] = {}
                for r in fired:
                    for name, how in peak_spec(r).items():
                        rows = in_ep[hits[r.id][in_ep]]
                        peaks.setdefault(name, _peak(metric(name)[rows], how))
                rec: dict[str, Any] = {
                    "condition": cond, "rule": worst.id, "rules": [r.id for r in fired],
                    "severity": worst.severity, "sensor": sensor, "topic": topic,
                    "start_frame": _exact_int(frames, span[0]),
                    "end_frame": _exact_int(frames, span[-1]),
                    "start_t_ns": _exact_int(t_ns, span[0]),
                    "end_t_ns": _exact_int(t_ns, span[-1]),
                    "start_t_rel_s": float(t_rel[span[0]]), "end_t_rel_s": float(t_rel[span[-1]]),
                    "n_frames": len(in_ep), "n_rows": len(span),
                }
                rec["duration_s"] = max(rec["end_t_rel_s"] - rec["start_t_rel_s"], 0.0)
                shown = ", ".join(f"{m} {_PEAK_WORD.get(how, how)} {_fmt(peaks[m])}"
                                  for m, how in peak_spec(worst).items()
                                  if not np.isnan(peaks.get(m, np.nan)))
                rec["weak_axis"], rec["weak_dir"] = _weak_direction(table, in_ep)
                if rec["weak_dir"]:
                    shown = f"weakest direction {rec['weak_dir']}" + (f", {shown}" if shown
                                                                       else "")
                rec["summary"] = (f"{cond} [{worst.severity}] {topic} "
                                  f"{rec['start_t_rel_s']:.2f}-{rec['end_t_rel_s']:.2f} s, frames "
                                  f"{rec['start_frame']}-{rec['end_frame']} ({len(in_ep)} hit): "
                                  f"{worst.title}" + (f"; {shown}" if shown else ""))
                rec.update({f"peak_{m}": v for m, v in peaks.items()})
                records.append(rec)
    base_cols = ["condition", "rule", "rules", "severity", "sensor", "topic", "start_frame",
                 "end_frame", "start_t_ns", "end_t_ns", "start_t_rel_s", "end_t_rel_s",
                 "duration_s", "n_frames", "n_rows", "weak_axis", "weak_dir", "summary"]
    eps = pd.DataFrame.from_records(records, columns=None if records else base_cols)
    if eps.empty:
        return pd.DataFrame({c: pd.Series(dtype=object) for c in base_cols})
    peak_cols = sorted(c for c in eps.columns if c.startswith("peak_"))
    eps = eps[base_cols + peak_cols]
    return sort_worst_first(eps)


def sort_worst_first(eps: pd.DataFrame) -> pd.DataFrame:
    """Severity first, then the longest, then the earliest."""
    if eps.empty:
        return eps
    rank = eps["severity"].map(SEVERITY_RANK).to_numpy(dtype=int)
    order = np.lexsort((eps["start_t_rel_s"].to_numpy(dtype=float),
                        -eps["n_frames"].to_numpy(dtype=int), -rank))
    return eps.iloc[order].reset_index(drop=True)


def relative_time(table: pd.DataFrame) -> np.ndarray:
    """t_rel_s, or seconds since the first t_ns of the table when that column is absent."""
    if "t_rel_s" in table.columns:
        return col(table, "t_rel_s")
    t = col(table, "t_ns")
    if np.all(np.isnan(t)):
        return np.full(len(table), np.nan)
    return (t - np.nanmin(t)) / 1e9


def derive_missing(table: pd.DataFrame, manifest: Mapping[str, Any] | None = None) -> None:
    """Add derivable columns a table written by an older frontdiag lacks (in place)."""
    if "keypoint_fill" not in table.columns and "n_keypoints" in table.columns:
        params = ((manifest or {}).get("params") or {}).get("camera") or {}
        budget = float(params.get("n_features") or DEFAULT_FEATURE_BUDGET)
        table["keypoint_fill"] = keypoint_fill(col(table, "n_keypoints"), col(table, "width"),
                                               col(table, "height"), budget)


def copy_on_write() -> bool:
    """Whether pandas copies a shared column on its first write: always from pandas 3, by the
    ``mode.copy_on_write`` option in pandas 2."""
    if int(pd.__version__.split(".")[0]) >= 3:
        return True
    return pd.get_option("mode.copy_on_write") is True


def evaluate(table: pd.DataFrame, ruleset: Ruleset) -> Verdicts:
    """Run every rule of the ruleset over the per-frame table."""
    out = table.drop(columns=[c for c in VERDICT_COLUMNS if c in table.columns])
    if not copy_on_write():
        # the rules write columns of their own, never the input's; without copy-on-write
        # pandas may hand out views of the input, so they work on a copy (with it, the
        # result shares the input's columns: 25 MiB less at 30 000 frames)
        out = out.copy()
    out = out.reset_index(drop=True)
    derive_missing(out, table.attrs.get("manifest"))
    # pandas deep-copies attrs into every column it hands out: keep the (large) manifest
    # aside while the rules read columns, and put it back on the result
    out.attrs = {}
    add_baselines(out, ruleset.frame_rules)
    hits = _frame_hits(out, ruleset.frame_rules)
    n = len(out)
    conds: list[list[str]] = [[] for _ in range(n)]
    rule_ids: list[list[str]] = [[] for _ in range(n)]
    rank = np.zeros(n, dtype=int)
    order = {c: i for i, c in enumerate(CONDITIONS)}
    for rule in sorted(ruleset.frame_rules, key=lambda r: (order.get(r.condition, 99), r.id)):
        for i in np.flatnonzero(hits[rule.id]):
            if rule.condition not in conds[i]:
                conds[i].append(rule.condition)
            rule_ids[i].append(rule.id)
            rank[i] = max(rank[i], SEVERITY_RANK[rule.severity])
    names = {v: k for k, v in SEVERITY_RANK.items()}
    out["conditions"] = pd.Series(conds, dtype=object)
    out["rules"] = pd.Series(rule_ids, dtype=object)
    out["verdict"] = [names[r] for r in rank]
    findings = []
    for rule in ruleset.run_rules:
        chk = CHECKS[rule.check or ""]
        assert chk.run is not None
        outcome: RunOutcome = chk.run(out, rule.param_values())
        findings.append(RunFinding(rule.id, rule.condition, rule.severity, outcome.fired,
                                   outcome.value, outcome.message, outcome.frames,
                                   outcome.evaluated))
    episodes = _episodes(out, ruleset.frame_rules, hits, relative_time(out),
                         ruleset.run.episodes.max_gap_frames)
    notes = _unread_notes(out, ruleset.frame_rules)
    out.attrs = dict(table.attrs)
    return Verdicts(out, episodes, findings, ruleset, hits, notes)
