"""Score per-frame verdicts against labelled intervals, per condition.

Inputs are two tables:

- frames: one row per analysed frame with ``t_ns`` (header stamp), ``sensor`` (``camera`` or
  ``lidar``; a table without it is all camera), optionally ``topic``, and ``conditions`` (the
  condition names that fired: a list, or a ``;``-separated string as in CSV).
- labels: ``t_start_ns, t_end_ns, condition`` — inclusive intervals of header stamps
  (``<recording>.labels.csv``, written by ``frontdiag simulate``).

Semantics, per condition ``c``:

- Only rows of the sensors that can show ``c`` count (:data:`CONDITION_SENSORS`): a LiDAR
  corridor label is not held against the camera frames recorded at the same time.
- A row is *labelled* if any interval contains it; rows outside every interval are unlabelled
  and never count as errors.
- A row is *healthy for its sensor* if a ``healthy`` interval contains it and no interval of a
  condition its sensor can show does (a condition overrides ``healthy`` on its own sensors).
- Episodes are the labelled intervals of ``c`` (their rows of the relevant sensors, per sensor
  and topic). An episode is found when at least half its frames carry ``c``; an episode of one
  or two frames needs one.
- Frame precision counts ``c`` on labelled rows; a row just before or just after an episode
  (one frame of slack at each edge) is neither right nor wrong.
- The false-alarm rate is the share of healthy rows that carry any condition (overall), or
  ``c`` (per condition); the edge slack excuses these too.

Episode recall and the false-alarm rate carry a 95 % Wilson score interval (Wilson 1927;
Brown, Cai & DasGupta 2001 recommend it over the normal approximation for small counts): with
4 episodes, 3 found reads 0.75 but is consistent with anything from 0.30 to 0.95. Frame precision
carries none: the frames of one episode are not independent draws (a verdict holds over a
persistence window), so a binomial interval over frames would be far too narrow.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from frontdiag.conditions import CONDITION_SENSORS, CONDITIONS, HEALTHY, LABELS
from frontdiag.errors import ConfigError
from frontdiag.output import read_table

LABEL_COLUMNS = ("t_start_ns", "t_end_ns", "condition")

CONFIDENCE = 0.95
"""Level of the intervals on episode recall and the false-alarm rate."""


def wilson_interval(k: int, n: int, confidence: float = CONFIDENCE) -> tuple[float, float] | None:
    """The Wilson score interval of a proportion k/n (scipy's ``binomtest``); None when n is 0."""
    if n <= 0:
        return None
    from scipy.stats import binomtest

    ci = binomtest(k, n).proportion_ci(confidence_level=confidence, method="wilson")
    return float(ci.low), float(ci.high)


@dataclass
class ConditionScore:
    condition: str
    sensors: tuple[str, ...]
    episodes: int
    episodes_found: int
    frames_labelled: int
    frames_flagged: int
    true_positives: int
    false_positives: int
    healthy_frames: int
    false_alarms: int

    @property
    def episode_recall(self) -> float | None:
        return self.episodes_found / self.episodes if self.episodes else None

    @property
    def episode_recall_ci95(self) -> tuple[float, float] | None:
        return wilson_interval(self.episodes_found, self.episodes)

    @property
    def precision(self) -> float | None:
        n = self.true_positives + self.false_positives
        return self.true_positives / n if n else None

    @property
    def recall(self) -> float | None:
        return self.true_positives / self.frames_labelled if self.frames_labelled else None

    @property
    def f1(self) -> float | None:
        p, r = self.precision, self.recall
        if r == 0.0:  # nothing labelled was found: F1 is 0 whether or not anything was flagged
            return 0.0
        if p is None or r is None:
            return None
        return 2 * p * r / (p + r) if p + r else 0.0

    @property
    def false_alarm_rate(self) -> float | None:
        return self.false_alarms / self.healthy_frames if self.healthy_frames else None

    @property
    def false_alarm_rate_ci95(self) -> tuple[float, float] | None:
        return wilson_interval(self.false_alarms, self.healthy_frames)

    def as_dict(self) -> dict[str, Any]:
        return {"condition": self.condition, "sensors": list(self.sensors),
                "episodes": self.episodes, "episodes_found": self.episodes_found,
                "episode_recall": self.episode_recall,
                "episode_recall_ci95": _pair(self.episode_recall_ci95),
                "frames_labelled": self.frames_labelled,
                "frames_flagged": self.frames_flagged, "true_positives": self.true_positives,
                "false_positives": self.false_positives, "frame_precision": self.precision,
                "frame_recall": self.recall, "frame_f1": self.f1,
                "healthy_frames": self.healthy_frames, "false_alarms": self.false_alarms,
                "false_alarm_rate": self.false_alarm_rate,
                "false_alarm_rate_ci95": _pair(self.false_alarm_rate_ci95)}


def _pair(ci: tuple[float, float] | None) -> list[float] | None:
    return None if ci is None else [ci[0], ci[1]]


def format_interval(ci: tuple[float, float] | None, pct: bool = False, dash: str = "-",
                    missing: str = "-") -> str:
    """``0.30-0.95`` (or ``0.1-1.4 %`` with ``pct``) for an interval; ``missing`` for None."""
    if ci is None:
        return missing
    if pct:
        return f"{100 * ci[0]:.1f}{dash}{100 * ci[1]:.1f} %"
    return f"{ci[0]:.2f}{dash}{ci[1]:.2f}"


@dataclass
class EvalReport:
    conditions: list[ConditionScore]
    frames: int
    labelled_frames: int
    healthy_frames: int
    false_alarms: int
    unknown_predicted: list[str] = field(default_factory=list)

    @property
    def false_alarm_rate(self) -> float | None:
        return self.false_alarms / self.healthy_frames if self.healthy_frames else None

    @property
    def false_alarm_rate_ci95(self) -> tuple[float, float] | None:
        return wilson_interval(self.false_alarms, self.healthy_frames)

    def table(self) -> pd.DataFrame:
        return pd.DataFrame([c.as_dict() for c in self.conditions])

    def as_dict(self) -> dict[str, Any]:
        def clean(v: Any) -> Any:
            return None if isinstance(v, float) and math.isnan(v) else v

        return {"frames": self.frames, "labelled_frames": self.labelled_frames,
                "healthy_frames": self.healthy_frames, "false_alarms": self.false_alarms,
                "false_alarm_rate": self.false_alarm_rate,
                "false_alarm_rate_ci95": _pair(self.false_alarm_rate_ci95),
                "unknown_predicted": self.unknown_predicted,
                "conditions": [{k: clean(v) for k, v in c.as_dict().items()}
                               for c in self.conditions]}


# -- reading -----------------------------------------------------------------------------

def read_labels(path: Path | str) -> pd.DataFrame:
    """Read and validate a ``.labels.csv``."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"labels file not found: {p}")
    try:
        df = pd.read_csv(p, dtype={"condition": str})
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: not a labels CSV ({exc})") from exc
    missing = [c for c in LABEL_COLUMNS if c not in df.columns]
    if missing:
        raise ConfigError(f"{p}: missing column(s) {', '.join(missing)}",
                          hint="expected header: t_start_ns,t_end_ns,condition")
    df = df[list(LABEL_COLUMNS)].copy()
    df["condition"] = df["condition"].astype(str).str.strip()
    bad = sorted(set(df["condition"]) - set(LABELS))
    if bad:
        raise ConfigError(f"{p}: unknown condition(s) {', '.join(bad)}",
                          hint=f"known: {', '.join(LABELS)}")
    try:
        df["t_start_ns"] = df["t_start_ns"].astype("int64")
        df["t_end_ns"] = df["t_end_ns"].astype("int64")
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"{p}: timestamps must be integer nanoseconds ({exc})") from exc
    if (df["t_end_ns"] < df["t_start_ns"]).any():
        raise ConfigError(f"{p}: an interval ends before it starts")
    return df.reset_index(drop=True)


def split_conditions(value: Any) -> tuple[str, ...]:
    """A ``conditions`` cell (list, array, ``a;b`` string, empty or NaN) as a tuple."""
    if value is None:
        return ()
    if isinstance(value, float) and math.isnan(value):
        return ()
    if isinstance(value, str):
        parts: Iterable[Any] = value.replace(",", ";").split(";")
    elif isinstance(value, Iterable):
        parts = value
    else:
        return ()
    out = [str(v).strip() for v in parts]
    return tuple(v for v in out if v and v != HEALTHY)


def read_frames(path: Path | str) -> pd.DataFrame:
    """The per-frame table of an ``analyze --out`` directory (or a .parquet/.csv file)."""
    return normalise_frames(read_table(Path(path)), source=str(path))


def normalise_frames(df: pd.DataFrame, source: str = "frames") -> pd.DataFrame:
    """Check the columns scoring needs; add ``sensor`` (camera) and parse ``conditions``."""
    if "t_ns" not in df.columns or "conditions" not in df.columns:
        raise ConfigError(f"{source}: the per-frame table needs columns t_ns and conditions",
                          hint="run `frontdiag analyze` with the rules to get verdicts")
    out = df.copy()
    if "sensor" not in out.columns:
        out["sensor"] = "camera"
    out["sensor"] = out["sensor"].fillna("camera").astype(str)
    out["t_ns"] = out["t_ns"].astype("int64")
    out["conditions"] = [split_conditions(v) for v in out["conditions"]]
    return out


# -- scoring -------------------------------------------------------------------------------

def _inside(t: np.ndarray, labels: pd.DataFrame) -> np.ndarray:
    """(n_rows, n_intervals) boolean: interval j contains row i."""
    a = labels["t_start_ns"].to_numpy(np.int64)
    b = labels["t_end_ns"].to_numpy(np.int64)
    return (t[:, None] >= a[None, :]) & (t[:, None] <= b[None, :])


def score(frames: pd.DataFrame, labels: pd.DataFrame, *, slack: int = 1,
          conditions: Iterable[str] | None = None) -> EvalReport:
    """Score a per-frame table against label intervals (see the module docstring)."""
    f = normalise_frames(frames)
    keys = ["sensor", "topic"] if "topic" in f.columns else ["sensor"]
    f = f.sort_values([*keys, "t_ns"], kind="stable").reset_index(drop=True)
    t = f["t_ns"].to_numpy(np.int64)
    sensor = f["sensor"].to_numpy()
    group = f[keys].astype(str).agg("/".join, axis=1).to_numpy() if len(f) else np.array([])
    # position of each row inside its sensor/topic stream, for the edge slack
    pos = f.groupby(keys, sort=False).cumcount().to_numpy() if len(f) else np.array([], int)
    inside = _inside(t, labels) if len(labels) else np.zeros((len(f), 0), bool)
    lab_cond = labels["condition"].to_numpy()
    labelled = inside.any(axis=1)
    in_cond = {c: inside[:, lab_cond == c].any(axis=1) for c in LABELS}
    pred_sets = list(f["conditions"])
    known = set(CONDITIONS)
    unknown = sorted({c for s in pred_sets for c in s} - known)
    pred = {c: np.array([c in s for s in pred_sets], bool) for c in CONDITIONS}

    # healthy for the row's own sensor: in a healthy interval, in no interval of a condition
    # that sensor can show
    healthy = in_cond[HEALTHY].copy()
    for c in CONDITIONS:
        shows = np.isin(sensor, CONDITION_SENSORS[c])
        healthy &= ~(in_cond[c] & shows)

    wanted = list(conditions) if conditions is not None else [
        c for c in CONDITIONS if in_cond[c].any() or pred[c].any()]
    scores: list[ConditionScore] = []
    alarm_any = np.zeros(len(f), bool)
    for c in CONDITIONS:
        rows = np.isin(sensor, CONDITION_SENSORS[c])
        truth = in_cond[c] & rows
        p = pred[c] & rows
        slack_rows = np.zeros(len(f), bool)
        n_ep = n_found = 0
        for j in np.nonzero(lab_cond == c)[0]:
            ep = inside[:, j] & rows
            for g in np.unique(group[ep]):
                idx = np.nonzero(ep & (group == g))[0]
                n = len(idx)
                hits = int(p[idx].sum())
                n_ep += 1
                if (n <= 2 and hits >= 1) or (n > 2 and hits >= 0.5 * n):
                    n_found += 1
                if slack > 0:
                    in_g = np.nonzero(group == g)[0]
                    lo, hi = pos[idx].min(), pos[idx].max()
                    near = in_g[((pos[in_g] >= lo - slack) & (pos[in_g] < lo))
                                | ((pos[in_g] > hi) & (pos[in_g] <= hi + slack))]
                    slack_rows[near] = True
        tp = int((p & truth).sum())
        fp = int((p & ~truth & labelled & ~slack_rows).sum())
        h_rows = healthy & rows
        alarms = p & h_rows & ~slack_rows
        alarm_any |= alarms
        if c not in wanted:
            continue
        scores.append(ConditionScore(
            condition=c, sensors=CONDITION_SENSORS[c], episodes=n_ep, episodes_found=n_found,
            frames_labelled=int(truth.sum()), frames_flagged=int(p.sum()), true_positives=tp,
            false_positives=fp, healthy_frames=int(h_rows.sum()),
            false_alarms=int(alarms.sum())))
    order = {c: i for i, c in enumerate(wanted)}
    scores.sort(key=lambda s: order[s.condition])
    return EvalReport(conditions=scores, frames=len(f), labelled_frames=int(labelled.sum()),
                      healthy_frames=int(healthy.sum()), false_alarms=int(alarm_any.sum()),
                      unknown_predicted=unknown)


# -- pooling over recordings ---------------------------------------------------------------

_COUNTS = ("episodes", "episodes_found", "frames_labelled", "frames_flagged", "true_positives",
           "false_positives", "healthy_frames", "false_alarms")


def pool(reports: Iterable[EvalReport]) -> EvalReport:
    """Sum the counts of several recordings' reports per condition (pooled scores).

    Ratios are recomputed from the summed counts, so a long recording weighs by its frames.
    Conditions come in :data:`CONDITIONS` order.
    """
    by: dict[str, ConditionScore] = {}
    frames = labelled = healthy = alarms = 0
    unknown: set[str] = set()
    for r in reports:
        frames += r.frames
        labelled += r.labelled_frames
        healthy += r.healthy_frames
        alarms += r.false_alarms
        unknown.update(r.unknown_predicted)
        for c in r.conditions:
            s = by.setdefault(c.condition, ConditionScore(c.condition, c.sensors,
                                                          *([0] * len(_COUNTS))))
            for k in _COUNTS:
                setattr(s, k, getattr(s, k) + getattr(c, k))
    rank = {c: i for i, c in enumerate(CONDITIONS)}
    conds = sorted(by.values(), key=lambda s: rank.get(s.condition, len(rank)))
    return EvalReport(conditions=conds, frames=frames, labelled_frames=labelled,
                      healthy_frames=healthy, false_alarms=alarms,
                      unknown_predicted=sorted(unknown))


def format_markdown(report: EvalReport) -> str:
    """A (pooled) report as a Markdown table, one row per condition with labelled episodes:
    episodes found, episode recall with its 95 % interval, frame precision and false alarms on
    healthy frames, then the overall false-alarm rate with its interval; conditions flagged
    but never labelled are named under the table (their precision is 0 by construction)."""
    def num(v: float | None) -> str:
        return "-" if v is None else f"{v:.2f}"

    lines = ["| condition | episodes found | episode recall (95 % interval) | frame precision "
             "| false alarms |", "|---|---|---|---|---|"]
    unlabelled = []
    for c in report.conditions:
        if not c.episodes:
            if c.frames_flagged:
                unlabelled.append(f"{c.condition} ({c.frames_flagged} frames)")
            continue
        ci = format_interval(c.episode_recall_ci95, dash="–")
        lines.append(f"| {c.condition} | {c.episodes_found}/{c.episodes} | "
                     f"{num(c.episode_recall)} ({ci}) | {num(c.precision)} | "
                     f"{c.false_alarms}/{c.healthy_frames} |")
    rate = report.false_alarm_rate
    share = "-" if rate is None else f"{100 * rate:.1f} %"
    ci = format_interval(report.false_alarm_rate_ci95, pct=True, dash="–").removesuffix(" %")
    lines.append(f"| all conditions, healthy frames | | | | {report.false_alarms}/"
                 f"{report.healthy_frames} ({share}; {ci} %) |")
    if unlabelled:
        lines.append("")
        lines.append("Flagged but never labelled in these recordings: " + ", ".join(unlabelled)
                     + ".")
    return "\n".join(lines)


def format_pooled(report: EvalReport) -> str:
    """Plain-text table of a (pooled) report: episodes found with the 95 % interval of episode
    recall, frame precision / recall / F1, false alarms on healthy frames per condition, then
    the overall false-alarm rate with its interval."""
    def f(v: float | None) -> str:
        return "  nan" if v is None else f"{v:5.2f}"

    lines = [f"{'condition':24s} {'found':>7s} {'95% CI':>9s} {'prec':>5s} {'recall':>6s} "
             f"{'F1':>5s} {'FA':>9s}"]
    for c in report.conditions:
        lines.append(f"{c.condition:24s} {c.episodes_found:>3d}/{c.episodes:<3d} "
                     f"{format_interval(c.episode_recall_ci95):>9s} {f(c.precision)} "
                     f"{f(c.recall):>6s} {f(c.f1)} {c.false_alarms:>4d}/{c.healthy_frames:<4d}")
    rate = report.false_alarm_rate
    lines.append(f"false alarms on healthy frames: {report.false_alarms}/{report.healthy_frames}"
                 f" = {float('nan') if rate is None else rate:.3f} "
                 f"(95% CI {format_interval(report.false_alarm_rate_ci95, pct=True)})")
    lines.append("95% CI: Wilson score interval of episode recall (episodes found / labelled) "
                 "and of the false-alarm rate")
    return "\n".join(lines)
