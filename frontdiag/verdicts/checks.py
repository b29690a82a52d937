"""Named checks: the logic a single `metric op value` clause cannot hold, registered in one dict.

A rule refers to a check by name and supplies every threshold the check uses as `params` in the
rules file, so the numbers stay data (with reasons) and users override them like any clause.

Frame checks receive the rows of one topic in time order and return one boolean per row; they
also explain a single row in words, naming the look-alike each value rules out. Run checks see
the whole table and return one finding.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import pandas as pd

from frontdiag.camera.geometry import homography_threshold_px
from frontdiag.records import SIZE_STATUS
from frontdiag.verdicts.baseline import rolling_baseline, widening_baseline

Params = Mapping[str, Any]


def col(df: pd.DataFrame, name: str) -> np.ndarray:
    """A column as float64 (NaN where absent or not numeric)."""
    if name not in df.columns:
        return np.full(len(df), np.nan)
    return pd.to_numeric(df[name], errors="coerce").to_numpy(dtype=float, na_value=np.nan)


def _v(row: Mapping[str, Any], name: str) -> float:
    try:
        return float(row.get(name, np.nan))
    except (TypeError, ValueError):
        return float("nan")


def _fmt(x: float) -> str:
    return "n/a" if np.isnan(x) else f"{x:.4g}"


@dataclass(frozen=True)
class RunOutcome:
    fired: bool
    value: float
    message: str
    frames: list[int] = field(default_factory=list)
    """`frame` numbers of the rows that drive the finding (for the report)."""
    evaluated: bool = True
    """False when the check could not run (no rows of its sensor, too few usable frames): such
    a finding is "not evaluated", never "ok"."""


@dataclass(frozen=True)
class Check:
    name: str
    summary: str
    scope: Literal["frame", "run"]
    sensor: Literal["camera", "lidar"]
    metrics: tuple[str, ...]
    params: Mapping[str, str]
    """Param name -> kind: "number" or "choice:a|b|c"."""
    peaks: Mapping[str, str]
    """Metric -> which extreme is the worst in an episode: "min", "max" or "absmax"."""
    param_metrics: Mapping[str, str] = field(default_factory=dict)
    """Param name -> the metric it is a threshold on (for units and `frontdiag explain`)."""
    frame: Callable[[pd.DataFrame, Params], np.ndarray] | None = None
    explain: Callable[[Mapping[str, Any], Params], list[str]] | None = None
    context: Callable[[pd.DataFrame, Params], pd.DataFrame] | None = None
    """Derived per-row values (from neighbours) that `explain` shows next to the row's own."""
    run: Callable[[pd.DataFrame, Params], RunOutcome] | None = None
    optional: frozenset[str] = frozenset()
    """Params a rule may leave out (the check then skips what they gate)."""
    unread: Callable[[pd.DataFrame, Params], tuple[np.ndarray, str]] | None = None
    """Rows the check declines to read whatever their values, and why (for a run note)."""
    baseline: Callable[[pd.DataFrame, Params], pd.DataFrame] | None = None
    """Columns of the recording's own level (verdicts/baseline.py) that the engine adds to the
    table, per topic in time order, before any rule reads it."""

    def param_problem(self, name: str, value: Any) -> str | None:
        kind = self.params.get(name)
        if kind is None:
            return f"check {self.name!r} has no param {name!r} (known: {', '.join(self.params)})"
        if kind == "number":
            ok = isinstance(value, int | float) and not isinstance(value, bool)
            return None if ok else f"param {name!r} of check {self.name!r} must be a number"
        choices = kind.split(":", 1)[1].split("|")
        if value not in choices:
            return f"param {name!r} of check {self.name!r} must be one of {choices}, got {value!r}"
        return None


# --- §3 of docs/derivations.md: feature count x ratio-test rejection --------------------------------------------

def _after_step(dmean: np.ndarray, step: float, frames: int) -> np.ndarray:
    """True on each row within `frames` rows after (and at) a |d_mean_intensity| > step row."""
    with np.errstate(invalid="ignore"):
        jump = np.abs(dmean) > step
    out = np.zeros(len(jump), dtype=bool)
    for lag in range(max(int(frames), 0) + 1):
        out[lag:] |= jump[: len(jump) - lag]
    return out


def frame_interval_s(df: pd.DataFrame) -> np.ndarray:
    """Seconds since the previous row of the same topic (NaN on the first): the baseline in time
    the frame was matched across (``--stride``, a low-rate recording and dropped frames widen it)."""
    t = col(df, "t_ns")
    return np.concatenate([[np.nan], np.diff(t) / 1e9]) if len(t) else t


def _wide_interval(df: pd.DataFrame, p: Params) -> np.ndarray:
    if "max_interval_s" not in p:
        return np.zeros(len(df), dtype=bool)
    with np.errstate(invalid="ignore"):
        return frame_interval_s(df) > p["max_interval_s"]


def _restarts(df: pd.DataFrame) -> np.ndarray:
    """Rows where the camera's image size changed: the scene-dependent levels before them
    (rejection, residual, feature count) belong to another camera setting."""
    if "status" not in df.columns:
        return np.zeros(len(df), dtype=bool)
    return (df["status"].astype(str) == SIZE_STATUS).to_numpy()


def _scene_baseline(df: pd.DataFrame, p: Params, metric: str, exclude: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    t = col(df, "t_ns") / 1e9
    return rolling_baseline(t, col(df, metric), p["baseline_window_s"],
                            int(p["baseline_min_rows"]), p["baseline_min_share"], exclude,
                            breaks=_restarts(df))


def _matching_baseline(df: pd.DataFrame, p: Params) -> pd.DataFrame:
    """The scene's own rejection: rows near an exposure step, matched across a wide interval
    or at/above the absolute line are left out (each is already read as something else)."""
    if "reject_excess" not in p:
        return pd.DataFrame(index=range(len(df)))
    rej = col(df, "ratio_reject_rate")
    with np.errstate(invalid="ignore"):
        near = _after_step(col(df, "d_mean_intensity"), p["dmean_step"], p["recovery_frames"])
        exclude = near | _wide_interval(df, p) | (rej >= p["reject_repetitive"])
    # no level within the window (a street that sits at the line for seconds): the nearest
    # level of the recording's own, before the absolute line (a rule without
    # baseline_widen_max_s keeps its window)
    base, sig, used = widening_baseline(
        col(df, "t_ns") / 1e9, rej, p["baseline_window_s"], int(p["baseline_min_rows"]),
        p["baseline_min_share"], exclude, max_window_s=_widen_max_s(p), breaks=_restarts(df))
    kp_base, _ = _scene_baseline(df, p, "n_keypoints", _wide_interval(df, p))
    return pd.DataFrame({"ratio_reject_base": base, "ratio_reject_base_sigma": sig,
                         "ratio_reject_base_window_s": used, "n_keypoints_base": kp_base})


def _widen_max_s(p: Params) -> float:
    """The widest window FD-REP-001's baseline may take (its own window if it does not widen)."""
    return float(max(p.get("baseline_widen_max_s", 0), p["baseline_window_s"]))


def reject_excess(rej: np.ndarray, base: np.ndarray) -> np.ndarray:
    """Share of the matches the scene's own level keeps that this frame refuses:
    (rejection - baseline) / (1 - baseline); 0 at the scene's level, 1 when all are refused."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return (rej - base) / (1.0 - base)


def _relative_repetition(df: pd.DataFrame, p: Params) -> tuple[np.ndarray, np.ndarray]:
    """(has a baseline, jumps above it) per row: the repetition signature read against the
    recording's own level, at an unchanged feature count."""
    rej, base = col(df, "ratio_reject_rate"), col(df, "ratio_reject_base")
    sig, kp, kp_base = col(df, "ratio_reject_base_sigma"), col(df, "n_keypoints"), \
        col(df, "n_keypoints_base")
    has = ~np.isnan(base)
    with np.errstate(invalid="ignore"):
        jump = ((reject_excess(rej, base) >= p["reject_excess"])
                & (rej - base > p["baseline_sigmas"] * sig)
                & ~(kp < p["keypoints_kept"] * kp_base))
    return has, jump


def _copies_in_frame(df: pd.DataFrame, p: Params) -> np.ndarray:
    """Rows whose scene repeats itself within the frame (in_frame_twin_rate at or above
    twins_in_frame); every row where the rule or the table does not carry the reading."""
    if "twins_in_frame" not in p or "in_frame_twin_rate" not in df.columns:
        return np.ones(len(df), bool)
    with np.errstate(invalid="ignore"):
        return col(df, "in_frame_twin_rate") >= p["twins_in_frame"]


def _matching_table(df: pd.DataFrame, p: Params) -> np.ndarray:
    """Features intact, outside an exposure step's recovery and matched at a tracking rate;
    then the rejection read against the scene's own level where the recording has one (the
    absolute line where it has none: a recording that is one long aisle). Whichever reading
    fires, the frame must also show copies of its own features (in_frame_twin_rate): the
    rejection says that the ratio test refused, the copies say why."""
    fill = col(df, "keypoint_fill")
    rej = col(df, "ratio_reject_rate")
    with np.errstate(invalid="ignore"):
        near_step = _after_step(col(df, "d_mean_intensity"), p["dmean_step"], p["recovery_frames"])
        readable = (fill >= p["fill_floor"]) & ~near_step & ~_wide_interval(df, p)
        absolute = rej >= p["reject_repetitive"]
    if "reject_excess" in p:
        has, jump = _relative_repetition(df, p)
        hit = readable & np.where(has, jump, absolute)
    else:
        hit = readable & absolute
    if "ambiguous_repetitive" in p:
        # twins: refused with a second candidate as good as a match; a wider interval makes
        # candidates less alike, not more, and a gain step makes them darker or brighter
        # together, so this reading holds at any frame rate and across a step
        with np.errstate(invalid="ignore"):
            twins = col(df, "ratio_ambiguous_rate") >= p["ambiguous_repetitive"]
            hit |= (fill >= p["fill_floor"]) & twins
    return hit & _copies_in_frame(df, p)


def _matching_unread(df: pd.DataFrame, p: Params) -> tuple[np.ndarray, str]:
    # a row with no rejection reading (first frame, after a gap) had nothing to decline
    wide = _wide_interval(df, p) & ~np.isnan(col(df, "ratio_reject_rate"))
    why = (f"matched across more than {p.get('max_interval_s', np.nan):g} s (slower than 3 Hz: "
           "--stride, a low-rate recording or dropped frames); read repetition at the "
           "recording's own rate")
    if "ambiguous_repetitive" not in p:
        return wide, why
    # the twins reading holds at any interval and still reads these rows: only the rejection
    # lines are declined, which is all a row the twins reading found lacks (it is reported)
    with np.errstate(invalid="ignore"):
        twins = col(df, "ratio_ambiguous_rate") >= p["ambiguous_repetitive"]
    return wide & ~twins, (
        f"{why}. Its twins reading (ratio_ambiguous_rate >= {p['ambiguous_repetitive']:g}), "
        "which holds at any interval, read these rows and stayed under its line")


def _matching_context(df: pd.DataFrame, p: Params) -> pd.DataFrame:
    return pd.DataFrame({"frame_interval_s": frame_interval_s(df)})


def _fill_words(kp: float, fill: float) -> str:
    return f"keypoint_fill {_fmt(fill)} ({_fmt(kp)} keypoints)"


def _relative_rejection_words(row: Mapping[str, Any], p: Params) -> str:
    rej, base, sig = (_v(row, m) for m in ("ratio_reject_rate", "ratio_reject_base",
                                           "ratio_reject_base_sigma"))
    kp, kp_base = _v(row, "n_keypoints"), _v(row, "n_keypoints_base")
    if np.isnan(base):
        span = f"{p['baseline_window_s']:g} s"
        if _widen_max_s(p) > p["baseline_window_s"]:
            span += ", nor in any wider window of the recording"
        return (f"relative: no baseline of the recording's own (fewer than "
                f"{p['baseline_min_rows']:g} rows, or under {p['baseline_min_share']:.0%} of "
                f"them, below the absolute line within {span}): the absolute line decides")
    exc = float(reject_excess(np.array([rej]), np.array([base]))[0])
    above = exc >= p["reject_excess"] and rej - base > p["baseline_sigmas"] * sig
    kept = not kp < p["keypoints_kept"] * kp_base
    win = _v(row, "ratio_reject_base_window_s")
    within = f"{p['baseline_window_s']:g} s"
    if not np.isnan(win) and win > p["baseline_window_s"]:
        within = (f"{win:.3g} s; no level formed within {p['baseline_window_s']:g} s, so the "
                  "window widened to the nearest level of the recording's own")
    words = (f"relative (decides): scene baseline {base:.0%} (robust sigma {sig:.1%}, lower "
             f"quartile of the rows under the absolute line within {within}); this "
             f"frame refuses {exc:.0%} of what the scene keeps (line {p['reject_excess']:.0%}, "
             f"and > {p['baseline_sigmas']:g} sigma); keypoints {kp:.0f} vs the scene's "
             f"{kp_base:.0f}")
    if above and kept:
        return words + ": a jump at an unchanged feature count, the repetition signature"
    if above:
        return words + ": the jump came with a loss of features, not repetition"
    return words + ": at the scene's own level, repetitive_structure ruled out"


def _copies_words(twin: float, line: float, dist: float = float("nan")) -> str:
    if np.isnan(twin):
        return ("in_frame_twin_rate not computable (fewer than two keypoints): no evidence that "
                "the scene repeats itself, so repetitive_structure is not read")
    within = ""
    if not np.isnan(dist):
        within = (f"; the frame's accepted matches lie a median {dist:.0f} bits from theirs, "
                  "and a copy counts within that over the ratio test's ratio (match_dist_med)")
    if twin >= line:
        return (f"in_frame_twin_rate {twin:.0%} >= {line:.0%}: the scene repeats itself (that "
                "share of the frame's features has a copy elsewhere in the same view, as close "
                f"as the frame's matches are to theirs, so the ratio test refuses their matches"
                f"{within})")
    return (f"in_frame_twin_rate {twin:.0%} < {line:.0%}: few features have a copy in the same "
            f"view{within}, so the ratio test's refusals are not repetition's (a wide baseline, "
            "blur or compression refuse features that nothing resembles): repetitive_structure "
            "ruled out")


def _matching_table_explain(row: Mapping[str, Any], p: Params) -> list[str]:
    kp, fill, rej = (_v(row, m) for m in ("n_keypoints", "keypoint_fill", "ratio_reject_rate"))
    dm = _v(row, "d_mean_intensity")
    out = []
    if np.isnan(fill):
        return ["keypoint_fill not computable: the three-way matching table (docs/derivations.md §3) cannot be read"]
    if fill < p["fill_floor"]:
        out.append(f"{_fill_words(kp, fill)} < {p['fill_floor']:g}: detection failed (reference: "
                   "~120 of 1000); repetitive structure ruled out, whatever the rejection rate")
        return out
    out.append(f"{_fill_words(kp, fill)} >= {p['fill_floor']:g}: detection_failure ruled out "
               "(features are fine)")
    if np.isnan(rej):
        out.append("ratio_reject_rate not computable (no previous frame)")
    elif rej >= p["reject_repetitive"]:
        out.append(f"absolute: ratio_reject_rate {rej:.0%} >= {p['reject_repetitive']:.0%}: the "
                   "ratio test refuses as much as on repetitive structure (~85%)")
    else:
        out.append(f"absolute: ratio_reject_rate {rej:.0%} < {p['reject_repetitive']:.0%} "
                   "(in the reference scene: healthy ~30%, exposure step ~55%"
                   + ("; the relative reading below is this recording's own)"
                      if "reject_excess" in p else ")"))
    if "reject_excess" in p and not np.isnan(rej):
        out.append(_relative_rejection_words(row, p))
    amb = _v(row, "ratio_ambiguous_rate")
    if "ambiguous_repetitive" in p and not np.isnan(amb):
        twins = amb >= p["ambiguous_repetitive"]
        out.append(f"ratio_ambiguous_rate {amb:.0%} {'>=' if twins else '<'} "
                   f"{p['ambiguous_repetitive']:.0%}: "
                   + ("features refused with two plausible partners (a twin within 50 bits): "
                      "repetition, at any frame rate" if twins else
                      "few features have a twin, so this reading adds nothing; the refusals "
                      "are of features nothing resembles closely (viewpoint change, blur, "
                      "compression, or a repeated object seen in perspective, whose copies "
                      "differ with distance and angle), and the rejection lines above decide"))
    if "twins_in_frame" in p:
        out.append(_copies_words(_v(row, "in_frame_twin_rate"), p["twins_in_frame"],
                                 _v(row, "match_dist_med")))
    if not np.isnan(dm) and abs(dm) > p["dmean_step"]:
        out.append(f"|d_mean_intensity| {abs(dm):.1f} > {p['dmean_step']:g}: an exposure step; "
                   f"a rejection spike within {p['recovery_frames']:g} frames is the step's")
    gap = _v(row, "frame_interval_s")
    if "max_interval_s" in p and not np.isnan(gap) and gap > p["max_interval_s"]:
        out.append(f"matched across {gap:.3g} s > {p['max_interval_s']:g} s (slower than "
                   "3 Hz): wide-baseline pairs reject more from viewpoint change alone, so "
                   "the three-way matching table (docs/derivations.md §3) is not read here")
    return out


# --- §5 of docs/derivations.md: exposure step -------------------------------------------------------------------

def _step_at(i: int, res: np.ndarray, rej: np.ndarray, p: Params,
             base: np.ndarray | None = None, sig: np.ndarray | None = None) -> tuple[bool, int]:
    """Whether row i jumps like an exposure step, and after how many rows it recovers
    (0: not within recovery_frames, -1: the data ends first).

    The photometric residual decides where it is computable: the row's residual reaches
    residual_step and at least residual_jump times the row before (a one-frame jump, which blur
    building up over several frames is not); it has recovered once the residual is back below
    the midpoint of the levels before and at the step. Where the recording has a level of its
    own (``base``, ``sig``: photo_residual_base), the row's residual is read against it instead
    of the absolute residual_step: at least residual_jump times the scene's level and
    baseline_sigmas of its noise above it. Without a residual the ratio-test rejection stands
    in (crossing reject_exposure, recovered below it).
    """
    n = len(res)
    window = max(int(p["recovery_frames"]), 1)
    prev = i - 1
    if not np.isnan(res[i]):
        before = res[prev] if prev >= 0 else np.nan
        b = np.nan if base is None or sig is None else base[i]
        if np.isnan(b):
            high = res[i] >= p["residual_step"]
            level = max(p["residual_step"], ((0.0 if np.isnan(before) else before) + res[i]) / 2)
        else:
            assert sig is not None
            high = res[i] >= p["residual_jump"] * b and res[i] - b > p["baseline_sigmas"] * sig[i]
            level = max(b + p["baseline_sigmas"] * sig[i],
                        ((b if np.isnan(before) else before) + res[i]) / 2)
        jump = bool(high) and (np.isnan(before) or res[i] >= p["residual_jump"] * before)
        ahead = res[i + 1:i + 1 + window]
        with np.errstate(invalid="ignore"):
            recovered = ahead < level
    else:
        before = rej[prev] if prev >= 0 else np.nan
        jump = bool(rej[i] >= p["reject_exposure"]) and not before >= p["reject_exposure"]
        with np.errstate(invalid="ignore"):
            recovered = rej[i + 1:i + 1 + window] < p["reject_exposure"]
    if recovered.any():
        return bool(jump), int(np.argmax(recovered)) + 1
    return bool(jump), -1 if i + window >= n else 0


def _exposure_baseline(df: pd.DataFrame, p: Params) -> pd.DataFrame:
    """The scene's own photometric residual, leaving out the rows within an exposure step's
    recovery window (|d_mean_intensity| > dmean_step and the frames after it)."""
    if "baseline_window_s" not in p:
        return pd.DataFrame(index=range(len(df)))
    near = _after_step(col(df, "d_mean_intensity"), p["dmean_step"], p["recovery_frames"])
    base, sig = _scene_baseline(df, p, "photo_residual_med", near)
    return pd.DataFrame({"photo_residual_base": base, "photo_residual_base_sigma": sig})


def _dark_step(df: pd.DataFrame, p: Params) -> np.ndarray:
    """Rows whose frame mean moved far past the step line into or out of a view where detection
    fails (lights out, lights back on): a brightness step whatever matching does after it."""
    if "dmean_dark" not in p:
        return np.zeros(len(df), dtype=bool)
    dm = np.abs(col(df, "d_mean_intensity"))
    fill = col(df, "keypoint_fill")
    with np.errstate(invalid="ignore"):
        failed = fill < p["fill_floor"]
        either = failed | np.concatenate([[False], failed[:-1]])
        return (dm > p["dmean_dark"]) & either


def _exposure_context(df: pd.DataFrame, p: Params) -> pd.DataFrame:
    res, rej = col(df, "photo_residual_med"), col(df, "ratio_reject_rate")
    base, sig = col(df, "photo_residual_base"), col(df, "photo_residual_base_sigma")
    steps = [_step_at(i, res, rej, p, base, sig) for i in range(len(df))]
    return pd.DataFrame({"prev_photo_residual_med": np.concatenate([[np.nan], res[:-1]]),
                         "dark_step": _dark_step(df, p).astype(float),
                         "ratio_step": _ratio_step(df, p).astype(float),
                         "jumps": [float(j) for j, _ in steps],
                         "recovers_after_frames": [float(r) for _, r in steps]})


def _affine_absorbs(df: pd.DataFrame, p: Params) -> np.ndarray:
    """Rows whose residual the affine brightness model brings back to a healthy level (none
    when a rule file leaves residual_affine_max out: rejection alone then decides)."""
    if "residual_affine_max" not in p:
        return np.zeros(len(df), dtype=bool)
    res_aff = col(df, "photo_residual_affine_med")
    with np.errstate(invalid="ignore"):
        return res_aff < p["residual_affine_max"]


def _ratio_step(df: pd.DataFrame, p: Params) -> np.ndarray:
    """Rows where the same surfaces came out brighter or darker than in the previous frame by
    at least the step ratio (brightness_ratio >= ratio_step or <= 1 / ratio_step), read only
    where more than ratio_min_inliers of the correspondences are geometrically verified: the
    ratio is a median over the matched patches, right only while most of them show the same
    surface. It needs neither alignment to the pixel nor clean frames around it, so it reads
    photographs a second apart and steps into darkness alike."""
    if "ratio_step" not in p:
        return np.zeros(len(df), dtype=bool)
    r = col(df, "brightness_ratio")
    w = col(df, "inlier_ratio")
    with np.errstate(invalid="ignore"):
        return _ratio_clears(r, col(df, "brightness_ratio_se"), p) \
            & (w > p.get("ratio_min_inliers", 0.5))


def _ratio_clears(ratio: np.ndarray, se: np.ndarray, p: Params) -> np.ndarray:
    """Whether the brightness ratio clears the step line (in log) by ratio_sigmas standard
    errors of its own median (``brightness_ratio_se``; no margin where it is missing)."""
    k = float(p.get("ratio_sigmas", 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.abs(np.log(ratio)) - k * np.nan_to_num(se, nan=0.0) >= np.log(p["ratio_step"])


def _exposure_step(df: pd.DataFrame, p: Params) -> np.ndarray:
    """One frame wide with clean frames on both sides, recovering within 2-3.

    A candidate row has |d_mean_intensity| > dmean_step and is explained by a change of gain:
    matching survives (rejection below reject_max: a gain step rejects ~55%, a scene cut ~100%)
    or the affine brightness model removes the residual at the matches (distinguishing
    value; where the scene already rejects much, a step adds its ~25 points on top, while a
    scene cut's unrelated patches keep their residual whatever the gain). It is a step when its
    photometric residual jumps in one frame and recovers within recovery_frames; the disturbed
    rows in between belong to it. A ramp that stays disturbed longer (lights fading, flicker) is
    another brightness violation, not a step.
    """
    dm = np.abs(col(df, "d_mean_intensity"))
    res, rej = col(df, "photo_residual_med"), col(df, "ratio_reject_rate")
    with np.errstate(invalid="ignore"):
        candidate = (dm > p["dmean_step"]) & (
            ~(rej >= p["reject_max"]) | _affine_absorbs(df, p))
    out = _dark_step(df, p) | _ratio_step(df, p)
    base, sig = col(df, "photo_residual_base"), col(df, "photo_residual_base_sigma")
    for i in np.flatnonzero(candidate).tolist():
        jump, after = _step_at(i, res, rej, p, base, sig)
        if jump and after > 0:
            out[i:i + after] = True
        elif jump and after < 0:  # the data ends before it could recover: keep the step
            out[i] = True
    return out


def _exposure_explain(row: Mapping[str, Any], p: Params) -> list[str]:
    dm, res = _v(row, "d_mean_intensity"), _v(row, "photo_residual_med")
    gain = _v(row, "affine_gain")
    res_aff = _v(row, "photo_residual_affine_med")
    out = [f"|d_mean_intensity| {_fmt(abs(dm))} vs step > {p['dmean_step']:g} grey levels",
           f"absolute: photo_residual_med {_fmt(res)} vs >= {p['residual_step']:g} (in the reference "
           "scene: healthy ~4, step 20-25" + ("; the relative reading below is this recording's "
                                              "own)" if "baseline_window_s" in p else ")")]
    base, sig = _v(row, "photo_residual_base"), _v(row, "photo_residual_base_sigma")
    if "baseline_window_s" in p:
        if np.isnan(base):
            out.append("relative: no baseline of the recording's own (too few rows outside "
                       f"steps within {p['baseline_window_s']:g} s): the absolute line decides")
        elif not np.isnan(res):
            far = res >= p["residual_jump"] * base and res - base > p["baseline_sigmas"] * sig
            out.append(f"relative (decides the residual reading): the scene's own residual "
                       f"{base:.3g} (robust sigma "
                       f"{sig:.2g}, rows within {p['baseline_window_s']:g} s outside steps); "
                       f"{res:.3g} is {res / base if base > 0 else float('inf'):.2g}x it: "
                       + ("far above, the exposure signature" if far else
                          f"not x{p['residual_jump']:g} and {p['baseline_sigmas']:g} sigma "
                          "above it"))
    ratio, w = _v(row, "brightness_ratio"), _v(row, "inlier_ratio")
    if "ratio_step" in p and not np.isnan(ratio):
        line = p["ratio_step"]
        beyond = ratio >= line or ratio <= 1 / line
        trusted = not np.isnan(w) and w > p.get("ratio_min_inliers", 0.5)
        se = _v(row, "brightness_ratio_se")
        k = float(p.get("ratio_sigmas", 0.0))
        clears = bool(_ratio_clears(np.array([ratio]), np.array([se]), p)[0])
        out.append(f"brightness_ratio {ratio:.3f}: the same surfaces "
                   f"{abs(ratio - 1) * 100:.0f}% {'brighter' if ratio >= 1 else 'darker'} than "
                   f"in the previous frame, vs the step line {line:g} (or {1 / line:.3f})"
                   + ("" if not beyond else
                      f", but only {w:.0%} of the correspondences are verified (needs > "
                      f"{p.get('ratio_min_inliers', 0.5):.0%}): the median patch ratio is not "
                      "trusted" if not trusted else
                      ": a brightness step" if clears else
                      f", but the patches scatter: the median is uncertain to "
                      f"{se * 100:.1f}% (standard error) and must clear the line by {k:g} of "
                      "those, so the surfaces may not have changed at all"))
    # the check's own readings (the context), so the words cannot drift from the verdict
    by_ratio = _v(row, "ratio_step") == 1.0
    by_dark = _v(row, "dark_step") == 1.0
    # where the brightness ratio or the step into darkness calls it a step, the residual
    # reading's look-alikes below only say why that reading alone would not
    decides = ("; the brightness ratio above decides" if by_ratio else
               "; the step into darkness above decides" if by_dark else "")
    if by_dark:
        out.append(f"|d_mean_intensity| {abs(dm):.1f} > {p['dmean_dark']:g}, into or out of a "
                   "view where detection fails: a step into darkness or back, whatever "
                   "matching does after it")
    if not np.isnan(gain):
        out.append(f"affine_gain {gain:.3f} (1.0 = no gain change; a 20% step is 1.2)")
    aff_max = float(p.get("residual_affine_max", p["residual_step"]))
    if not np.isnan(res_aff) and not np.isnan(res):
        verdict = ("the affine model absorbs it: a brightness change, not blur"
                   if res_aff < aff_max and res >= p["residual_step"] else "")
        out.append(f"residual after the affine model {res_aff:.1f} {verdict}".rstrip())
    prev = _v(row, "prev_photo_residual_med")
    rec = _v(row, "recovers_after_frames")
    rej = _v(row, "ratio_reject_rate")
    if not np.isnan(rej) and rej >= p["reject_max"]:
        if "residual_affine_max" in p and not np.isnan(res_aff) and res_aff < aff_max:
            out.append(f"ratio_reject_rate {rej:.0%} >= {p['reject_max']:.0%}, but the affine "
                       f"model brings the residual to {res_aff:.1f} (< "
                       f"{aff_max:g}): the matches are right and only the gain "
                       "changed, so not a scene cut")
        else:
            out.append(f"ratio_reject_rate {rej:.0%} >= {p['reject_max']:.0%} and the affine "
                       "model does not remove the residual: matching collapsed (a gain step "
                       "rejects ~55%); " + ("the residual reading alone takes it for a scene "
                                            f"cut or repetition{decides}" if decides else
                                            "a scene cut or repetition, not an exposure step"))
    if rec > 0:
        out.append(f"recovered {rec:.0f} frame(s) later (a step recovers within "
                   f"{p['recovery_frames']:g})")
    elif rec == 0:
        out.append(f"still disturbed {p['recovery_frames']:g} frames later: "
                   + (f"the residual reading alone sees a ramp (lights fading, flicker), not a "
                      f"step{decides}" if decides else
                      "a ramp (lights fading, flicker), not an auto-exposure step"))
    if np.isnan(prev):
        out.append("no residual on the frame before: the motion-blur look-alike cannot be "
                   "ruled out by onset")
    elif _v(row, "jumps") == 1.0:
        out.append(f"motion blur ruled out: the residual jumped from {prev:.1f} in one frame; "
                   "blur degrades over several frames, a step is one frame wide")
    else:
        out.append(f"residual {prev:.1f} on the frame before: no one-frame jump (x"
                   f"{p['residual_jump']:g}), "
                   + (f"so the residual reading alone sees gradual degradation (motion blur: "
                      f"check gyro rate){decides}" if decides else
                      "which reads as gradual degradation (motion blur: check gyro rate), not "
                      "an exposure step"))
    return out


# --- §4 of docs/derivations.md: H/E x parallax quadrants -------------------------------------------------------

def _quadrant(he: np.ndarray, par: np.ndarray, p: Params,
              rot_px: np.ndarray | None = None, rot: np.ndarray | None = None,
              par_px: np.ndarray | None = None, turn_px: np.ndarray | None = None,
              noise_ratio: np.ndarray | None = None) -> np.ndarray:
    """0 healthy, 1 nearly stationary, 2 planar, 3 pure rotation, -1 not computable.

    Parallax is low below parallax_split_deg, or, where the rule sets rot_fit_px, where a
    rotation-only model (the focal free within a factor of 2) explains the correspondences
    within rot_fit_px (and, where the rule sets rot_fit_noise_ratio, within that multiple of
    E's own residual, ``noise_ratio``: :func:`rotation_explains`): the angle is de-rotated with the
    given K, which an approximate K leaves inflated by the rotation it failed to remove, while
    the rotation-only residual is in pixels and does not trust K.

    Where the rule sets still_rotation_deg and still_parallax_px, a reading whose parallax is
    under both the split and still_parallax_px in the image, with a rotation under
    still_rotation_deg, is standing still, and is put in quadrant 3 whatever H/E says
    (:func:`standing_still`).
    """
    q = np.full(len(he), -1)
    ok = ~np.isnan(he) & ~np.isnan(par)
    degenerate = he > p["he_degenerate"]
    low = par < p["parallax_split_deg"]
    if rot_px is not None and "rot_fit_px" in p:
        with np.errstate(invalid="ignore"):
            low = low | rotation_explains(rot_px, noise_ratio, p)
            if "rot_fit_focal_max" in p:
                # fits at the edge of the focal range (infinite, _bracketed_rotation_fit): the
                # views differ by a pure image shift, a plane sliding past, so a low angle is
                # E's arbitrary split of that motion between rotation and translation
                low = low & ~np.isposinf(rot_px)
    q[ok & ~degenerate & ~low] = 0
    q[ok & ~degenerate & low] = 1
    q[ok & degenerate & ~low] = 2
    q[ok & degenerate & low] = 3
    if rot is not None and par_px is not None:
        q[ok & standing_still(par, par_px, rot, p)] = 3
    if turn_px is not None and rot_px is not None:
        q[ok & turned_only(rot_px, turn_px, p, noise_ratio)] = 3
    return q


def rotation_explains(rot_px: np.ndarray, noise_ratio: np.ndarray | None, p: Params) -> np.ndarray:
    """Where the rotation-only model explains the correspondences (rules with rot_fit_px):
    its median residual is within rot_fit_px and, where the rule sets rot_fit_noise_ratio,
    within that multiple of E's own median residual over the same correspondences (``noise_ratio``,
    rot_only_px / epi_residual_px; NaN reads as within, as in tables without the column).

    The pixel line assumes a localisation noise of 1 px. E's Sampson residual measures the
    noise these correspondences actually have: a correct E leaves |N(0, sigma^2)|, median
    0.674 sigma, and a rotation that is the whole motion leaves a 2-D transfer error with noise
    in both images, median 1.665 sigma, 2.47 times E's. A translation adds depth-dependent
    parallax that E absorbs and no rotation does, so the ratio grows with the translation
    whatever the camera's noise, resolution or scene.
    """
    with np.errstate(invalid="ignore"):
        fits = rot_px <= p["rot_fit_px"]
        if noise_ratio is not None and "rot_fit_noise_ratio" in p:
            fits = fits & ~(noise_ratio > p["rot_fit_noise_ratio"])
    return np.asarray(fits)


def turned_only(rot_px: np.ndarray, turn_px: np.ndarray, p: Params,
                noise_ratio: np.ndarray | None = None) -> np.ndarray:
    """A turn that a rotation-only model explains: pure rotation whatever H/E (rules with
    rot_fit_px and rot_fit_turn_px; both read over the interval's upper half by parallax).

    A camera that only turns leaves E without a translation: every correct correspondence
    satisfies x'^T [t]x R x = 0 for any t, so RANSAC picks the epipole that also admits the most
    mismatches along their epipolar lines, while the homography K R K^-1 admits only the
    correct ones; H/E falls with the mismatch share (0.6-0.9 on hand-held panoramas). The
    rotation-only residual does not have that freedom. It is read only where the rotation moved
    the image well beyond the threshold (``turn_px``, f tan(rotation)): a turn of a few pixels
    is within the scatter of E's rotation, and any short baseline fits a rotation within the
    threshold.
    """
    if "rot_fit_px" not in p or "rot_fit_turn_px" not in p:
        return np.zeros(len(rot_px), dtype=bool)
    with np.errstate(invalid="ignore"):
        return rotation_explains(rot_px, noise_ratio, p) & (turn_px >= p["rot_fit_turn_px"])


def standing_still(par: np.ndarray, par_px: np.ndarray, rot: np.ndarray, p: Params
                   ) -> np.ndarray:
    """Neither parallax nor rotation: the camera stands still (rules with still_rotation_deg
    and still_parallax_px). The points moved less in the image than localisation noise moves
    them (still_parallax_px) and the camera did not turn.

    H/E does not decide it. With no motion every static point maps to itself, x' = x, and
    x^T [t]x x = 0 for every t: each static correspondence is an inlier of every essential
    matrix with R = I, so RANSAC is free to choose the epipole that also admits the points of
    whatever moves through the view (people, vehicles), while the homography (the identity)
    keeps only the static ones. H/E then falls with the share of moving points and says
    nothing about the scene; what matters is that there is no baseline, so nothing can be
    triangulated and t is noise.
    """
    if "still_rotation_deg" not in p or "still_parallax_px" not in p:
        return np.zeros(len(par), dtype=bool)
    with np.errstate(invalid="ignore"):
        return ((par < p["parallax_split_deg"]) & (par_px < p["still_parallax_px"])
                & (rot < p["still_rotation_deg"]))


def _bracketed_rotation_fit(df: pd.DataFrame, p: Params) -> np.ndarray:
    """``rot_only_px``, infinite where its focal scale sits at an end of the search range (rules
    with rot_fit_focal_min / rot_fit_focal_max): such a fit is evidence against a rotation, not
    a missing reading, so in an interval's median it outvotes a lone fit inside the range.

    A rotation-only fit that wants a focal outside the range is not a rotation seen through an
    approximate K: as the focal grows the model x' ~ K R K^-1 x tends to a pure shift of the
    image, which is what a camera sliding sideways past a flat surface sees, so such a fit
    climbs to the longest focal allowed and fits there (a simulated side camera passing a
    wall of cartons at 3 m fits within 0.5-1.4 px at 2x, every frame). Only a minimum inside
    the range says the views differ by a rotation.
    """
    rot_px = col(df, "rot_only_px")
    edge = _at_focal_edge(col(df, "rot_focal_scale"), p)
    return np.where(edge & ~np.isnan(rot_px), np.inf, rot_px)


def _at_focal_edge(scale: np.ndarray, p: Params) -> np.ndarray:
    """Where a rotation fit's focal scale sits at an end of the range searched (False where the
    rule sets no range or the scale is missing)."""
    if "rot_fit_focal_min" not in p or "rot_fit_focal_max" not in p:
        return np.zeros(len(scale), dtype=bool)
    with np.errstate(invalid="ignore"):
        return ((scale <= p["rot_fit_focal_min"] * (1 + 1e-6))
                | (scale >= p["rot_fit_focal_max"] * (1 - 1e-6)))


def starved_geometry(df: pd.DataFrame, p: Params) -> np.ndarray:
    """Rows whose two-view models cannot be trusted to describe the scene (rules with
    ``max_starvation``): RANSAC ran fewer iterations than the measured inlier ratio requires,
    FD-RAN-001's test (``ransac_iters_required > max_starvation x ransac_iters_run``).

    At an inlier ratio of 0.1-0.2 (a chequerboard's matches after the ratio test) 1000
    iterations draw an all-inlier 5-point sample with probability 0.01-0.27, so E and H are
    fitted to whatever chance consensus the draws found (8-28 points of 58-107 on the hand-held
    chequerboards of the validation set's dev half), and their inlier counts, H/E, the parallax
    and the rotation say nothing about the scene. A plane or a pure rotation keeps its
    correspondences (inlier ratio 0.64-0.99 on the dev half's planar and rotating recordings
    without repetition), so reading them is not starved. Tables without the columns are read as
    before.
    """
    if "max_starvation" not in p:
        return np.zeros(len(df), dtype=bool)
    return _starved(col(df, "ransac_iters_required"), col(df, "ransac_iters_run"), p)


def _starved(req: Any, ran: Any, p: Params) -> Any:
    """``starved_geometry`` on arrays or on one row's values."""
    with np.errstate(invalid="ignore"):
        return (ran >= 1) & (req > p["max_starvation"] * ran)


def _keyframe_read(df: pd.DataFrame, p: Params) -> pd.DataFrame:
    """H/E and parallax as read where each row's reference keyframe saw the most parallax.

    H/E carries no information at low parallax: with a tiny baseline any scene fits a
    homography within the RANSAC threshold, so every frame just after a keyframe change reads
    H/E ~ 0.95. Degeneracy is a property of the scene between two keyframes, so each row takes
    the medians of H/E and parallax over the upper half (by parallax) of the rows sharing its
    reference; the median keeps one noisy frame from deciding the interval. The rotation read is
    the largest the reference saw (a pan grows from zero at each keyframe change); the turn in
    pixels (``kf_turn_px``, f tan(rotation)) is the median over the same upper half as the
    rotation-only residual it is read with, and so is that residual in units of E's own
    (``kf_rot_noise_ratio``, rot_only_px / epi_residual_px row by row). Rows without a `ref_frame` (or with
    read_at = "frame") are read on their own.
    """
    he, par = col(df, "h_over_e"), col(df, "parallax_med_deg")
    # a starved RANSAC's models are not the scene's: the row gives no reading at all
    he = np.where(starved_geometry(df, p), np.nan, he)
    par_px, rot = col(df, "parallax_med_px"), col(df, "rot_deg")
    rot_px = _bracketed_rotation_fit(df, p)
    ref = col(df, "ref_frame")
    with np.errstate(invalid="ignore", divide="ignore"):
        # the rotation fit's residual in units of E's own over the same correspondences
        noise_ratio = rot_px / col(df, "epi_residual_px")
        # the frontend's parallax_med_px is f tan(parallax_med_deg): the same focal turns the
        # rotation into how far it moves a point at the image centre
        focal = np.where(par > 0, par_px / np.tan(np.radians(par)), np.nan)
        turn_px = focal * np.tan(np.radians(np.minimum(rot, 89.0)))
    out = pd.DataFrame({"kf_h_over_e": he, "kf_parallax_med_deg": par,
                        "kf_parallax_med_px": par_px, "kf_rot_deg": rot,
                        "kf_rot_only_px": rot_px, "kf_rot_noise_ratio": noise_ratio,
                        "kf_turn_px": turn_px,
                        "kf_intervals": np.where(ref >= 0, 1.0, np.nan)})
    valid = ~np.isnan(he) & ~np.isnan(par) & (ref >= 0)
    if p.get("read_at", "frame") != "keyframe" or not valid.any():
        return out
    pos = np.flatnonzero(valid)
    rows = pd.DataFrame({"ref": ref[pos], "par": par[pos], "he": he[pos], "px": par_px[pos],
                         "rot": rot[pos], "rpx": rot_px[pos], "noise_ratio": noise_ratio[pos],
                         "turn": turn_px[pos]})
    read = _upper_half_read(rows, "par")
    # the rotation-only residual over the same higher-parallax rows (NaN-safe median)
    upper = rows[rows["par"] >= rows.groupby("ref")["par"].transform("median")]
    out.loc[pos, "kf_rot_only_px"] = upper.groupby("ref")["rpx"].median().reindex(
        ref[pos]).to_numpy()
    out.loc[pos, "kf_rot_noise_ratio"] = upper.groupby("ref")["noise_ratio"].median().reindex(
        ref[pos]).to_numpy()
    out.loc[pos, "kf_turn_px"] = upper.groupby("ref")["turn"].median().reindex(
        ref[pos]).to_numpy()
    out.loc[pos, "kf_h_over_e"] = read["he"].reindex(ref[pos]).to_numpy()
    out.loc[pos, "kf_parallax_med_deg"] = read["par"].reindex(ref[pos]).to_numpy()
    out.loc[pos, "kf_parallax_med_px"] = read["px"].reindex(ref[pos]).to_numpy()
    out.loc[pos, "kf_rot_deg"] = rows.groupby("ref")["rot"].max().reindex(ref[pos]).to_numpy()
    if "min_parallax_px" in p:
        _two_interval_read(df, out, pos, ref, p["min_parallax_px"])
    return out


def _upper_half_read(rows: pd.DataFrame, by: str) -> pd.DataFrame:
    """Per reference (``ref``): medians of he, par and px over the rows in the upper half by
    ``by`` (the interval's higher-parallax frames)."""
    upper = rows[rows[by] >= rows.groupby("ref")[by].transform("median")]
    return upper.groupby("ref")[["he", "par", "px"]].median()


def _two_interval_read(df: pd.DataFrame, out: pd.DataFrame, pos: np.ndarray, ref: np.ndarray,
                       min_px: float) -> None:
    """Where an interval's own reading has under ``min_px`` of parallax, read it against the
    keyframe before its reference instead (the frontend's ``*_2kf`` columns), the same way:
    medians over the upper half by parallax of the rows sharing the reference."""
    he2, par2, px2 = col(df, "h_over_e_2kf"), col(df, "parallax_med_deg_2kf"), \
        col(df, "parallax_med_px_2kf")
    ok = ~np.isnan(he2[pos]) & ~np.isnan(px2[pos])
    if not ok.any():
        return
    p2 = pos[ok]
    rows = pd.DataFrame({"ref": ref[p2], "he": he2[p2], "par": par2[p2], "px": px2[p2]})
    read = _upper_half_read(rows, "px").reindex(ref[pos])
    short = out.loc[pos, "kf_parallax_med_px"].to_numpy() < min_px
    use = short & (read["px"].to_numpy() >= min_px)
    at = pos[use]
    out.loc[at, "kf_h_over_e"] = read["he"].to_numpy()[use]
    out.loc[at, "kf_parallax_med_deg"] = read["par"].to_numpy()[use]
    out.loc[at, "kf_parallax_med_px"] = read["px"].to_numpy()[use]
    out.loc[at, "kf_intervals"] = 2.0
    # the rotation-only residual was read over one interval: it does not describe the two
    out.loc[at, "kf_rot_only_px"] = np.nan
    out.loc[at, "kf_rot_noise_ratio"] = np.nan


# H/E separates a plane from 3D structure only when points off the plane move off the
# plane-induced homography by more than its RANSAC threshold (2.45 px at sigma = 1 px). A point
# at depth Z moves off it by about parallax_px * |1 - Z_plane / Z|, about half the parallax
# for a scene spanning 2:1 in depth: below twice the threshold the reading carries little.
WEAK_HE_PARALLAX_PX = 2 * homography_threshold_px(1.0)


def _wanted_quadrant(df: pd.DataFrame, p: Params) -> tuple[pd.DataFrame, np.ndarray]:
    """The keyframe reading, and which rows it puts in the quadrant the rule wants."""
    read = _keyframe_read(df, p)
    with np.errstate(invalid="ignore"):
        q = _quadrant(read["kf_h_over_e"].to_numpy(), read["kf_parallax_med_deg"].to_numpy(), p,
                      read["kf_rot_only_px"].to_numpy(), read["kf_rot_deg"].to_numpy(),
                      read["kf_parallax_med_px"].to_numpy(), read["kf_turn_px"].to_numpy(),
                      read["kf_rot_noise_ratio"].to_numpy())
    return read, q == (3 if p["want"] == "pure_rotation" else 2)


def span_translates(rot_px: np.ndarray, epi_px: np.ndarray, p: Params) -> np.ndarray:
    """Where the motion over the span (``rot_only_px_span``, ``epi_residual_px_span``: the
    interval's last frame against a frame at least a third of a second before it) shows a
    translation: the rotation-only model leaves more than ``span_translation_px`` and more
    than ``rot_fit_noise_ratio`` times E's own residual over the same points (rules with
    span_translation_px; NaN, no span reading, never does).

    Both lines, because each alone fails somewhere: a camera standing still leaves E fitting
    sub-pixel jitter (0.03-0.3 px), so the ratio alone reads 2-35 whatever the motion, while
    the pixel line alone assumes 1 px of localisation noise."""
    if "span_translation_px" not in p:
        return np.zeros(len(rot_px), dtype=bool)
    with np.errstate(invalid="ignore"):
        return np.asarray((rot_px > p["span_translation_px"])
                          & (rot_px > p.get("rot_fit_noise_ratio", 0.0) * epi_px))


def _he_parallax(df: pd.DataFrame, p: Params) -> np.ndarray:
    read, hit = _wanted_quadrant(df, p)
    # a keyframe interval shorter than the turn it is part of: over the span the camera
    # translated, so the short interval's reading is not pure rotation
    hit &= ~span_translates(col(df, "rot_only_px_span"), col(df, "epi_residual_px_span"), p)
    with np.errstate(invalid="ignore"):
        if "min_entropy" in p:
            # features crowded into a small cone are locally planar: a homography fits them
            # whatever the scene, so H/E only reads the scene when the features are spread.
            # Standing still is read on the motion alone, not on H/E: a view that did not move
            # has no baseline however its features lie (a street at night, only its lamps)
            still = standing_still(read["kf_parallax_med_deg"].to_numpy(),
                                   read["kf_parallax_med_px"].to_numpy(),
                                   read["kf_rot_deg"].to_numpy(), p)
            hit &= (quadrant_entropy(df) >= p["min_entropy"]) | still
        if "min_parallax_px" in p:
            # below it a 3D scene fits H nearly as well as E: the reading cannot tell (a table
            # without parallax_med_px is read as before)
            hit &= ~(read["kf_parallax_med_px"].to_numpy() < p["min_parallax_px"])
    return hit


def _he_parallax_unread(df: pd.DataFrame, p: Params) -> tuple[np.ndarray, str]:
    """Rows whose reading falls in the wanted quadrant but with too little image parallax for
    H/E to tell a plane from a 3D scene (min_parallax_px), and rows whose own two-view models
    would fall in it but come from a starved RANSAC (max_starvation)."""
    mask, why = np.zeros(len(df), dtype=bool), []
    if "min_parallax_px" in p:
        read, wanted = _wanted_quadrant(df, p)
        with np.errstate(invalid="ignore"):
            low = wanted & (read["kf_parallax_med_px"].to_numpy() < p["min_parallax_px"])
        if low.any():
            mask |= low
            why.append(
                f"H/E > {p['he_degenerate']:g} over a keyframe interval whose parallax stayed "
                f"under {p['min_parallax_px']:g} px in the image, also when read two keyframe "
                "intervals back, where a 3D scene fits a homography nearly as well as E; a "
                "higher resolution or a longer keyframe baseline lets it be read")
    starved = starved_geometry(df, p)
    if starved.any():
        raw = {k: v for k, v in p.items() if k != "max_starvation"} | {"read_at": "frame"}
        _, wanted_raw = _wanted_quadrant(df.iloc[np.flatnonzero(starved)], raw)
        at = np.flatnonzero(starved)[wanted_raw]
        if at.size:
            mask[at] = True
            why.append(
                "their own E and H would read this quadrant, but RANSAC was starved (fewer "
                "iterations than the inlier ratio requires, FD-RAN-001): models fitted to a "
                "chance consensus say nothing about the scene")
    return mask, "; ".join(why)


_QUADRANT_WORDS = {
    -1: "quadrant unknown: h_over_e or parallax_med_deg not computable",
    0: "healthy quadrant (H/E low, parallax high): the normal operating point",
    1: "H/E low, parallax low: a short baseline over 3D structure, triangulate nothing yet",
    2: "planar quadrant (H/E high, parallax high): decompose H instead of E",
    3: "pure-rotation quadrant (H/E high, parallax low): do not estimate t, do not triangulate",
}


def _he_parallax_explain(row: Mapping[str, Any], p: Params) -> list[str]:
    he, par = _v(row, "h_over_e"), _v(row, "parallax_med_deg")
    kf_he, kf_par = _v(row, "kf_h_over_e"), _v(row, "kf_parallax_med_deg")
    out = [f"this frame: h_over_e {_fmt(he)}, parallax_med_deg {_fmt(par)}"]
    req, ran = _v(row, "ransac_iters_required"), _v(row, "ransac_iters_run")
    if "max_starvation" in p and _starved(req, ran, p):
        w = _v(row, "inlier_ratio")
        out.append(f"not read: RANSAC was starved (inlier ratio {_fmt(w)} requires {req:.4g} "
                   f"iterations, {ran:.4g} ran; FD-RAN-001): E and H were fitted to a chance "
                   f"consensus of {_fmt(_v(row, 'inliers_e'))} and "
                   f"{_fmt(_v(row, 'inliers_h'))} points, so H/E, parallax and rotation say "
                   "nothing about the scene (a plane or a turn keeps most of its "
                   "correspondences as inliers)")
        return out
    if _v(row, "kf_intervals") == 2:
        out.append(f"read against keyframe {int(_v(row, 'ref2_frame'))}, two keyframe "
                   f"intervals back, because one interval spanned under "
                   f"{float(p.get('min_parallax_px', WEAK_HE_PARALLAX_PX)):.2g} px: h_over_e "
                   f"{_fmt(kf_he)}, parallax {_fmt(kf_par)} (H/E is uninformative at low "
                   "parallax)")
        he, par = kf_he, kf_par
    elif not np.isnan(kf_he) and (kf_he != he or kf_par != par):
        out.append(f"read over the reference keyframe's higher-parallax frames: h_over_e "
                   f"{_fmt(kf_he)}, parallax {_fmt(kf_par)} (H/E is uninformative at low "
                   "parallax)")
        he, par = kf_he, kf_par
    rpx = _v(row, "kf_rot_only_px")
    noise_ratio = _v(row, "kf_rot_noise_ratio")
    rot = _v(row, "kf_rot_deg")
    rot = _v(row, "rot_deg") if np.isnan(rot) else rot
    px = _v(row, "kf_parallax_med_px")
    px = _v(row, "parallax_med_px") if np.isnan(px) else px
    with np.errstate(invalid="ignore"):
        q = int(_quadrant(np.array([he]), np.array([par]), p, np.array([rpx]),
                          np.array([rot]), np.array([px]), np.array([_v(row, "kf_turn_px")]),
                          np.array([noise_ratio]))[0])
        still = bool(standing_still(np.array([par]), np.array([px]), np.array([rot]), p)[0])
        turn = _v(row, "kf_turn_px")
        turned = bool(turned_only(np.array([rpx]), np.array([turn]), p, np.array([noise_ratio]))[0])
    out += [f"degenerate > {p['he_degenerate']:g} (general 3D < 0.5); parallax split at "
            f"{p['parallax_split_deg']:g} deg (rotation < 0.1, plane 2-3)"]
    raw_rpx, raw_scale = _v(row, "rot_only_px"), _v(row, "rot_focal_scale")
    if "rot_fit_px" in p and np.isinf(rpx):
        at_edge = not np.isnan(raw_rpx) and bool(_at_focal_edge(np.array([raw_scale]), p)[0])
        out.append("rotation-only model: "
                   + (f"this frame's fit is best at {raw_scale:.2g}x the given focal ("
                      f"{raw_rpx:.2g} px there), " if at_edge else "")
                   + f"most fits of the interval's higher-parallax frames are best at an end of "
                   f"the {p.get('rot_fit_focal_min', 0.5):g}-{p.get('rot_fit_focal_max', 2):g}x "
                   "focal range searched, so not read as a rotation: a camera sliding sideways "
                   "past a flat surface fits a rotation better the longer the focal")
    if "rot_fit_px" in p and np.isfinite(rpx):
        within = rpx <= p["rot_fit_px"]
        fits = bool(rotation_explains(np.array([rpx]), np.array([noise_ratio]), p)[0])
        scale = _v(row, "rot_focal_scale")
        line = p.get("rot_fit_noise_ratio")
        relative = ("" if line is None or np.isnan(noise_ratio) else
                    f"; relative: {noise_ratio:.2g}x E's own residual over the same points "
                    f"({'<=' if noise_ratio <= line else '>'} {line:g}x; a rotation alone leaves "
                    "about 2.5x)")
        out.append(f"rotation-only model (focal free 0.5-2x): median residual {rpx:.2g} px "
                   f"{'<=' if within else '>'} {p['rot_fit_px']:g} px"
                   + (f" (best at {scale:.2g}x the given focal)" if not np.isnan(scale) else "")
                   + relative
                   + (": the views differ by a rotation only, whatever the accuracy of K"
                      if fits else ": a translation moved the points beyond what the "
                      "localisation noise explains" if within else
                      ": a translation moved the points"))
    span_px, span_epi = _v(row, "rot_only_px_span"), _v(row, "epi_residual_px_span")
    span_moved = bool(span_translates(np.array([span_px]), np.array([span_epi]), p)[0])
    if q == 3 and span_moved:
        out.append("this keyframe interval alone reads like a turn or a stop (H/E high, "
                   "parallax low), but it is shorter than the motion it is part of (below)")
    elif q == 3 and (still or turned) and not he > p["he_degenerate"]:
        out.append("pure-rotation reading from the motion alone (H/E set aside, below): do not "
                   "estimate t, do not triangulate")
    else:
        out.append(_QUADRANT_WORDS[q])
    floor = float(p.get("min_parallax_px", WEAK_HE_PARALLAX_PX))
    if q == 2 and px < floor:
        out.append(f"not read: the parallax is {px:.2g} px in the image, under {floor:.2g} px "
                   "(twice the homography threshold), so a 3D scene also fits H nearly as well "
                   "as E (low resolution or short baseline)")
    ent_sh = _v(row, "entropy_inliers_shared_norm")
    ent = float(_quadrant_spread(_v(row, "entropy_norm"), _v(row, "entropy_inliers_norm"),
                                 ent_sh))
    where = ("inliers over the view shared with the reference keyframe"
             if not np.isnan(ent_sh) else "inliers")
    if "min_entropy" in p and not ent >= p["min_entropy"] and q == 3 and still:
        out.append(f"entropy (keypoints or {where}, the lower) {_fmt(ent)} < "
                   f"{p['min_entropy']:g}: H/E is not read on clustered features, but standing "
                   "still is read on the motion alone, and a view that did not move has no "
                   "baseline however its features lie")
    elif "min_entropy" in p and not ent >= p["min_entropy"]:
        out.append(f"not read: entropy (keypoints or {where}, the lower) {_fmt(ent)} < "
                   f"{p['min_entropy']:g}, clustered features fit a homography whatever the "
                   "scene (feature_clustering look-alike)")
    elif "min_entropy" in p and not np.isnan(ent_sh) and \
            _v(row, "entropy_inliers_norm") < p["min_entropy"]:
        out.append(f"entropy of the inliers {_fmt(_v(row, 'entropy_inliers_norm'))} over the "
                   f"whole view, {_fmt(ent_sh)} over the part the reference keyframe also saw "
                   f">= {p['min_entropy']:g}: the inliers fill the shared view (a turn or a "
                   "pass leaves the rest unseen), so they are spread, not clustered")
    if q == 3 and still:
        out.append(f"standing still: rotation {rot:.2g} deg < {p['still_rotation_deg']:g} and the "
                   f"points moved {px:.2g} px < {p['still_parallax_px']:g} px, within "
                   "localisation noise, so nothing can be triangulated (reported as "
                   "pure_rotation: translation is unobservable; do not estimate t, do not create "
                   "keyframes)")
        if not he > p["he_degenerate"]:
            out.append(f"h_over_e {he:.3g} is not read when standing still: every static point "
                       "is an inlier of any essential matrix with R = I, so E also takes points "
                       "that move through the view and H/E falls with their share")
    if q == 3 and turned and not still and not he > p["he_degenerate"]:
        out.append(f"turned {turn:.3g} px in the image >= {p['rot_fit_turn_px']:g} px and a "
                   f"rotation alone "
                   f"explains the points ({rpx:.2g} px): h_over_e {he:.3g} is not read, since "
                   "with no translation E takes every correct correspondence for any epipole, "
                   "plus the mismatches along the one RANSAC picks")
    if "span_translation_px" in p and not np.isnan(span_px):
        moved = span_moved
        ratio = span_px / span_epi if span_epi > 0 else float("inf")
        out.append(f"over {_v(row, 'span_dt_s'):.2g} s (against frame "
                   f"{int(_v(row, 'span_frame'))}, longer than this keyframe interval): the "
                   f"rotation-only model leaves {span_px:.2g} px, {ratio:.2g}x E's residual "
                   f"(lines {p['span_translation_px']:g} px and "
                   f"{p.get('rot_fit_noise_ratio', 0):g}x): "
                   + ("the camera translated, so the short interval's reading is not pure "
                      "rotation" if moved else "still a rotation (or standing still)"))
    if q == 3:
        why = (f"parallax {par:.3g} deg < {p['parallax_split_deg']:g}"
               if par < p["parallax_split_deg"] else
               f"the rotation-only fit ({rpx:.2g} px)")
        out.append(f"planar_degeneracy ruled out by {why}")
    elif q == 2:
        out.append(f"pure_rotation ruled out by parallax {par:.3g} deg >= "
                   f"{p['parallax_split_deg']:g}")
    elif q in (0, 1):
        out.append(f"planar_degeneracy and pure_rotation ruled out by h_over_e {he:.3g} <= "
                   f"{p['he_degenerate']:g}")
    return out


# --- §2 of docs/derivations.md: clustering confirmed by the pose information matrix ----------------------------

def constraint_entropy(df: pd.DataFrame) -> np.ndarray:
    """The lower of keypoint entropy and essential-inlier entropy (NaN only if both are).

    Bucketing with a low-threshold retry spreads keypoints over blank cells, but corners found
    in sensor noise never match: the pose is constrained only where the inliers are.
    """
    with np.errstate(invalid="ignore"):
        return np.fmin(col(df, "entropy_norm"), col(df, "entropy_inliers_norm"))


def quadrant_entropy(df: pd.DataFrame) -> np.ndarray:
    """The spread the H/E quadrant is read on: the lower of keypoint entropy and the inliers'
    entropy over the view both frames share (over the whole view where the shared part is
    unknown).

    A homography fits features crowded into a small cone whatever the scene, so H/E reads the
    scene only when the inliers are spread. Spread is judged over what the reference keyframe
    also saw: a camera that turned 40 deg through a 60 deg lens shares a third of its view, and
    inliers filling that third are as spread as correspondences can be, while over the whole
    grid they read 0.4.
    Under ``MIN_SHARED_CELLS`` (a sixth of the view) the shared part is unknown.
    """
    return _quadrant_spread(col(df, "entropy_norm"), col(df, "entropy_inliers_norm"),
                            col(df, "entropy_inliers_shared_norm"))


def _quadrant_spread(ent: Any, ent_in: Any, ent_shared: Any) -> Any:
    """``quadrant_entropy`` on arrays or on one row's values."""
    return np.fmin(ent, np.where(np.isnan(ent_shared), ent_in, ent_shared))


def _clustering(df: pd.DataFrame, p: Params) -> np.ndarray:
    ent, fill = constraint_entropy(df), col(df, "keypoint_fill")
    cond = col(df, "pose_info_cond")
    with np.errstate(invalid="ignore"):
        return (ent < p["entropy_alarm"]) & (fill >= p["fill_floor"]) & (cond > p["cond_confirm"])


def _clustering_explain(row: Mapping[str, Any], p: Params) -> list[str]:
    ent, ent_in, kp, fill, cond = (_v(row, m) for m in (
        "entropy_norm", "entropy_inliers_norm", "n_keypoints", "keypoint_fill", "pose_info_cond"))
    out = [f"entropy_norm {_fmt(ent)}, of the inliers {_fmt(ent_in)}, vs alarm < "
           f"{p['entropy_alarm']:g} (uniform 1.0, acceptable 0.737, 8 cells 0.537, 4 cells 0.358)"]
    if ent >= p["entropy_alarm"] and ent_in < p["entropy_alarm"]:
        out.append("the keypoints are spread but the inliers are not: the spread keypoints do "
                   "not match, so they do not constrain the pose")
    if not np.isnan(fill) and fill < p["fill_floor"]:
        out.append(f"{_fill_words(kp, fill)} < {p['fill_floor']:g}: few features crowd few "
                   "cells; that is detection_failure, not clustering")
    elif not np.isnan(fill):
        out.append(f"detection_failure ruled out by {_fill_words(kp, fill)} >= "
                   f"{p['fill_floor']:g}")
    if np.isnan(cond):
        out.append("pose_info_cond not computable (no intrinsics?): clustering unconfirmed")
    elif cond > p["cond_confirm"]:
        out.append(f"pose_info_cond {cond:.4g} > {p['cond_confirm']:g}: yaw and sideslip are "
                   "confusable (healthy 20-80, clustered > 3000): confirmed")
    else:
        out.append(f"pose_info_cond {cond:.4g} <= {p['cond_confirm']:g}: the pose stays "
                   "well constrained, clustering ruled out as a cause of drift")
    return out


# --- texture at scale: a detector that fills its budget with noise ---------------------------------------------

_NO_COARSE = ("n_coarse_keypoints not in this table (written by an older frontdiag): re-run "
              "analyze to read texture at scale")


def _coarse_split(df: pd.DataFrame, p: Params) -> tuple[np.ndarray, np.ndarray]:
    """(few corners at scale although the budget is full, of those: clustered where they are)."""
    n, hull, fill = (col(df, m) for m in ("n_coarse_keypoints", "coarse_hull_share",
                                          "keypoint_fill"))
    with np.errstate(invalid="ignore"):
        few = (fill >= p["fill_floor"]) & (n < p["coarse_min"])
        clustered = few & (n >= p["min_points"]) & (hull < p["hull_max"])
    return few, clustered


def _texture_at_scale(df: pd.DataFrame, p: Params) -> np.ndarray:
    few, clustered = _coarse_split(df, p)
    return clustered if p["want"] == "clustered" else few & ~clustered


def _texture_at_scale_explain(row: Mapping[str, Any], p: Params) -> list[str]:
    n, hull, kp, fill = (_v(row, m) for m in ("n_coarse_keypoints", "coarse_hull_share",
                                             "n_keypoints", "keypoint_fill"))
    if np.isnan(n):
        return [_NO_COARSE]
    if not n < p["coarse_min"]:
        return [f"n_coarse_keypoints {_fmt(n)} (level >= 3, FAST score >= 20) >= "
                f"{p['coarse_min']:g}: the view has texture at scale (textured views keep "
                "100-300); FD-CLU-001/002 read where it is from the keypoints themselves"]
    out = [f"n_coarse_keypoints {_fmt(n)} (level >= 3, FAST score >= 20) < {p['coarse_min']:g}: "
           "textured views keep 100-300; the rest of the corners found are fine-scale noise"]
    if not np.isnan(fill) and fill < p["fill_floor"]:
        out.append(f"{_fill_words(kp, fill)} < {p['fill_floor']:g}: the detector itself finds "
                   "too little (FD-DET-001 reads this frame)")
    elif not np.isnan(fill):
        out.append(f"{_fill_words(kp, fill)} >= {p['fill_floor']:g}: the budget is full, of "
                   "corners that do not survive at scale")
    if np.isnan(hull):
        out.append(f"fewer than {p['min_points']:g} of them with another within 54 px: no "
                   "texture to locate, a blank view")
    elif hull < p["hull_max"]:
        out.append(f"coarse_hull_share {hull:.3f} < {p['hull_max']:g}: what texture there is sits "
                   "in one small part of the view (clustering)")
    else:
        out.append(f"coarse_hull_share {hull:.3f} >= {p['hull_max']:g}: the few corners at "
                   "scale are scattered over the view, not one textured object (a blank view)")
    return out



def _object_on_plain(df: pd.DataFrame, p: Params) -> np.ndarray:
    """Many corners at scale, all in one small part of a lit view, and the matched points not
    spread over it: the keypoints elsewhere are the retry's noise on a plain surface."""
    n, hull, fill, lit, ent_in = (col(df, m) for m in (
        "n_coarse_keypoints", "coarse_hull_share", "keypoint_fill", "lit_share",
        "entropy_inliers_norm"))
    with np.errstate(invalid="ignore"):
        # under 30 inliers (NaN) the matches cannot show a spread: they do not contradict
        spread_matches = ent_in >= p["inlier_spread"]
        return (fill >= p["fill_floor"]) & (n >= p["coarse_min"]) & (hull < p["hull_max"]) \
            & (lit >= p["lit_min"]) & ~spread_matches


def _object_on_plain_explain(row: Mapping[str, Any], p: Params) -> list[str]:
    n, hull, fill, kp, lit, ent, ent_in = (_v(row, m) for m in (
        "n_coarse_keypoints", "coarse_hull_share", "keypoint_fill", "n_keypoints", "lit_share",
        "entropy_norm", "entropy_inliers_norm"))
    if np.isnan(n):
        return [_NO_COARSE]
    if not n >= p["coarse_min"]:
        return [f"n_coarse_keypoints {_fmt(n)} < {p['coarse_min']:g}: FD-CLU-003 and FD-DET-002 "
                "read a view with this few corners at scale"]
    out = []
    if np.isnan(hull) or hull >= p["hull_max"]:
        out.append(f"coarse_hull_share {_fmt(hull)} >= {p['hull_max']:g}: the {_fmt(n)} strong "
                   "corners at scale are spread over the view, not one small object")
        return out
    out.append(f"coarse_hull_share {hull:.3f} < {p['hull_max']:g}: the {_fmt(n)} strong corners "
               "at scale (level >= 3, FAST >= 20) sit in one small part of the view")
    if not np.isnan(fill) and fill < p["fill_floor"]:
        out.append(f"{_fill_words(kp, fill)} < {p['fill_floor']:g}: FD-DET-001 reads this frame")
    elif ent >= p["inlier_spread"]:
        out.append(f"the keypoints read entropy_norm {ent:.2f} >= {p['inlier_spread']:g}: the rest "
                   "of the budget is spread over the plain part of the view, so their own "
                   "entropy is blind to the object")
    elif not np.isnan(ent):
        out.append(f"the keypoints read entropy_norm {ent:.2f} < {p['inlier_spread']:g}: they "
                   "crowd the object too (FD-CLU-001/002 read that where the pose confirms it)")
    if np.isnan(lit) or lit < p["lit_min"]:
        out.append(f"lit_share {_fmt(lit)} < {p['lit_min']:g}: the view is dim and its corners "
                   "gather where the light is; the exposure and black-view rules read that")
    else:
        out.append(f"lit_share {lit:.2f} >= {p['lit_min']:g}: the rest of the view is lit, "
                   "a plain surface rather than darkness")
    if ent_in >= p["inlier_spread"]:
        out.append(f"but the essential-matrix inliers read entropy {ent_in:.2f} >= "
                   f"{p['inlier_spread']:g}: the points elsewhere match, so they are texture, "
                   "not noise (not this rule)")
    elif np.isnan(ent_in):
        out.append("fewer than 30 essential-matrix inliers: no spread of matched points "
                   "contradicts it")
    else:
        out.append(f"the essential-matrix inliers read entropy {ent_in:.2f} < "
                   f"{p['inlier_spread']:g}: what matches is the object")
    return out

# --- §4 of docs/derivations.md: RANSAC starvation -----------------------------------------------------------

def _ransac_starved(df: pd.DataFrame, p: Params) -> np.ndarray:
    req, ran = col(df, "ransac_iters_required"), col(df, "ransac_iters_run")
    with np.errstate(invalid="ignore"):
        return (ran >= 1) & (req > p["margin"] * ran)


def _ransac_explain(row: Mapping[str, Any], p: Params) -> list[str]:
    req, ran, w = (_v(row, m) for m in
                   ("ransac_iters_required", "ransac_iters_run", "inlier_ratio"))
    if np.isnan(req) or np.isnan(ran) or ran < 1:
        return ["RANSAC iteration counts not available for this frame"]
    ratio = req / ran
    return [f"required {req:.0f} iterations at w = {_fmt(w)} against {ran:.0f} run: "
            f"ratio {ratio:.2f} (starved above {p['margin']:g}); success probability is "
            "what 1-(1-w^5)^N gives at the budget, not the confidence asked for"]


# --- §5 of docs/derivations.md: run-level correlation of pose increment with |d mean intensity| ----------------

def pose_increment_deg(df: pd.DataFrame) -> np.ndarray:
    """Per-row pose increment in degrees, for rows of one topic in time order.

    Monocular translation has no scale, so the increment is the norm of the rotation change since
    the previous row (against the same reference keyframe) and the change of the translation
    direction (`t_dir_change_deg`) where that column exists.
    """
    rot = col(df, "rot_deg")
    ref = col(df, "ref_frame")
    d_rot = np.abs(np.diff(rot, prepend=np.nan))
    same_ref = np.concatenate([[False], ref[1:] == ref[:-1]]) | np.isnan(ref)
    d_rot[~same_ref] = np.nan
    tdir = col(df, "t_dir_change_deg")
    if np.all(np.isnan(tdir)):
        return d_rot
    inc = np.hypot(np.nan_to_num(d_rot), np.nan_to_num(tdir))
    inc[np.isnan(d_rot) & np.isnan(tdir)] = np.nan
    return inc


def _pose_intensity_corr(df: pd.DataFrame, p: Params) -> RunOutcome:
    cams = df[df["sensor"] == "camera"] if "sensor" in df.columns else df
    incs, dms, frames = [], [], []
    keys = ["topic"] if "topic" in cams.columns else []
    groups = cams.groupby(keys, sort=True) if keys else [((), cams)]
    for _, g in groups:
        g = g.sort_values("t_ns", kind="stable") if "t_ns" in g.columns else g
        incs.append(pose_increment_deg(g))
        dms.append(np.abs(col(g, "d_mean_intensity")))
        frames.append(col(g, "frame"))
    if not incs:
        return RunOutcome(False, float("nan"), "no camera rows", evaluated=False)
    inc, dm, fr = np.concatenate(incs), np.concatenate(dms), np.concatenate(frames)
    ok = ~np.isnan(inc) & ~np.isnan(dm)
    n = int(ok.sum())
    steps = ok & (dm > p["dmean_step"])
    if n < p["min_frames"]:
        return RunOutcome(False, float("nan"),
                          f"only {n} frames with both a pose increment and a mean-intensity "
                          f"change (needs {p['min_frames']:g})", evaluated=False)
    if not steps.any():
        return RunOutcome(False, float("nan"),
                          f"no frame with |d_mean_intensity| > {p['dmean_step']:g}: nothing to "
                          "correlate, brightness constancy held")
    x, y = inc[ok], dm[ok]
    r = float(np.corrcoef(x, y)[0, 1]) if x.std() > 0 and y.std() > 0 else 0.0
    spike = [int(f) for f in fr[steps] if not np.isnan(f)]
    fired = r > p["r_alarm"]
    word = "exposure steps move the pose" if fired else "pose does not follow the steps"
    return RunOutcome(fired, r, f"corr(pose increment, |d_mean_intensity|) = {r:.2f} over {n} "
                      f"frames, alarm > {p['r_alarm']:g}: {word}", spike[:20])


_NUM = "number"
_BASELINE_PARAMS = {"baseline_window_s": _NUM, "baseline_min_rows": _NUM,
                    "baseline_min_share": _NUM}
CHECKS: dict[str, Check] = {c.name: c for c in [
    Check("matching_table", "three-way matching table: repetitive structure is ~85% ratio-test rejection "
          "with the features intact (not ~120 features: detection failure) and not inside the "
          "2-3 frames after an exposure step (~55%, recovering)", "frame", "camera",
          ("n_keypoints", "keypoint_fill", "ratio_reject_rate", "d_mean_intensity",
           "ratio_ambiguous_rate", "in_frame_twin_rate"),
          {"fill_floor": _NUM, "reject_repetitive": _NUM, "dmean_step": _NUM,
           "recovery_frames": _NUM, "max_interval_s": _NUM, **_BASELINE_PARAMS,
           "reject_excess": _NUM, "baseline_sigmas": _NUM, "keypoints_kept": _NUM,
           "ambiguous_repetitive": _NUM, "baseline_widen_max_s": _NUM, "twins_in_frame": _NUM},
          {"n_keypoints": "min", "ratio_reject_rate": "max", "in_frame_twin_rate": "max"},
          {"fill_floor": "keypoint_fill", "reject_repetitive": "ratio_reject_rate",
           "dmean_step": "d_mean_intensity", "reject_excess": "ratio_reject_base",
           "ambiguous_repetitive": "ratio_ambiguous_rate", "twins_in_frame": "in_frame_twin_rate"},
          frame=_matching_table, explain=_matching_table_explain, context=_matching_context,
          optional=frozenset({"max_interval_s", "reject_excess", "baseline_sigmas",
                              "keypoints_kept", "ambiguous_repetitive", "baseline_widen_max_s",
                              "twins_in_frame", *_BASELINE_PARAMS}),
          unread=_matching_unread, baseline=_matching_baseline),
    Check("exposure_step", "a jump of mean intensity with the photometric residual "
          "jumping with it, clean before and clean again within 2-3 frames",
          "frame", "camera",
          ("d_mean_intensity", "photo_residual_med", "ratio_reject_rate", "affine_gain",
           "photo_residual_affine_med", "brightness_ratio", "inlier_ratio"),
          {"dmean_step": _NUM, "residual_step": _NUM, "residual_jump": _NUM,
           "residual_affine_max": _NUM, "reject_exposure": _NUM, "reject_max": _NUM,
           "recovery_frames": _NUM, "dmean_dark": _NUM, "fill_floor": _NUM,
           "baseline_sigmas": _NUM, "ratio_step": _NUM, "ratio_min_inliers": _NUM,
           "ratio_sigmas": _NUM, **_BASELINE_PARAMS},
          {"d_mean_intensity": "absmax", "photo_residual_med": "max", "affine_gain": "absdev1",
           "brightness_ratio": "absdev1"},
          {"dmean_step": "d_mean_intensity", "residual_step": "photo_residual_med",
           "reject_exposure": "ratio_reject_rate", "reject_max": "ratio_reject_rate",
           "residual_affine_max": "photo_residual_affine_med", "dmean_dark": "d_mean_intensity",
           "fill_floor": "keypoint_fill", "ratio_step": "brightness_ratio",
           "ratio_min_inliers": "inlier_ratio", "ratio_sigmas": "brightness_ratio_se"},
          frame=_exposure_step, explain=_exposure_explain, context=_exposure_context,
          optional=frozenset({"residual_affine_max", "dmean_dark", "fill_floor",
                              "baseline_sigmas", "ratio_step", "ratio_min_inliers",
                              "ratio_sigmas", *_BASELINE_PARAMS}),
          baseline=_exposure_baseline),
    Check("he_parallax_quadrant", "H/E inlier ratio x median parallax separates pure "
          "rotation, a planar scene, a nearly stationary camera and healthy motion",
          "frame", "camera", ("h_over_e", "parallax_med_deg", "ref_frame", "entropy_norm",
                              "entropy_inliers_norm", "entropy_inliers_shared_norm",
                              "parallax_med_px", "rot_deg", "rot_only_px", "epi_residual_px",
                              "ransac_iters_required", "ransac_iters_run", "rot_only_px_span",
                              "epi_residual_px_span"),
          {"want": "choice:pure_rotation|planar_degeneracy", "he_degenerate": _NUM,
           "parallax_split_deg": _NUM, "read_at": "choice:keyframe|frame",
           "min_entropy": _NUM, "min_parallax_px": _NUM, "still_rotation_deg": _NUM,
           "still_parallax_px": _NUM, "rot_fit_px": _NUM, "rot_fit_turn_px": _NUM,
           "rot_fit_focal_min": _NUM, "rot_fit_focal_max": _NUM, "rot_fit_noise_ratio": _NUM,
           "max_starvation": _NUM, "span_translation_px": _NUM},
          {"h_over_e": "max", "parallax_med_deg": "min"},
          {"he_degenerate": "h_over_e", "parallax_split_deg": "parallax_med_deg",
           "min_entropy": "entropy_norm", "min_parallax_px": "parallax_med_px",
           "still_rotation_deg": "rot_deg", "still_parallax_px": "parallax_med_px",
           "rot_fit_px": "rot_only_px", "rot_fit_focal_min": "rot_focal_scale",
           "rot_fit_focal_max": "rot_focal_scale", "max_starvation": "ransac_iters_required",
           "span_translation_px": "rot_only_px_span"},
          frame=_he_parallax, explain=_he_parallax_explain, context=_keyframe_read,
          optional=frozenset({"min_entropy", "min_parallax_px", "still_rotation_deg",
                              "still_parallax_px", "rot_fit_px", "rot_fit_turn_px",
                              "rot_fit_focal_min", "rot_fit_focal_max", "rot_fit_noise_ratio",
                              "max_starvation", "span_translation_px"}),
          unread=_he_parallax_unread),
    Check("clustering", "low keypoint entropy with enough features, confirmed by the "
          "condition number of the pose information matrix",
          "frame", "camera", ("entropy_norm", "entropy_inliers_norm", "n_keypoints",
                              "keypoint_fill", "pose_info_cond"),
          {"entropy_alarm": _NUM, "fill_floor": _NUM, "cond_confirm": _NUM},
          {"entropy_norm": "min", "entropy_inliers_norm": "min", "pose_info_cond": "max"},
          {"entropy_alarm": "entropy_norm", "fill_floor": "keypoint_fill",
           "cond_confirm": "pose_info_cond"},
          frame=_clustering, explain=_clustering_explain),
    Check("texture_at_scale", "the detector fills its budget but almost none of its corners "
          "survive at scale (level >= 3): a blank view (want = absent) or one small textured "
          "object on it (want = clustered)",
          "frame", "camera", ("n_coarse_keypoints", "coarse_hull_share", "n_keypoints",
                              "keypoint_fill"),
          {"want": "choice:absent|clustered", "coarse_min": _NUM, "min_points": _NUM,
           "hull_max": _NUM, "fill_floor": _NUM},
          {"n_coarse_keypoints": "min", "coarse_hull_share": "min"},
          {"coarse_min": "n_coarse_keypoints", "hull_max": "coarse_hull_share",
           "fill_floor": "keypoint_fill"},
          frame=_texture_at_scale, explain=_texture_at_scale_explain),
    Check("object_on_plain", "many corners at scale, all in one small part of a lit view, "
          "while the keypoints elsewhere do not match: one textured object on a plain surface "
          "whose noise fills the rest of the budget",
          "frame", "camera", ("n_coarse_keypoints", "coarse_hull_share", "keypoint_fill",
                              "lit_share", "entropy_inliers_norm", "entropy_norm", "n_keypoints"),
          {"coarse_min": _NUM, "hull_max": _NUM, "fill_floor": _NUM, "lit_min": _NUM,
           "inlier_spread": _NUM},
          {"coarse_hull_share": "min", "entropy_inliers_norm": "min"},
          {"coarse_min": "n_coarse_keypoints", "hull_max": "coarse_hull_share",
           "fill_floor": "keypoint_fill", "lit_min": "lit_share",
           "inlier_spread": "entropy_inliers_norm"},
          frame=_object_on_plain, explain=_object_on_plain_explain),
    Check("ransac_starved", "the iterations the measured inlier ratio requires "
          "exceed the iterations run, so the frame is untrusted", "frame", "camera",
          ("ransac_iters_required", "ransac_iters_run", "inlier_ratio"), {"margin": _NUM},
          {"ransac_iters_required": "max", "inlier_ratio": "min"},
          {"margin": "ransac_iters_required"},
          frame=_ransac_starved, explain=_ransac_explain),
    Check("pose_intensity_correlation", "correlation over the run of the pose-increment "
          "norm with |d_mean_intensity|; near zero when brightness constancy holds", "run",
          "camera", ("rot_deg", "ref_frame", "t_dir_change_deg", "d_mean_intensity"),
          {"r_alarm": _NUM, "min_frames": _NUM, "dmean_step": _NUM}, {},
          {"dmean_step": "d_mean_intensity"},
          run=_pose_intensity_corr),
]}
