"""The camera frontend, one call per frame: detect, match, verify geometry, check photometry.

Matching statistics are always against the previous frame (unguided, global). Geometry is
against a reference keyframe; correspondences with it come from feature tracks carried by
chaining frame-to-frame matches, so no second full matching is needed. Tracks broken by one
missed frame-to-frame match are re-linked by matching only the keyframe features that lost
their track against only the current features that have none (a small sub-matrix).

Keyframe policy (docs/derivations.md §4), decided after each frame; the frame that triggers it
becomes the reference of the frames that follow:

* ``lost``          — fewer than ``min_correspondences`` correspondences with the reference;
* ``max_frames``    — ``kf_max_frames`` (20) frames have passed since the reference;
* ``tracked_share`` — tracks alive / tracks the reference established in the frame after it
  fall below ``kf_min_tracked_share`` (0.9);
* ``parallax``      — the median parallax reaches ``kf_parallax_deg``; 2.29 deg is a baseline
  of 4% of the median depth (tan 2.29 deg = 0.04), the "few percent of the median tracked
  depth" of the reference figures, measured as an angle because monocular scale is unknown.

H/E needs parallax to say anything: below about twice the homography threshold (4.9 px at
sigma = 1 px) a 3D scene fits H nearly as well as E. When a keyframe interval is that short
(a high frame rate, a low resolution, or tracks thinning as a wall fills the view), the frame is
also read against the keyframe before its reference, over the tracks alive across both
intervals: ``h_over_e_2kf`` and ``parallax_med_px_2kf`` (``ref2_frame`` names that keyframe).
That reading is frontdiag's, not a stage of the frontend: its time is ``ms_diagnostic``, outside
``ms_geometry`` and ``ms_total``. It is needed only where the interval as a whole is short, so it
is taken when the interval closes (the next keyframe, a reset, or :meth:`finish`): the frames
under 4.9 px of an interval whose own reading — the median image parallax over its upper half by
parallax, as FD-PLN-001 reads it — stays under ``two_interval_px`` are read then, and the rows
get them through :meth:`take_updates`; the frames of longer intervals are not read (their
``*_2kf`` columns stay empty: the H/E reading of their own interval holds), nor those of an
interval that, added to the one before it, stays far under the line (a camera standing still),
whose reading the rule could not use either.

The rotation-only fit (``rot_only_px``, ``rot_focal_scale``) is frontdiag's too, and is only
needed where it can move a frame from the planar quadrant to the rotation quadrant: where H/E is
above ``rot_fit_he`` with parallax at least ``rot_fit_parallax_deg``, read on the frame itself or
over its interval (the medians over the interval's upper half by parallax, where FD-PLN-001 and
FD-ROT-001 take the reading). So it is also taken when the interval closes, on the frames of its
upper half when the interval's reading is in that quadrant and on any frame whose own reading
is. It is also taken on the frames of that upper half when their median rotation moves the image
by at least ``rot_fit_turn_px``, whatever H/E: a camera that only turns leaves E without a
translation, so E takes every correct correspondence for any epipole plus the mismatches along
the one RANSAC picks, and H/E falls with the mismatch share (FD-ROT-001's ``rot_fit_turn_px``,
read over the same frames). Elsewhere the
columns stay empty, since a rotation fit cannot change a quadrant whose H/E is low or whose
parallax is already under the split.

A keyframe interval can be much shorter than a turn or a stop (at 30 Hz a hand-held camera's
tracked share falls under 0.9 within 1-4 frames of a sweep), and over so short a baseline a
walking camera's parallax stays within the noise a rotation-only model leaves. So where an
interval lasted under ``rot_span_s`` (0.33 s, the time FD-ROT-001's persistence window spans)
and could read as a turn or as standing still (its parallax, the median over its upper half,
under ``rot_fit_parallax_deg``, or a rotation-only fit within the homography threshold), its last
frame is also read against the newest kept frame at least ``rot_span_s`` before it, matched
directly (``span_frame``): E, its residual, the parallax and the rotation-only fit over the
span (``*_span`` columns, on every row of the interval). A camera that only turns or stands
still is still explained by a rotation over the longer span; a translating one is not. Frames
are kept for this as descriptors and points only, and only as far back as a later interval
can read.

The span is longer where the focal length in pixels is short: ``rot_span_s`` times
``rot_span_focal_px / f`` below ``rot_span_focal_px`` (495 px). Its lines are noise lines in
pixels (the homography threshold, 2.45 px at sigma = 1 px), but a moving camera's parallax in
pixels is proportional to f: the slowest motion the span must tell from standing still (1 % of
the scene's depth in 0.2 s, 0.05 depths a second), moving forward (median sine of the angle
between a ray and the direction of travel about 0.3 over a 60 deg view), moves points
f x 0.05 x 0.3 x 0.33 px in 0.33 s, which is 2.45 px at f = 495 px. At half that focal length
(the same camera at half the resolution) the same motion needs twice the time to rise above the
same noise; a camera standing still stays under the lines however long the span.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from typing import Any

import cv2
import numpy as np

from frontdiag.camera.features import (
    EDGE,
    ENTROPY_GRID,
    MIN_ENTROPY_POINTS,
    Features,
    OrbExtractor,
    coarse_texture,
    entropy_from_counts,
    grid_counts,
    lit_share,
    shared_entropy,
    spatial_entropy,
)
from frontdiag.camera.geometry import (
    E_SAMPLE,
    homography_threshold_px,
    ransac_iters_required,
    ransac_iters_run,
    rotation_only_fit,
    shared_cells,
    two_view,
    undistort_points,
)
from frontdiag.camera.matching import copy_line_bits, in_frame_twin_rate, match
from frontdiag.camera.photometric import photometric
from frontdiag.io.camera_info import CalibrationsBySize, fit_to_images
from frontdiag.metrics import DEFAULT_FEATURE_BUDGET, keypoint_fill
from frontdiag.records import (
    KP_INLIER,
    KP_OUTLIER,
    KP_TRACKED,
    KP_UNTRACKED,
    SIZE_STATUS,
    CameraAnnotation,
    CameraFrame,
    Intrinsics,
)
from frontdiag.timing import Clock, StageTimer

NAN = float("nan")
# two-interval readings are skipped where both intervals' largest parallaxes together stay under
# this share of the line they are read against (``_two_intervals_short``)
TWO_INTERVAL_MARGIN = 0.5
# frames kept for the span reading at most: 0.33 s at 750 Hz, about 10 MB of descriptors and
# points at 1000 keypoints; only stamps that do not advance come near it
SPAN_HISTORY_MAX = 256
# Images whose size differs by at most this many pixels a side from the reference keyframe's
# (or from the calibration's) show the same view: an editor's or a driver's crop or pad by a pixel
# or two (a set of 1280x720 photographs holding some 1281x721 ones). K describes them within
# that many pixels of principal point, under the 2.45 px homography threshold at the frontend's
# 1 px localisation noise, so the frontend goes on matching and keeps K; a larger change is
# another camera setting and restarts it.
SAME_VIEW_PX = 2


@dataclass(frozen=True)
class CameraParams:
    """Frontend parameters; the defaults are the reference figures'."""

    n_features: int = DEFAULT_FEATURE_BUDGET
    n_levels: int = 8
    scale_factor: float = 1.2
    fast_threshold: int = 20
    fast_threshold_min: int = 7
    grid_cols: int = 8  # bucketing grid (the entropy grid is fixed at 8x6)
    grid_rows: int = 6
    ratio: float = 0.8
    mutual: bool = True
    ransac_confidence: float = 0.999
    sigma_px: float = 1.0
    ransac_max_iters: int = 1000
    min_correspondences: int = 15
    kf_max_frames: int = 20
    kf_min_tracked_share: float = 0.9
    kf_parallax_deg: float = 2.29
    relink_tracks: bool = True
    two_interval_px: float = 4.9  # read intervals shorter than this two keyframes back
    rot_fit_he: float = 0.9  # rotation-only fit where H/E is above this (module docstring)
    rot_fit_parallax_deg: float = 0.3  # ... with at least this much parallax
    rot_fit_turn_px: float = 10.0  # ... and on intervals that turned this much, whatever H/E
    rot_span_s: float = 0.33  # read the motion over at least this long (module docstring)
    rot_span_focal_px: float = 495.0  # ... longer in proportion below this focal length
    seed: int = 0

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class _View:
    """What is kept of a frame: features, undistorted points, tracks."""

    index: int
    gray: np.ndarray
    feats: Features
    und: np.ndarray  # (N, 2) undistorted pixel coordinates
    kf_idx: np.ndarray  # (N,) index of the reference keyframe feature this one tracks, or -1
    mean: float = NAN
    t_ns: int = 0


@dataclass(frozen=True)
class _Past:
    """What the span reading needs of an earlier frame: its descriptors and points."""

    index: int
    t_ns: int
    des: np.ndarray
    und: np.ndarray


@dataclass
class _Keyframe:
    view: _View
    n_base: int = 0  # tracks established in the first frame after the keyframe
    frames: int = 0  # frames processed since it became the reference
    last_t: np.ndarray | None = None
    parent: _View | None = None  # the keyframe before this one, when tracks link the two
    parent_idx: np.ndarray | None = None  # per feature of ``view``: its track in ``parent``, or -1
    reads: list[tuple[float, float, float, float]] = field(default_factory=list)
    """(parallax deg, parallax px, H/E, rotation px) per row with both readings; the rotation
    in pixels is f tan(rotation), how far it moves a point at the image centre."""
    pending: list[tuple[int, np.ndarray, np.ndarray]] = field(default_factory=list)
    """Two-interval readings to take if the interval turns out short: (frame, parent points,
    current points)."""
    rot_pending: list[tuple[int, float, float, np.ndarray, np.ndarray]] = field(
        default_factory=list)
    """Rotation-only fits to take if the frame or its interval reads H/E high with parallax, or
    the interval turned: (frame, H/E, parallax deg, reference inliers, current inliers)."""
    parent_deg: float = NAN
    """The largest median parallax (deg) a frame of the parent's interval read against the
    parent: the first leg of this interval's two-interval readings (NaN when none was read)."""
    row_frames: list[int] = field(default_factory=list)
    """The frames read against this keyframe, in order (the interval's rows)."""

    def largest_parallax_deg(self) -> float:
        """The largest median parallax (deg) a frame of this interval read against it (NaN when
        none was read)."""
        return max((r[0] for r in self.reads), default=NAN)


def _row_template() -> dict[str, Any]:
    return {
        "n_keypoints": 0, "n_weak_keypoints": 0, "keypoint_fill": NAN, "entropy_norm": NAN,
        "occupied_cells": 0, "entropy_inliers_norm": NAN, "entropy_inliers_shared_norm": NAN,
        "n_coarse_keypoints": 0,
        "coarse_hull_share": NAN, "lit_share": NAN,
        "n_putative": 0, "ratio_reject_rate": NAN, "ratio_ambiguous_rate": NAN,
        "match_dist_med": NAN, "in_frame_twin_rate": NAN, "n_matches": 0,
        "ref_frame": -1, "n_ref_matches": 0, "tracked_share": NAN,
        "inliers_e": NAN, "inliers_h": NAN, "h_over_e": NAN, "inlier_ratio": NAN,
        "ransac_iters_required": NAN, "ransac_iters_run": NAN, "parallax_med_deg": NAN,
        "parallax_med_px": NAN, "rot_deg": NAN, "rot_only_px": NAN, "rot_focal_scale": NAN,
        "epi_residual_px": NAN,
        "t_dir_change_deg": NAN, "pose_info_cond": NAN,
        "ref2_frame": -1, "h_over_e_2kf": NAN, "parallax_med_deg_2kf": NAN,
        "parallax_med_px_2kf": NAN,
        "span_frame": -1, "span_dt_s": NAN, "rot_only_px_span": NAN, "epi_residual_px_span": NAN,
        "parallax_med_deg_span": NAN,
        "mean_intensity": NAN, "d_mean_intensity": NAN, "photo_residual_med": NAN,
        "affine_gain": NAN, "affine_bias": NAN, "photo_residual_affine_med": NAN,
        "brightness_ratio": NAN, "brightness_ratio_se": NAN, "keyframe_reason": "", "ms_detect": 0.0, "ms_match": 0.0, "ms_geometry": 0.0,
        "ms_photometric": 0.0, "ms_diagnostic": 0.0, "ms_total": 0.0, "status": "ok",
    }


def _measurable(shape: tuple[int, ...]) -> bool:
    """Whether a grey frame of this shape is large enough for the extractor to detect on (a
    smaller one reads ``no_features``, whatever its size)."""
    return len(shape) == 2 and min(shape) > 2 * EDGE + 2


def span_seconds(p: CameraParams, fx: float | None) -> float:
    """How long the span reading reads the motion over: ``rot_span_s``, and in proportion
    longer where the focal length ``fx`` (px) is under ``rot_span_focal_px`` (module
    docstring), so that the slowest motion it must see rises above localisation noise within
    it at any resolution."""
    if fx is None or fx <= 0 or p.rot_span_focal_px <= 0:
        return p.rot_span_s
    return p.rot_span_s * max(1.0, p.rot_span_focal_px / fx)


class CameraFrontend:
    """Stateful per-recording frontend; ``process`` returns one metrics row per frame."""

    def __init__(self, params: CameraParams = CameraParams(),
                 intrinsics: Intrinsics | None = None,
                 clock: Clock = time.perf_counter,
                 calibrations: CalibrationsBySize | None = None) -> None:
        self.params = params
        self.intrinsics = intrinsics
        # the recording's own CameraInfo for another image size, where it has one
        self._calibrations = calibrations
        self._clock = clock
        self._K = None if intrinsics is None else np.asarray(intrinsics.K, np.float64)
        # the calibration as given (for the images' first size), and fitted to each other size
        # the images come in (:meth:`_fit_to_size`)
        self._base = intrinsics
        self._fits: dict[tuple[int, int], tuple[Intrinsics, str]] = {}
        self.resized: str | None = None
        """Set by ``process`` when the frame's size differs from the reference keyframe's (by
        more than SAME_VIEW_PX): ``"WxH -> W'xH': "`` and what became of K; None otherwise."""
        self._extractor = OrbExtractor(params.n_features, params.n_levels, params.scale_factor,
                                       params.fast_threshold, params.fast_threshold_min,
                                       params.grid_cols, params.grid_rows)
        self._prev: _View | None = None
        self._kf: _Keyframe | None = None
        self._he_min_px = 2 * homography_threshold_px(params.sigma_px)
        self._two_interval_sel: np.ndarray | None = None
        self._updates: list[tuple[int, dict[str, Any]]] = []
        self._history: list[_Past] = []  # recent frames, for the span reading
        self._grid = np.zeros((0, 0), np.int64)
        self._state: np.ndarray | None = None
        self._flow: tuple[int, np.ndarray, np.ndarray] | None = None
        self.last_annotation: CameraAnnotation | None = None
        """What the last ``process`` call computed, for drawing (see CameraAnnotation)."""

    def reset(self) -> None:
        self._close_interval(self._prev)
        self._prev = None
        self._kf = None
        self._history = []

    def finish(self) -> None:
        """The end of the frames: close the open interval (see :meth:`take_updates`)."""
        self._close_interval(self._prev)

    def take_updates(self) -> list[tuple[int, dict[str, Any]]]:
        """Columns of earlier rows completed since the last call: ``(frame, values)``."""
        out, self._updates = self._updates, []
        return out

    @property
    def pending(self) -> bool:
        """Whether rows already returned may still be completed by later frames."""
        kf = self._kf
        if kf is None:
            return False
        return bool(kf.pending or kf.rot_pending or self._span_open(kf))

    def _span_open(self, kf: _Keyframe) -> bool:
        """Whether the open interval may still get a span reading: it has rows and has lasted
        under ``rot_span_s`` so far."""
        if not kf.row_frames or self._prev is None or self._K is None:
            return False
        return (self._prev.t_ns - kf.view.t_ns) * 1e-9 < self._span_s()

    def _span_s(self) -> float:
        return span_seconds(self.params, None if self._K is None else float(self._K[0, 0]))

    # ------------------------------------------------------------------ state (for windows)
    def state_key(self) -> tuple[int, int, int] | None:
        """What the rows of the following frames depend on, in comparable form.

        The reference keyframe and the keyframe before it (-1 when tracks do not link them),
        and the oldest frame kept for the span reading (-1 when none). Every track, count and
        direction the frontend keeps is built from the frames since the earlier of the two
        keyframes, which became a keyframe with fresh tracks, and the kept frames are pruned by
        their stamps alone (and a cap); so two runs with the same key after frame f hold the same state and give
        the same rows from f + 1 on (the previous frame is f in both).
        """
        kf = self._kf
        if kf is None:
            return None
        return kf.view.index, -1 if kf.parent is None else kf.parent.index, \
            self._history[0].index if self._history else -1

    def get_state(self) -> tuple[Any, Any, Any]:
        """The frontend's state between frames (picklable), for handing a run on."""
        return self._prev, self._kf, list(self._history)

    def set_state(self, state: tuple[Any, ...]) -> None:
        self._prev, self._kf = state[0], state[1]
        self._history = list(state[2]) if len(state) > 2 else []

    # ------------------------------------------------------------------ stages
    def _detect(self, frame: CameraFrame, row: dict[str, Any]) -> _View:
        gray = frame.gray
        if gray.dtype != np.uint8 or gray.ndim != 2:
            gray = np.zeros((0, 0), np.uint8) if gray.size == 0 else gray.astype(np.uint8)
        feats = self._extractor.detect_and_compute(gray) if gray.ndim == 2 else Features.empty()
        h, w = gray.shape[:2] if gray.ndim >= 2 else (0, 0)
        counts = grid_counts(feats.xy, w, h)
        ent = entropy_from_counts(counts) if len(feats) else NAN
        occ = int(np.count_nonzero(counts))
        self._grid = counts
        fill = float(keypoint_fill(len(feats), w, h, self.params.n_features))
        n_coarse, hull = coarse_texture(feats, w, h, self.params.fast_threshold)
        row.update(n_keypoints=len(feats), n_weak_keypoints=feats.n_weak, entropy_norm=ent,
                   occupied_cells=occ, keypoint_fill=fill, n_coarse_keypoints=n_coarse,
                   coarse_hull_share=hull)
        mean = float(cv2.mean(gray)[0]) if gray.size else NAN
        row["mean_intensity"] = mean
        row["lit_share"] = lit_share(gray, self.params.fast_threshold) if gray.size else NAN
        und = undistort_points(feats.xy, self.intrinsics)
        return _View(frame.index, gray, feats, und,
                     np.full(len(feats), -1, np.intp), mean, int(frame.t_ns))

    def _match(self, cur: _View, prev: _View, kf: _Keyframe, row: dict[str, Any]
               ) -> tuple[np.ndarray, np.ndarray]:
        p = self.params
        m = match(cur.feats.des, prev.feats.des, p.ratio, p.mutual)
        row.update(n_putative=m.n_putative, ratio_reject_rate=m.ratio_reject_rate,
                   ratio_ambiguous_rate=m.ratio_ambiguous_rate, n_matches=len(m.query))
        f = cur.feats
        row["match_dist_med"] = m.d_accepted_med
        row["in_frame_twin_rate"] = in_frame_twin_rate(
            f.des, f.xy, f.octave, copy_line_bits(m.d_accepted_med, p.ratio), p.scale_factor)
        cur.kf_idx[m.query] = prev.kf_idx[m.train]
        if p.relink_tracks and kf.view is not prev and len(kf.view.feats):
            self._relink(cur, kf.view)
        return m.query, m.train

    def _relink(self, cur: _View, kfv: _View) -> None:
        """Re-find keyframe features whose track broke, among current features without one."""
        alive = np.zeros(len(kfv.feats), bool)
        tracked = cur.kf_idx >= 0
        alive[cur.kf_idx[tracked]] = True
        lost = np.flatnonzero(~alive)
        free = np.flatnonzero(~tracked)
        if len(lost) < 2 or len(free) == 0:
            return
        p = self.params
        m = match(cur.feats.des[free], kfv.feats.des[lost], p.ratio, p.mutual)
        cur.kf_idx[free[m.query]] = lost[m.train]

    def _geometry(self, cur: _View, kf: _Keyframe, row: dict[str, Any]) -> bool:
        """E/H against the reference; returns whether the reference is lost."""
        p = self.params
        row["ref_frame"] = kf.view.index
        sel = np.flatnonzero(cur.kf_idx >= 0)
        n = len(sel)
        row["n_ref_matches"] = n
        if kf.frames == 1:
            kf.n_base = n
        row["tracked_share"] = n / kf.n_base if kf.n_base else NAN
        if n < max(p.min_correspondences, E_SAMPLE):
            row["status"] = "too_few_matches"
            return True
        p_ref = kf.view.und[cur.kf_idx[sel]]
        p_cur = cur.und[sel]
        tv = two_view(p_ref, p_cur, self._K, sigma_px=p.sigma_px,
                      confidence=p.ransac_confidence, max_iters=p.ransac_max_iters, seed=p.seed)
        self._note_correspondences(cur, kf, sel, tv.inlier_mask)
        row.update(inliers_h=tv.inliers_h)
        if tv.inlier_mask is not None and np.count_nonzero(tv.inlier_mask) >= MIN_ENTROPY_POINTS:
            h, w = cur.gray.shape[:2]
            xy_in = cur.feats.xy[sel[tv.inlier_mask]]
            row["entropy_inliers_norm"] = spatial_entropy(xy_in, w, h)[0]
            shared = shared_cells(tv.H, p_cur[tv.inlier_mask], self.intrinsics, w, h,
                                  ENTROPY_GRID)
            if shared is not None:
                row["entropy_inliers_shared_norm"] = shared_entropy(xy_in, shared, w, h)
        if self._K is None:
            row["status"] = "no_intrinsics"
            return False
        row.update(inliers_e=tv.inliers_e, h_over_e=tv.h_over_e, inlier_ratio=tv.inlier_ratio,
                   rot_deg=tv.rot_deg, parallax_med_deg=tv.parallax_med_deg,
                   pose_info_cond=tv.pose_info_cond, epi_residual_px=tv.epi_residual_px,
                   ransac_iters_required=ransac_iters_required(tv.inlier_ratio, E_SAMPLE,
                                                               p.ransac_confidence),
                   ransac_iters_run=ransac_iters_run(tv.inlier_ratio, p.ransac_max_iters,
                                                     E_SAMPLE, p.ransac_confidence))
        if tv.parallax_med_deg == tv.parallax_med_deg:
            row["parallax_med_px"] = self._deg_to_px(tv.parallax_med_deg)
            if row["h_over_e"] == row["h_over_e"]:
                kf.reads.append((tv.parallax_med_deg, row["parallax_med_px"], row["h_over_e"],
                                 self._deg_to_px(min(tv.rot_deg, 89.0))))
                if tv.inlier_mask is not None and tv.ok_e:
                    # read when the interval closes, if it can change the quadrant
                    kf.rot_pending.append((cur.index, row["h_over_e"], tv.parallax_med_deg,
                                           p_ref[tv.inlier_mask], p_cur[tv.inlier_mask]))
            if row["parallax_med_px"] < self._he_min_px:
                self._two_interval_sel = sel  # read after the geometry stage (diagnostic)
        if not tv.ok_e:
            row["status"] = "essential_failed"
            return False
        if kf.last_t is not None and tv.t_dir is not None:
            c = float(np.clip(np.dot(kf.last_t, tv.t_dir), -1.0, 1.0))
            row["t_dir_change_deg"] = math.degrees(math.acos(c))
        kf.last_t = tv.t_dir
        return False

    def _note_correspondences(self, cur: _View, kf: _Keyframe, sel: np.ndarray,
                              inliers: np.ndarray | None) -> None:
        """Keep which keypoints the geometry stage read and the inliers' flow from the
        reference, for drawing (``last_annotation``); indexing only, nothing is recomputed."""
        state = np.full(len(cur.feats), KP_UNTRACKED, np.uint8)
        if inliers is None or len(inliers) != len(sel):
            state[sel] = KP_TRACKED
            used = sel[:0]
        else:
            state[sel] = np.where(inliers, KP_INLIER, KP_OUTLIER)
            used = sel[inliers]
        self._state = state
        self._flow = (kf.view.index, kf.view.feats.xy[cur.kf_idx[used]], cur.feats.xy[used])

    def _annotation(self, cur: _View) -> CameraAnnotation:
        h, w = cur.gray.shape[:2] if cur.gray.ndim == 2 else (0, 0)
        n = len(cur.feats)
        state = self._state if self._state is not None and len(self._state) == n \
            else np.full(n, KP_UNTRACKED, np.uint8)
        empty = np.zeros((0, 2), np.float32)
        ref, f_ref, f_cur = self._flow if self._flow is not None else (-1, empty, empty)
        return CameraAnnotation(int(w), int(h), np.asarray(cur.feats.xy, np.float32).reshape(-1, 2),
                                state, self._grid, int(ref), np.asarray(f_ref, np.float32),
                                np.asarray(f_cur, np.float32))

    def _deg_to_px(self, deg: float) -> float:
        assert self._K is not None
        return float(self._K[0, 0] * math.tan(math.radians(deg)))

    def _queue_two_intervals(self, cur: _View, kf: _Keyframe, sel: np.ndarray) -> None:
        """Keep this frame's correspondences with the keyframe before the reference, to read
        when the interval closes (module docstring)."""
        if kf.parent is None or kf.parent_idx is None:
            return
        p = self.params
        idx = kf.parent_idx[cur.kf_idx[sel]]
        ok = idx >= 0
        if ok.sum() < max(p.min_correspondences, E_SAMPLE):
            return
        kf.pending.append((cur.index, kf.parent.und[idx[ok]], cur.und[sel[ok]]))

    def _interval_short(self, kf: _Keyframe) -> bool:
        """The interval's own reading: median image parallax over its upper half by parallax
        (degrees), as the planar rule reads a keyframe interval; short when under
        ``two_interval_px`` (or when no row could be read)."""
        if not kf.reads:
            return True
        par, px, _, _ = np.array(kf.reads).T
        upper = px[par >= np.median(par)]
        # a hair of margin: reading an interval the rule would not is harmless, the reverse not
        return bool(np.median(upper) < self.params.two_interval_px * (1 + 1e-9))

    def _two_intervals_short(self, kf: _Keyframe) -> bool:
        """Whether both intervals together stay far under the line their reading is used at
        (FD-PLN-001 takes it only where its parallax reaches ``two_interval_px``).

        A static point's parallax is the angle between its rays, rotation removed; angles on the
        sphere obey the triangle inequality, so its parallax across two intervals is at most
        the sum of its parallaxes over each. The intervals' largest per-frame median angles
        stand in for the points' (a median of sums can exceed the sum of medians, and the
        rotations of the two legs are estimated apart), with a margin of 2: the readings are
        skipped when the sum stays under half the line (``two_interval_px``, or the 4.9 px
        under which H/E cannot tell a plane, if lower, as an angle at the focal length). Over
        the validation set and the simulator at three resolutions, the reading the rule takes
        (the median over the upper half of an interval's two-interval parallaxes) came to at
        most 1.83x that sum, and to at most 0.6 of the line where this skips it: a camera
        standing still (EuRoC V1, both cameras), a fixed camera over a plaza, a parked robot
        panning its camera head; slow pans and drives whose two intervals reach the line are
        read as before."""
        own = kf.largest_parallax_deg()
        if self._K is None or math.isnan(own) or math.isnan(kf.parent_deg):
            return False
        line_px = min(self.params.two_interval_px, self._he_min_px)
        line = math.degrees(math.atan(line_px / float(self._K[0, 0])))
        return own + kf.parent_deg < TWO_INTERVAL_MARGIN * line

    def _remember(self, cur: _View) -> None:
        """Keep ``cur`` for the span reading and forget the frames no later interval can read
        against: all but the newest of those at least ``rot_span_s`` older than it."""
        if self._K is None or self.params.rot_span_s <= 0:
            return
        # stamps that went back (a recording spliced or replayed) start the history afresh
        if self._history and self._history[-1].t_ns > cur.t_ns:
            self._history = []
        self._history.append(_Past(cur.index, cur.t_ns, cur.feats.des, cur.und))
        line = cur.t_ns - self._span_s() * 1e9
        old = [i for i, h in enumerate(self._history) if h.t_ns <= line]
        if old:
            del self._history[:old[-1]]
        # stamps that do not advance (a camera driver that repeats them) never make a frame
        # old enough: the history stays bounded anyway
        del self._history[:-SPAN_HISTORY_MAX]

    def _close_interval(self, last: _View | None) -> None:
        """Take the readings that wait for the interval to close: the rotation-only fits that
        can change a quadrant, the span reading if the interval was shorter than
        ``rot_span_s``, and the two-interval readings if the interval was short. ``last`` is
        the interval's last frame."""
        kf = self._kf
        if kf is None:
            return
        fits = self._close_rotation_fits(kf)
        if last is not None and kf.row_frames:
            self._close_span(kf, last, fits)
        kf.row_frames = []  # read (or not) once: nothing of this interval is pending
        if not kf.pending:
            return
        pending, kf.pending = kf.pending, []
        if not self._interval_short(kf) or self._two_intervals_short(kf):
            return
        assert kf.parent is not None
        p = self.params
        for frame, p_par, p_cur in pending:
            t0 = self._clock()
            tv = two_view(p_par, p_cur, self._K, sigma_px=p.sigma_px,
                          confidence=p.ransac_confidence, max_iters=p.ransac_max_iters,
                          seed=p.seed, pose_information=False)
            upd: dict[str, Any] = {}
            if tv.ok_e and tv.parallax_med_deg == tv.parallax_med_deg:
                upd = {"ref2_frame": kf.parent.index, "h_over_e_2kf": tv.h_over_e,
                       "parallax_med_deg_2kf": tv.parallax_med_deg,
                       "parallax_med_px_2kf": self._deg_to_px(tv.parallax_med_deg)}
            upd["ms_diagnostic"] = (self._clock() - t0) * 1e3
            self._updates.append((frame, upd))

    def _close_rotation_fits(self, kf: _Keyframe) -> list[float]:
        """The rotation-only fit of the frames where it can move the reading from the planar
        quadrant to the rotation quadrant (module docstring): frames whose own H/E and parallax
        are in the planar quadrant, and, when the interval's reading (medians over its upper
        half by parallax) is, the frames of that upper half; and the frames of that upper half
        when it turned (median rotation) at least ``rot_fit_turn_px``."""
        pending, kf.rot_pending = kf.rot_pending, []
        fits: list[float] = []
        if not pending or self._K is None:
            return fits
        p = self.params
        # a hair of margin: reading a frame the rules would not is harmless, the reverse not
        he_line = p.rot_fit_he * (1 - 1e-9)
        par_line = p.rot_fit_parallax_deg * (1 - 1e-9)
        turn_line = p.rot_fit_turn_px * (1 - 1e-9)
        par, _, he, turn = np.array(kf.reads).T
        split = float(np.median(par))
        upper = par >= split
        interval = bool(np.median(he[upper]) > he_line and np.median(par[upper]) >= par_line)
        turned = bool(np.nanmedian(turn[upper]) >= turn_line) if upper.any() else False
        for frame, he_f, par_f, p_ref, p_cur in pending:
            own = he_f > he_line and par_f >= par_line
            if not (own or ((interval or turned) and par_f >= split)):
                continue
            t0 = self._clock()
            rpx, scale = rotation_only_fit(p_ref, p_cur, self._K)
            fits.append(rpx)
            self._updates.append((frame, {"rot_only_px": rpx, "rot_focal_scale": scale,
                                          "ms_diagnostic": (self._clock() - t0) * 1e3}))
        return fits

    def _close_span(self, kf: _Keyframe, last: _View, fits: list[float]) -> None:
        """The motion over at least ``rot_span_s``, for an interval shorter than that which
        could read as a turn or as standing still (module docstring): the interval's last frame
        against the newest kept frame at least ``rot_span_s`` before it, matched directly; E,
        its residual, the parallax and the rotation-only fit, written to every row of the
        interval. An interval reads as rotation or standing still only where its parallax
        (the median over its upper half, as the rule reads it) is under
        ``rot_fit_parallax_deg`` or a rotation-only fit explained a row within the homography
        threshold, so only those are read."""
        p = self.params
        if self._K is None or p.rot_span_s <= 0:
            return
        span_s = self._span_s()
        if (last.t_ns - kf.view.t_ns) * 1e-9 >= span_s:
            return
        par_line = p.rot_fit_parallax_deg * (1 - 1e-9)
        par = np.array([r[0] for r in kf.reads])
        # the interval's reading, as FD-ROT-001 takes it: the median over its upper half
        low = bool(par.size) and bool(np.median(par[par >= np.median(par)]) < par_line)
        fit = any(f <= homography_threshold_px(p.sigma_px) for f in fits)
        if not (low or fit):
            return
        line = last.t_ns - span_s * 1e9
        old = [h for h in self._history if h.t_ns <= line and h.index < last.index]
        if not old:
            return
        past = old[-1]
        t0 = self._clock()
        m = match(last.feats.des, past.des, p.ratio, p.mutual)
        upd: dict[str, Any] = {}
        if len(m.query) >= max(p.min_correspondences, E_SAMPLE):
            p_old, p_cur = past.und[m.train], last.und[m.query]
            tv = two_view(p_old, p_cur, self._K, sigma_px=p.sigma_px,
                          confidence=p.ransac_confidence, max_iters=p.ransac_max_iters,
                          seed=p.seed, pose_information=False, homography=False)
            if tv.ok_e and tv.inlier_mask is not None:
                rpx, _ = rotation_only_fit(p_old[tv.inlier_mask], p_cur[tv.inlier_mask], self._K)
                upd = {"span_frame": past.index, "span_dt_s": (last.t_ns - past.t_ns) * 1e-9,
                       "rot_only_px_span": rpx, "epi_residual_px_span": tv.epi_residual_px,
                       "parallax_med_deg_span": tv.parallax_med_deg}
        ms = (self._clock() - t0) * 1e3
        for frame in kf.row_frames:
            self._updates.append((frame, dict(upd)))
        self._updates.append((last.index, {"ms_diagnostic": ms}))

    def _photometric(self, cur: _View, prev: _View, q: np.ndarray, t: np.ndarray,
                     row: dict[str, Any]) -> None:
        row["d_mean_intensity"] = cur.mean - prev.mean
        ph = photometric(prev.gray, cur.gray, prev.feats.xy[t], cur.feats.xy[q])
        row.update(photo_residual_med=ph.residual_med, affine_gain=ph.gain,
                   affine_bias=ph.bias, photo_residual_affine_med=ph.residual_affine_med,
                   brightness_ratio=ph.brightness_ratio,
                   brightness_ratio_se=ph.brightness_ratio_se)

    def _keyframe_reason(self, lost: bool, kf: _Keyframe, row: dict[str, Any]) -> str:
        p = self.params
        if lost:
            return "lost"
        if kf.frames >= p.kf_max_frames:
            return "max_frames"
        share = row["tracked_share"]
        if share == share and share < p.kf_min_tracked_share:
            return "tracked_share"
        par = row["parallax_med_deg"]
        if par == par and par >= p.kf_parallax_deg:
            return "parallax"
        return ""

    def _fit_to_size(self, w: int, h: int) -> str:
        """Use the calibration fitted to ``w x h`` images (as a CameraInfo made for another
        size is: K scaled for the same view resized, kept with a note otherwise); returns what
        became of K. A function of the size alone, so every window of a split run fits the
        same K to the same frames."""
        base = self._base
        if base is None or base.width <= 0 or base.height <= 0:
            return "no intrinsics" if base is None else "K kept (its image size is not known)"
        if abs(w - base.width) <= SAME_VIEW_PX and abs(h - base.height) <= SAME_VIEW_PX:
            fit, words = base, "K as calibrated"
        elif (w, h) in self._fits:
            fit, words = self._fits[(w, h)]
        else:
            cal = self._calibrations
            own = cal.calibration(w, h) if cal is not None else None
            if cal is not None and own is not None:
                made = f"{w}x{h} images" if cal.downscale == 1 else \
                    f"these images before --downscale {cal.downscale}"
                fit, words = own[0], (f"K from CameraInfo on {cal.topic} message {own[1]}, "
                                      f"made for {made}")
            else:
                notes: list[str] = []
                fit = fit_to_images(base, (w, h), notes)
                words = notes[0] if notes else "K as calibrated"
            self._fits[(w, h)] = fit, words
        self.intrinsics = fit
        self._K = np.asarray(fit.K, np.float64)
        return words

    # ------------------------------------------------------------------ entry point
    def process(self, frame: CameraFrame) -> dict[str, Any]:
        """One metrics row for ``frame``; never raises on a frame with nothing to match.

        A frame of another size than the reference keyframe's (the camera reconfigured: binning,
        another resolution, another crop; more than SAME_VIEW_PX a side) starts the frontend
        afresh, as a gap does: nothing is matched across the change, and K is fitted to the new
        size (status ``size_changed``).
        """
        timer = StageTimer(self._clock)
        row = _row_template()
        self._state = self._flow = None
        self.resized = None
        gray = frame.gray
        if _measurable(gray.shape):
            h, w = gray.shape
            # the frame matched against: the reference keyframe's (a frame too small to hold
            # a feature, a decoder's glitch, never becomes one of another size)
            ref = self._kf.view.gray.shape if self._kf is not None else None
            resized = ref is not None and _measurable(ref) and (
                abs(ref[0] - h) > SAME_VIEW_PX or abs(ref[1] - w) > SAME_VIEW_PX)
            if resized:
                self.reset()  # closes the open interval with the K of its own frames
            words = None
            if self._base is not None and (self.intrinsics is None or (
                    self.intrinsics.width, self.intrinsics.height) != (w, h)):
                words = self._fit_to_size(w, h)
            if resized and ref is not None:
                self.resized = f"{ref[1]}x{ref[0]} -> {w}x{h}: " + (
                    words or ("no intrinsics" if self._base is None else "K as before"))
        with timer("detect"):
            cur = self._detect(frame, row)
        prev, kf = self._prev, self._kf
        if prev is None or kf is None:
            row["status"] = SIZE_STATUS if self.resized is not None else "first_frame"
            reason = "first_frame"
        else:
            kf.frames += 1
            with timer("match"):
                q, t = self._match(cur, prev, kf, row)
            with timer("photometric"):
                self._photometric(cur, prev, q, t, row)
            self._two_interval_sel = None
            with timer("geometry"):
                lost = self._geometry(cur, kf, row)
            kf.row_frames.append(cur.index)
            # frontdiag's own readings, not stages of the frontend: timed apart, so the
            # stage times (and budget projections from them) stay the frontend's
            with timer("diagnostic"):
                if self._two_interval_sel is not None:
                    self._queue_two_intervals(cur, kf, self._two_interval_sel)
            if len(cur.feats) < 2:
                row["status"] = "no_features"
            reason = self._keyframe_reason(lost, kf, row)
        self.last_annotation = self._annotation(cur)
        self._remember(cur)
        if reason:
            self._close_interval(cur)
            # the new reference keeps its tracks into the old one, unless they were lost
            linked = kf is not None and reason != "lost"
            parent_idx = cur.kf_idx if linked else None
            cur.kf_idx = np.arange(len(cur.feats), dtype=np.intp)
            self._kf = _Keyframe(cur, parent=kf.view if linked and kf else None,
                                 parent_idx=parent_idx,
                                 parent_deg=kf.largest_parallax_deg() if linked and kf else NAN)
        row["keyframe_reason"] = reason
        self._prev = cur
        row.update(ms_detect=timer.ms.get("detect", 0.0), ms_match=timer.ms.get("match", 0.0),
                   ms_geometry=timer.ms.get("geometry", 0.0),
                   ms_photometric=timer.ms.get("photometric", 0.0),
                   ms_diagnostic=timer.ms.get("diagnostic", 0.0),
                   ms_total=timer.total() - timer.ms.get("diagnostic", 0.0))
        return row

