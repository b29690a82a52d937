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


def _matching_table(df: pd.DataFrame, p: Params) -> np.ndarray:
    fill = col(df, "keypoint_fill")
    rej = col(df, "ratio_reject_rate")
    with np.errstate(invalid="ignore"):
        near_step = _after_step(col(df, "d_mean_intensity"), p["dmean_step"], p["recovery_frames"])
        return ((fill >= p["fill_floor"]) & (rej >= p["reject_repetitive"]) & ~near_step
                & ~_wide_interval(df, p))


def _matching_unread(df: pd.DataFrame, p: Params) -> tuple[np.ndarray, str]:
    # a row with no rejection reading (first frame, after a gap) had nothing to decline
    return _wide_interval(df, p) & ~np.isnan(col(df, "ratio_reject_rate")), (
        f"matched across more than {p.get('max_interval_s', np.nan):g} s (slower than 3 Hz: "
        "--stride, a low-rate recording or dropped frames); read repetition at the "
        "recording's own rate")


def _matching_context(df: pd.DataFrame, p: Params) -> pd.DataFrame:
    return pd.DataFrame({"frame_interval_s": frame_interval_s(df)})


def _fill_words(kp: float, fill: float) -> str:
    return f"keypoint_fill {_fmt(fill)} ({_fmt(kp)} keypoints)"


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
        out.append(f"ratio_reject_rate {rej:.0%} >= {p['reject_repetitive']:.0%}: the ratio test "
                   "refuses ambiguous candidates (repetitive ~85%)")
    else:
        out.append(f"ratio_reject_rate {rej:.0%} < {p['reject_repetitive']:.0%}: "
                   "repetitive_structure ruled out (healthy ~30%, exposure step ~55%)")
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

def _step_at(i: int, res: np.ndarray, rej: np.ndarray, p: Params) -> tuple[bool, int]:
    """Whether row i jumps like an exposure step, and after how many rows it recovers
    (0: not within recovery_frames, -1: the data ends first).

    The photometric residual decides where it is computable: the row's residual reaches
    residual_step and at least residual_jump times the row before (a one-frame jump, which blur
    building up over several frames is not); it has recovered once the residual is back below
    the midpoint of the levels before and at the step. Without a residual the ratio-test
    rejection stands in (crossing reject_exposure, recovered below it).
    """
    n = len(res)
    window = max(int(p["recovery_frames"]), 1)
    prev = i - 1
    if not np.isnan(res[i]):
        before = res[prev] if prev >= 0 else np.nan
        jump = res[i] >= p["residual_step"] and (
            np.isnan(before) or res[i] >= p["residual_jump"] * before)
        level = max(p["residual_step"], ((0.0 if np.isnan(before) else before) + res[i]) / 2)
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


def _exposure_context(df: pd.DataFrame, p: Params) -> pd.DataFrame:
    res, rej = col(df, "photo_residual_med"), col(df, "ratio_reject_rate")
    steps = [_step_at(i, res, rej, p) for i in range(len(df))]
    return pd.DataFrame({"prev_photo_residual_med": np.concatenate([[np.nan], res[:-1]]),
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
    out = np.zeros(len(df), dtype=bool)
    for i in np.flatnonzero(candidate).tolist():
        jump, after = _step_at(i, res, rej, p)
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
           f"photo_residual_med {_fmt(res)} vs >= {p['residual_step']:g} (healthy ~4, step 20-25)"]
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
                       "rejects ~55%); a scene cut or repetition, not an exposure step")
    if rec > 0:
        out.append(f"recovered {rec:.0f} frame(s) later (a step recovers within "
                   f"{p['recovery_frames']:g})")
    elif rec == 0:
        out.append(f"still disturbed {p['recovery_frames']:g} frames later: a ramp (lights "
                   "fading, flicker), not an auto-exposure step")
    if np.isnan(prev):
        out.append("no residual on the frame before: the motion-blur look-alike cannot be "
                   "ruled out by onset")
    elif _v(row, "jumps") == 1.0:
        out.append(f"motion blur ruled out: the residual jumped from {prev:.1f} in one frame; "
                   "blur degrades over several frames, a step is one frame wide")
    else:
        out.append(f"residual {prev:.1f} on the frame before: no one-frame jump (x"
                   f"{p['residual_jump']:g}), which reads as gradual degradation (motion blur: "
                   "check gyro rate), not an exposure step")
    return out


# --- §4 of docs/derivations.md: H/E x parallax quadrants -------------------------------------------------------

def _quadrant(he: np.ndarray, par: np.ndarray, p: Params) -> np.ndarray:
    """0 healthy, 1 nearly stationary, 2 planar, 3 pure rotation, -1 not computable."""
    q = np.full(len(he), -1)
    ok = ~np.isnan(he) & ~np.isnan(par)
    degenerate = he > p["he_degenerate"]
    low = par < p["parallax_split_deg"]
    q[ok & ~degenerate & ~low] = 0
    q[ok & ~degenerate & low] = 1
    q[ok & degenerate & ~low] = 2
    q[ok & degenerate & low] = 3
    return q


def _keyframe_read(df: pd.DataFrame, p: Params) -> pd.DataFrame:
    """H/E and parallax as read where each row's reference keyframe saw the most parallax.

    H/E carries no information at low parallax: with a tiny baseline any scene fits a
    homography within the RANSAC threshold, so every frame just after a keyframe change reads
    H/E ~ 0.95. Degeneracy is a property of the scene between two keyframes, so each row takes
    the medians of H/E and parallax over the upper half (by parallax) of the rows sharing its
    reference; the median keeps one noisy frame from deciding the interval. The rotation read is
    the largest the reference saw (a pan grows from zero at each keyframe change). Rows without
    a `ref_frame` (or with read_at = "frame") are read on their own.
    """
    he, par = col(df, "h_over_e"), col(df, "parallax_med_deg")
    par_px, rot = col(df, "parallax_med_px"), col(df, "rot_deg")
    ref = col(df, "ref_frame")
    out = pd.DataFrame({"kf_h_over_e": he, "kf_parallax_med_deg": par,
                        "kf_parallax_med_px": par_px, "kf_rot_deg": rot,
                        "kf_intervals": np.where(ref >= 0, 1.0, np.nan)})
    valid = ~np.isnan(he) & ~np.isnan(par) & (ref >= 0)
    if p.get("read_at", "frame") != "keyframe" or not valid.any():
        return out
    pos = np.flatnonzero(valid)
    rows = pd.DataFrame({"ref": ref[pos], "par": par[pos], "he": he[pos], "px": par_px[pos],
                         "rot": rot[pos]})
    read = _upper_half_read(rows, "par")
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


# H/E separates a plane from 3D structure only when points off the plane move off the
# plane-induced homography by more than its RANSAC threshold (2.45 px at sigma = 1 px). A point
# at depth Z moves off it by about parallax_px * |1 - Z_plane / Z|, about half the parallax
# for a scene spanning 2:1 in depth: below twice the threshold the reading carries little.
WEAK_HE_PARALLAX_PX = 2 * homography_threshold_px(1.0)


def _wanted_quadrant(df: pd.DataFrame, p: Params) -> tuple[pd.DataFrame, np.ndarray]:
    """The keyframe reading, and which rows it puts in the quadrant the rule wants."""
    read = _keyframe_read(df, p)
    with np.errstate(invalid="ignore"):
        q = _quadrant(read["kf_h_over_e"].to_numpy(), read["kf_parallax_med_deg"].to_numpy(), p)
    return read, q == (3 if p["want"] == "pure_rotation" else 2)


def _he_parallax(df: pd.DataFrame, p: Params) -> np.ndarray:
    read, hit = _wanted_quadrant(df, p)
    with np.errstate(invalid="ignore"):
        if "min_entropy" in p:
            # features crowded into a small cone are locally planar: a homography fits them
            # whatever the scene, so H/E only reads the scene when the features are spread
            hit &= constraint_entropy(df) >= p["min_entropy"]
        if "min_rotation_deg" in p:
            # no rotation either: a robot standing still, which accumulates no baseline and
            # stays safe; the failure is the parked camera that pans
            hit &= ~(read["kf_rot_deg"].to_numpy() < p["min_rotation_deg"])
        if "min_parallax_px" in p:
            # below it a 3D scene fits H nearly as well as E: the reading cannot tell (a table
            # without parallax_med_px is read as before)
            hit &= ~(read["kf_parallax_med_px"].to_numpy() < p["min_parallax_px"])
    return hit


def _he_parallax_unread(df: pd.DataFrame, p: Params) -> tuple[np.ndarray, str]:
    """Rows whose reading falls in the wanted quadrant but with too little image parallax for
    H/E to tell a plane from a 3D scene (min_parallax_px)."""
    if "min_parallax_px" not in p:
        return np.zeros(len(df), dtype=bool), ""
    read, wanted = _wanted_quadrant(df, p)
    with np.errstate(invalid="ignore"):
        low = read["kf_parallax_med_px"].to_numpy() < p["min_parallax_px"]
    return wanted & low, (
        f"H/E > {p['he_degenerate']:g} over a keyframe interval whose parallax stayed under "
        f"{p['min_parallax_px']:g} px in the image, also when read two keyframe intervals back, "
        "where a 3D scene fits a homography nearly as well as E; a higher resolution or a longer "
        "keyframe baseline lets it be read")


_QUADRANT_WORDS = {
    -1: "quadrant unknown: h_over_e or parallax_med_deg not computable",
    0: "healthy quadrant (H/E low, parallax high): the normal operating point",
    1: "nearly stationary with 3D structure (H/E low, parallax low): safe, triangulate nothing yet",
    2: "planar quadrant (H/E high, parallax high): decompose H instead of E",
    3: "pure-rotation quadrant (H/E high, parallax low): do not estimate t, do not triangulate",
}


def _he_parallax_explain(row: Mapping[str, Any], p: Params) -> list[str]:
    he, par = _v(row, "h_over_e"), _v(row, "parallax_med_deg")
    kf_he, kf_par = _v(row, "kf_h_over_e"), _v(row, "kf_parallax_med_deg")
    out = [f"this frame: h_over_e {_fmt(he)}, parallax_med_deg {_fmt(par)}"]
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
    with np.errstate(invalid="ignore"):
        q = int(_quadrant(np.array([he]), np.array([par]), p)[0])
    out += [f"degenerate > {p['he_degenerate']:g} (general 3D < 0.5); parallax split at "
            f"{p['parallax_split_deg']:g} deg (rotation < 0.1, plane 2-3)", _QUADRANT_WORDS[q]]
    px = _v(row, "kf_parallax_med_px")
    px = _v(row, "parallax_med_px") if np.isnan(px) else px
    floor = float(p.get("min_parallax_px", WEAK_HE_PARALLAX_PX))
    if q == 2 and px < floor:
        out.append(f"not read: the parallax is {px:.2g} px in the image, under {floor:.2g} px "
                   "(twice the homography threshold), so a 3D scene also fits H nearly as well "
                   "as E (low resolution or short baseline)")
    ent = float(np.fmin(_v(row, "entropy_norm"), _v(row, "entropy_inliers_norm")))
    if "min_entropy" in p and not ent >= p["min_entropy"]:
        out.append(f"not read: entropy (keypoints or inliers, the lower) {_fmt(ent)} < "
                   f"{p['min_entropy']:g}, clustered features fit a homography whatever the "
                   "scene (feature_clustering look-alike)")
    rot = _v(row, "kf_rot_deg")
    rot = _v(row, "rot_deg") if np.isnan(rot) else rot
    if q == 3 and "min_rotation_deg" in p and rot < p["min_rotation_deg"]:
        out.append(f"not read as pure rotation: rotation {rot:.2g} deg < "
                   f"{p['min_rotation_deg']:g}, the camera is standing still (no baseline, "
                   "no keyframes: safe)")
    if q == 3:
        out.append(f"planar_degeneracy ruled out by parallax {par:.3g} deg < "
                   f"{p['parallax_split_deg']:g}")
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
CHECKS: dict[str, Check] = {c.name: c for c in [
    Check("matching_table", "three-way matching table: repetitive structure is ~85% ratio-test rejection "
          "with the features intact (not ~120 features: detection failure) and not inside the "
          "2-3 frames after an exposure step (~55%, recovering)", "frame", "camera",
          ("n_keypoints", "keypoint_fill", "ratio_reject_rate", "d_mean_intensity"),
          {"fill_floor": _NUM, "reject_repetitive": _NUM, "dmean_step": _NUM,
           "recovery_frames": _NUM, "max_interval_s": _NUM},
          {"n_keypoints": "min", "ratio_reject_rate": "max"},
          {"fill_floor": "keypoint_fill", "reject_repetitive": "ratio_reject_rate",
           "dmean_step": "d_mean_intensity"},
          frame=_matching_table, explain=_matching_table_explain, context=_matching_context,
          optional=frozenset({"max_interval_s"}), unread=_matching_unread),
    Check("exposure_step", "a jump of mean intensity with the photometric residual "
          "jumping with it, clean before and clean again within 2-3 frames",
          "frame", "camera",
          ("d_mean_intensity", "photo_residual_med", "ratio_reject_rate", "affine_gain",
           "photo_residual_affine_med"),
          {"dmean_step": _NUM, "residual_step": _NUM, "residual_jump": _NUM,
           "residual_affine_max": _NUM, "reject_exposure": _NUM, "reject_max": _NUM,
           "recovery_frames": _NUM},
          {"d_mean_intensity": "absmax", "photo_residual_med": "max", "affine_gain": "absdev1"},
          {"dmean_step": "d_mean_intensity", "residual_step": "photo_residual_med",
           "reject_exposure": "ratio_reject_rate", "reject_max": "ratio_reject_rate",
           "residual_affine_max": "photo_residual_affine_med"},
          frame=_exposure_step, explain=_exposure_explain, context=_exposure_context,
          optional=frozenset({"residual_affine_max"})),
    Check("he_parallax_quadrant", "H/E inlier ratio x median parallax separates pure "
          "rotation, a planar scene, a nearly stationary camera and healthy motion",
          "frame", "camera", ("h_over_e", "parallax_med_deg", "ref_frame", "entropy_norm",
                              "entropy_inliers_norm", "parallax_med_px", "rot_deg"),
          {"want": "choice:pure_rotation|planar_degeneracy", "he_degenerate": _NUM,
           "parallax_split_deg": _NUM, "read_at": "choice:keyframe|frame",
           "min_entropy": _NUM, "min_parallax_px": _NUM, "min_rotation_deg": _NUM},
          {"h_over_e": "max", "parallax_med_deg": "min"},
          {"he_degenerate": "h_over_e", "parallax_split_deg": "parallax_med_deg",
           "min_entropy": "entropy_norm", "min_parallax_px": "parallax_med_px",
           "min_rotation_deg": "rot_deg"},
          frame=_he_parallax, explain=_he_parallax_explain, context=_keyframe_read,
          optional=frozenset({"min_entropy", "min_parallax_px", "min_rotation_deg"}),
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
