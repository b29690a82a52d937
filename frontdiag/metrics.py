"""Every per-frame column, declared once: name, unit, sensor, meaning, which way is better.

The rules engine validates rule files against this catalogue; the README's column table and
`frontdiag explain` read it too. Units live in the names (`_deg`, `_ms`, `_m`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

# The reference feature-count figures (1000 healthy, ~120 failed) are for 1280x720 with a
# 1000-feature budget. The corners a scene offers scale with the pixel area, so below that size
# the budget a frame can be expected to fill is prorated by area.
REFERENCE_AREA_PX = 1280 * 720
DEFAULT_FEATURE_BUDGET = 1000  # the reference ORB budget (CameraParams.n_features)


def keypoint_fill(n_keypoints: np.ndarray | float, width: np.ndarray | float,
                  height: np.ndarray | float, budget: float) -> np.ndarray:
    """n_keypoints / (budget x min(1, width*height / 1280x720)); an unknown size counts as
    the reference size."""
    area = np.asarray(width, dtype=float) * np.asarray(height, dtype=float)
    share = np.where(np.isfinite(area) & (area > 0), np.minimum(1.0, area / REFERENCE_AREA_PX),
                     1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.asarray(n_keypoints, dtype=float) / (budget * share)

Better = Literal["higher", "lower", "none"]


@dataclass(frozen=True)
class Metric:
    name: str
    unit: str
    sensor: Literal["camera", "lidar", "any"]
    meaning: str
    better: Better = "none"


_M = Metric
METRICS: dict[str, Metric] = {m.name: m for m in [
    _M("frame", "", "any", "index of the message on its topic (before --stride/--start selection)"),
    _M("t_ns", "ns", "any", "header stamp (log time when the stamp is zero)"),
    _M("t_rel_s", "s", "any", "seconds since the first message of the recording"),
    _M("sensor", "", "any", "camera or lidar"),
    _M("topic", "", "any", "topic the row was computed from"),
    _M("status", "", "any", "ok, or why the frame could not be evaluated"),
    _M("width", "px", "camera", "image width after decoding"),
    _M("height", "px", "camera", "image height after decoding"),
    # --- camera: detection
    _M("n_keypoints", "count", "camera", "ORB keypoints detected", "higher"),
    _M("entropy_norm", "ratio", "camera",
       "keypoint spatial entropy over an 8x6 grid divided by log2(48); >0.74 ok, <0.6 alarm", "higher"),
    _M("keypoint_fill", "x expected", "camera",
       "n_keypoints / expected count, the expected count being the feature budget x min(1, "
       "pixels / 1280x720): 1 means the frame holds as many keypoints as a frame of its size "
       "is expected to; it exceeds 1 when a frame smaller than 1280x720 fills more than its "
       "prorated share (up to 3 at 640x480); a starved frame (~120 of 1000) reads 0.12",
       "higher"),
    _M("entropy_inliers_norm", "ratio", "camera",
       "entropy_norm of the essential-matrix inliers in this frame: where the constraints on the "
       "pose come from (spread weak keypoints that never match do not constrain it); NaN under 30 "
       "inliers, where even a uniform spread reads below 0.6 by sampling alone", "higher"),
    _M("entropy_inliers_shared_norm", "ratio", "camera",
       "entropy_inliers_norm over the cells of the grid that the reference keyframe also saw "
       "(cell centres taken back through the pair's homography into its image), divided by "
       "log2 of their number: how the inliers spread over the part of the view they could come "
       "from. A panorama shot turned 40 deg through a 60 deg lens shares a third of its view, "
       "and its inliers, spread over that third, read 0.4 over the whole grid; NaN when under 8 "
       "cells are shared or the homography is singular", "higher"),
    _M("occupied_cells", "count", "camera", "cells of the 8x6 grid holding at least one keypoint", "higher"),
    _M("n_coarse_keypoints", "count", "camera",
       "keypoints at pyramid level >= 3 (scale >= 1.73) with a FAST score >= 20: texture at "
       "scale; sensor noise and paper grain make corners at the finest levels only (textured "
       "views: 100-300 of the 297 those levels are given)", "higher"),
    _M("coarse_hull_share", "ratio", "camera",
       "share of the image covered by the convex hull of the n_coarse_keypoints that have "
       "another within 54 px (strays left out): where the texture at scale is; NaN under 3"),
    _M("n_weak_keypoints", "count", "camera",
       "keypoints from the low-threshold FAST retry (t=7) in cells empty at t=20; many = low contrast"),
    # --- camera: matching (against the previous frame)
    _M("n_putative", "count", "camera", "query features with two candidate neighbours", "higher"),
    _M("ratio_reject_rate", "ratio", "camera",
       "share of query features whose best match failed the Lowe ratio test (0.8)", "lower"),
    _M("ratio_ambiguous_rate", "ratio", "camera",
       "share of query features refused by the ratio test although their second candidate is "
       "also a good match (within 50 of 256 bits): two plausible partners, the repetition share "
       "of ratio_reject_rate", "lower"),
    _M("match_dist_med", "bits", "camera",
       "median Hamming distance (of 256 bits) of the matches the ratio test accepted against the "
       "previous frame: how much the same corners changed between the two pictures (a wider "
       "baseline, blur or a coarser stream raise it); in_frame_twin_rate's copy line is this / "
       "0.8, capped at 50 bits / 0.8", "lower"),
    _M("in_frame_twin_rate", "ratio", "camera",
       "share of the frame's keypoints with a copy elsewhere in the same frame: another keypoint "
       "beyond half an ORB patch whose descriptor is within the frame's median accepted match "
       "distance / 0.8, so the ratio test refuses their matches; the scene repeating itself, "
       "read in one image (frame rate and motion do not raise it)", "lower"),
    _M("ratio_reject_base", "ratio", "camera",
       "the recording's own ratio_reject_rate: lower quartile of the rows within 5 s either side "
       "(row itself, rows near an exposure step, matched over > 1/3 s or at/above the 0.70 line "
       "left out); NaN where fewer than 10 rows or a quarter of the window remain "
       "(FD-REP-001 baseline_* params)"),
    _M("ratio_reject_base_window_s", "s", "camera",
       "the window ratio_reject_base was read over: 10 s, or wider where no level formed within "
       "10 s (doubling up to the whole recording, FD-REP-001 baseline_widen_max_s)"),
    _M("ratio_reject_base_sigma", "ratio", "camera",
       "robust spread of ratio_reject_base: (median - lower quartile) / 0.6745 of the same rows"),
    _M("n_keypoints_base", "count", "camera",
       "the recording's own n_keypoints: lower quartile of the rows within 5 s either side"),
    _M("n_matches", "count", "camera", "matches passing the ratio test and mutual consistency", "higher"),
    # --- camera: geometry (against the reference keyframe)
    _M("ref_frame", "", "camera", "frame index of the reference keyframe"),
    _M("n_ref_matches", "count", "camera", "correspondences with the reference keyframe", "higher"),
    _M("tracked_share", "ratio", "camera",
       "correspondences with the reference / those in the first frame after it; <0.9 -> new keyframe",
       "higher"),
    _M("keyframe_reason", "", "camera",
       "why this frame became the reference for the next ones (first_frame, lost, max_frames, "
       "tracked_share, parallax), empty if it did not"),
    _M("inliers_e", "count", "camera", "essential-matrix inliers (USAC_MAGSAC)", "higher"),
    _M("inliers_h", "count", "camera", "homography inliers on the same correspondences", "none"),
    _M("h_over_e", "ratio", "camera",
       "homography inliers / essential inliers; <0.5 general 3D, >0.9 degenerate", "lower"),
    _M("inlier_ratio", "ratio", "camera", "RANSAC inlier ratio w = inliers_e / correspondences", "higher"),
    _M("ransac_iters_required", "count", "camera", "N = ln(1-p)/ln(1-w^5) at the measured w", "lower"),
    _M("ransac_iters_run", "count", "camera", "iterations the estimator actually ran", "none"),
    _M("parallax_med_deg", "deg", "camera",
       "median parallax angle of inlier correspondences after de-rotation; 1 deg triangulation gate",
       "higher"),
    _M("parallax_med_px", "px", "camera",
       "parallax_med_deg as an image displacement, fx * tan(angle): H/E can tell a plane from 3D "
       "structure only when this is well above the 2.45 px homography threshold", "higher"),
    _M("rot_deg", "deg", "camera", "rotation angle recovered against the reference keyframe"),
    _M("rot_only_px", "px", "camera",
       "median transfer error of the best rotation-only model x' ~ K R K^-1 x over the essential "
       "inliers, the focal allowed 0.5-2x the given one: near the localisation noise when the "
       "camera only turned (or stood still), whatever the accuracy of K; read only where H/E "
       "is above 0.9 with parallax >= 0.3 deg (on the frame or its interval), the only "
       "readings it can change", "none"),
    _M("epi_residual_px", "px", "camera",
       "median Sampson distance of the essential inliers to E's epipolar geometry: the "
       "localisation noise E leaves (0.674 sigma for a correct E); a rotation alone leaves "
       "rot_only_px near 2.47x it, a translation more"),
    _M("rot_focal_scale", "ratio", "camera",
       "focal length, as a multiple of the given one, at which rot_only_px is smallest"),
    _M("ref2_frame", "", "camera",
       "the keyframe before the reference, read when parallax_med_px is under twice the "
       "homography threshold (4.9 px); -1 when not read"),
    _M("h_over_e_2kf", "ratio", "camera",
       "h_over_e against ref2_frame, over the tracks alive across both keyframe intervals",
       "lower"),
    _M("parallax_med_deg_2kf", "deg", "camera", "parallax_med_deg against ref2_frame", "higher"),
    _M("parallax_med_px_2kf", "px", "camera", "parallax_med_px against ref2_frame", "higher"),
    _M("span_frame", "", "camera",
       "the frame the motion over at least rot_span_s (0.33 s; longer in proportion below a "
       "495 px focal length, rot_span_focal_px) was read against, where the keyframe interval "
       "was shorter and could read as rotation or standing still; -1 when not read"),
    _M("span_dt_s", "s", "camera", "time between span_frame and the interval's last frame"),
    _M("rot_only_px_span", "px", "camera",
       "rot_only_px over the span (the interval's last frame against span_frame): over a "
       "third of a second a translating camera's parallax outgrows the noise that a short "
       "keyframe interval leaves it in", "none"),
    _M("epi_residual_px_span", "px", "camera", "epi_residual_px over the span"),
    _M("parallax_med_deg_span", "deg", "camera", "parallax_med_deg over the span", "higher"),
    _M("t_dir_change_deg", "deg", "camera",
       "change of the recovered translation direction since the previous frame (same reference)"),
    _M("pose_info_cond", "ratio", "camera",
       "lambda_max/lambda_min of the pose information matrix J^T J; 20-80 healthy, >3000 clustered",
       "lower"),
    # --- camera: photometric
    _M("mean_intensity", "grey level", "camera", "frame mean intensity (0-255)"),
    _M("lit_share", "ratio", "camera",
       "share of the pixels brighter than the FAST threshold (20 grey levels): where no pixel "
       "exceeds it no corner can fire at it; under 0.01 the view is black but for a few lights",
       "higher"),
    _M("d_mean_intensity", "grey level", "camera",
       "change of frame mean intensity from the previous frame; >8 is an exposure step"),
    _M("photo_residual_med", "grey level", "camera",
       "median |I2 - I1| over 8x8 patches at tracked features; ~4 healthy, 20-25 at a gain step",
       "lower"),
    _M("photo_residual_base", "grey level", "camera",
       "the recording's own photo_residual_med: lower quartile of the rows within 5 s either side "
       "outside exposure steps and their recovery (row itself left out); NaN where fewer than 10 "
       "rows or a quarter of the window remain (FD-EXP-001 baseline_* params)"),
    _M("photo_residual_base_sigma", "grey level", "camera",
       "robust spread of photo_residual_base: (median - lower quartile) / 0.6745 of the same rows"),
    _M("affine_gain", "ratio", "camera", "gain a of r = I2 - (a*I1 + b) fitted at tracked features"),
    _M("affine_bias", "grey level", "camera", "offset b of the affine brightness model"),
    _M("photo_residual_affine_med", "grey level", "camera",
       "median residual after removing the affine brightness model", "lower"),
    _M("brightness_ratio", "ratio", "camera",
       "median over tracked features of mean(8x8 patch now) / mean(patch in the previous frame): "
       "how much brighter the same surfaces are; 1.0 unchanged, 1.2 a 20% gain step"),
    _M("brightness_ratio_se", "log ratio", "camera",
       "standard error of log(brightness_ratio): sqrt(pi/2) x 1.4826 MAD of the patches' log "
       "ratios / sqrt(patches); 0.01 means the ratio is known to about 1%", "lower"),
    # --- timing
    _M("ms_decode", "ms", "any", "decode + grey conversion", "lower"),
    _M("ms_detect", "ms", "camera", "ORB detection + description with bucketing", "lower"),
    _M("ms_match", "ms", "camera", "Hamming kNN matching, ratio test, mutual check", "lower"),
    _M("ms_geometry", "ms", "camera", "E and H estimation, recoverPose, parallax, pose information",
       "lower"),
    _M("ms_photometric", "ms", "camera", "photometric residual and affine fit", "lower"),
    _M("ms_diagnostic", "ms", "camera",
       "frontdiag's own extra readings (H/E over two keyframe intervals, the rotation-only fit), "
       "not frontend stages; "
       "left out of ms_total", "lower"),
    _M("ms_total", "ms", "any", "all stages of this frame (ms_diagnostic excluded)", "lower"),
    # --- lidar
    _M("n_points", "count", "lidar", "finite points in the scan", "higher"),
    _M("n_points_used", "count", "lidar", "points after voxel downsampling used in registration",
       "higher"),
    _M("deskew_m", "m", "lidar",
       "how far the scene moves in the sensor frame over one sweep under the motion prior (the "
       "largest correction deskewing makes between first and last point); 1.5 m/s over 100 ms "
       "is 0.15; empty when the points carry no time or no motion is known yet"),
    _M("icp_fitness", "ratio", "lidar", "share of points with a correspondence inside the threshold",
       "higher"),
    _M("icp_rmse_m", "m", "lidar",
       "RMS point-to-plane distance of inlier correspondences on well-defined map planes",
       "lower"),
    _M("icp_iters", "count", "lidar", "registration iterations", "lower"),
    _M("lidar_eig_min", "points of 20k", "lidar",
       "smallest eigenvalue of the point-to-plane J^T J at the solution, rotation as arc length "
       "at the RMS range, scaled to a 20,000-point scan: the number of points out of 20,000 "
       "that would see the weakest direction squarely; ~2400 healthy, ~12 degenerate (see "
       "docs/lidar.md)", "higher"),
    _M("lidar_cond", "ratio", "lidar",
       "lambda_max/lambda_min of the same J^T J; ~35 healthy, >900 degenerate", "lower"),
    _M("lidar_weak_dir", "", "lidar",
       "the weakest eigenvector in words, sensor frame (x forward, y left, z up)"),
    _M("lidar_weak_axis", "", "lidar",
       "the axis carrying most of the weakest eigenvector: x, y, z (translation) or roll, pitch, "
       "yaw; one of six values, to count over a run"),
    _M("lidar_weak_vec", "unit vector", "lidar",
       "the weakest eigenvector itself, (roll, pitch, yaw, x, y, z), rotation as arc length at "
       "the RMS range; zeros for the axes a 2D scan does not observe"),
    _M("ms_lidar_preprocess", "ms", "lidar", "range filter + deskew + voxel downsampling",
       "lower"),
    _M("ms_lidar_register", "ms", "lidar", "registration + correspondences + spectrum", "lower"),
    _M("ms_lidar_map", "ms", "lidar",
       "local map upkeep: rebuild (voxel grid, normals, KD-tree) when a keyframe is added",
       "lower"),
    _M("icp_max_corr_m", "m", "lidar",
       "adaptive correspondence threshold used: 3 x RMS prediction error of past scans "
       "(KISS-ICP), never below one voxel; 2.0 before any motion"),
    _M("lidar_prior", "", "lidar",
       "motion prior of the scan: odometry, constant_velocity or none"),
    # --- verdicts (added by the rules engine)
    _M("conditions", "", "any", "condition names that fired on this row"),
    _M("rules", "", "any", "rule IDs that fired on this row"),
    _M("verdict", "", "any", "ok / warn / fail"),
]}

CAMERA_COLUMNS: tuple[str, ...] = (
    "frame", "t_ns", "sensor", "topic", "n_keypoints", "entropy_norm", "n_putative",
    "ratio_reject_rate", "n_matches", "inliers_e", "inliers_h", "h_over_e", "inlier_ratio",
    "ransac_iters_required", "ransac_iters_run", "parallax_med_deg", "rot_deg", "pose_info_cond",
    "mean_intensity", "d_mean_intensity", "photo_residual_med", "affine_gain", "ms_decode",
    "ms_detect", "ms_match", "ms_geometry", "ms_total", "status",
)
"""Columns every camera row carries (the contract of the analyze table)."""

LIDAR_COLUMNS: tuple[str, ...] = (
    "frame", "t_ns", "sensor", "topic", "n_points", "n_points_used", "deskew_m", "icp_fitness",
    "icp_rmse_m", "icp_iters", "lidar_eig_min", "lidar_cond", "lidar_weak_dir",
    "ms_lidar_preprocess", "ms_lidar_register", "ms_total", "status",
)
