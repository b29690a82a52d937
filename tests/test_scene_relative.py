"""Scene-relative readings, rotation without trusting K, steps into darkness, planar gating."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from test_verdicts_support import frames

from frontdiag.camera.geometry import homography_threshold_px, rotation_only_fit, two_view
from frontdiag.verdicts import evaluate, load_ruleset
from frontdiag.verdicts.baseline import rolling_baseline
from frontdiag.verdicts.explain import explain_row


@pytest.fixture(scope="module")
def ruleset():
    return load_ruleset()


def hits(result, condition: str) -> np.ndarray:
    return result.table["conditions"].map(lambda c: condition in c).to_numpy()


def _noisy(n: int, centre: float, spread: float, seed: int) -> np.ndarray:
    return centre + np.random.default_rng(seed).uniform(-spread, spread, n)


# --- the baseline itself --------------------------------------------------------------------

def test_rolling_baseline_leaves_out_the_row_excluded_rows_and_thin_windows() -> None:
    t = np.arange(100, dtype=float)  # 1 s apart
    x = np.full(100, 0.3)
    x[40:50] = 0.9
    med, sig = rolling_baseline(t, x, window_s=30, min_rows=10, min_share=0.25,
                                exclude=x >= 0.7)
    assert med[45] == pytest.approx(0.3) and sig[45] == pytest.approx(0.0)
    # the first rows borrow their level from the rows after them (centred window)
    assert med[0] == pytest.approx(0.3)
    # too few rows within the window: no baseline
    med, _ = rolling_baseline(t, x, window_s=6, min_rows=10, min_share=0.25)
    assert np.isnan(med).all()
    # a window that is mostly excluded rows has no level of its own
    y = np.full(100, 0.9)
    y[::10] = 0.3
    med, _ = rolling_baseline(t, y, window_s=30, min_rows=2, min_share=0.25, exclude=y >= 0.7)
    assert np.isnan(med).all()


# --- repetition against the scene's own rejection --------------------------------------------

def _jump(copies: float) -> dict[int, dict[str, float]]:
    """A scene at 0.30 rejection jumping to 0.62 for 50 frames, those frames with ``copies``
    of their features repeated within the view."""
    rej = _noisy(300, 0.30, 0.03, seed=1)
    rej[150:200] = _noisy(50, 0.62, 0.02, seed=2)
    change = {i: {"ratio_reject_rate": float(r)} for i, r in enumerate(rej)}
    for i in range(150, 200):
        change[i]["in_frame_twin_rate"] = copies
    return change


def test_a_rejection_jump_above_the_scene_at_unchanged_features_is_repetition(ruleset) -> None:
    """0.30 -> 0.62: under the absolute 0.70 line, but twice the scene's own level with the
    feature count unchanged."""
    res = evaluate(frames(300, _jump(copies=0.25)), ruleset)
    rep = hits(res, "repetitive_structure")
    assert rep[152:198].all() and not rep[:145].any() and not rep[205:].any()
    assert res.table["ratio_reject_base"].iloc[170] == pytest.approx(0.30, abs=0.02)
    lines = next(e for e in explain_row(res, 170) if e.rule.id == "FD-REP-001").check_lines
    assert any(ln.startswith("in_frame_twin_rate 25% >= 5%: the scene repeats itself")
               for ln in lines)
    assert any("scene baseline" in ln and "repetition signature" in ln for ln in lines)
    assert any(ln.startswith("absolute:") for ln in lines)


def test_a_rejection_jump_without_copies_in_the_view_is_not_repetition(ruleset) -> None:
    """The same jump, but the frames show no copies of their own features (a faster motion,
    a coarser stream): the ratio test refused features that nothing resembles."""
    change = _jump(copies=0.04)
    for row in change.values():
        row["match_dist_med"] = 35.0
    res = evaluate(frames(300, change), ruleset)
    assert not hits(res, "repetitive_structure").any()
    lines = next(e for e in explain_row(res, 170) if e.rule.id == "FD-REP-001").check_lines
    assert any("repetition signature" in ln for ln in lines)
    assert any(ln.startswith("in_frame_twin_rate 4% < 5%") and "ruled out" in ln
               and "accepted matches lie a median 35 bits" in ln for ln in lines)


def test_a_long_wide_baseline_stretch_is_not_one_long_aisle(ruleset) -> None:
    """A drive read every second frame (5 Hz): rejection 0.75-0.85 on every frame, no level of
    its own below the absolute line, few copies in the view (0.00-0.05). The simulator's aisle
    at 320x240 rejects as much with 0.06-0.11 of its features repeated in the view."""
    rej = _noisy(150, 0.80, 0.05, seed=7)
    twins = _noisy(150, 0.025, 0.025, seed=8)
    drive = evaluate(frames(150, {i: {"ratio_reject_rate": float(r),
                                      "in_frame_twin_rate": float(c)}
                                  for i, (r, c) in enumerate(zip(rej, twins, strict=True))},
                            rate_hz=5), ruleset)
    assert np.isnan(drive.table["ratio_reject_base"]).all()
    assert not hits(drive, "repetitive_structure").any()
    aisle = evaluate(frames(150, {i: {"ratio_reject_rate": float(r),
                                      "in_frame_twin_rate": float(c) + 0.06}
                                  for i, (r, c) in enumerate(zip(rej, twins, strict=True))},
                            rate_hz=5), ruleset)
    assert hits(aisle, "repetitive_structure")[5:].all()


def test_a_table_without_the_copies_column_is_read_as_before(ruleset) -> None:
    """A table written before in_frame_twin_rate existed: the rule reads the rejection alone."""
    t = frames(120, {range(120): {"ratio_reject_rate": 0.82}}).drop(columns="in_frame_twin_rate")
    assert hits(evaluate(t, ruleset), "repetitive_structure")[5:].all()


def test_a_scene_that_always_rejects_much_is_not_repetition(ruleset) -> None:
    """A street at 10 Hz: rejection 0.60-0.78 on every frame, crossing the absolute line on
    about a third of them, and never far above the scene's own level."""
    rej = _noisy(200, 0.69, 0.09, seed=3)
    assert (rej >= 0.70).mean() > 0.3
    res = evaluate(frames(200, {i: {"ratio_reject_rate": float(r)} for i, r in enumerate(rej)},
                          rate_hz=10), ruleset)
    assert not hits(res, "repetitive_structure").any()


def test_a_rejection_jump_with_features_lost_is_not_repetition(ruleset) -> None:
    rej = _noisy(300, 0.30, 0.03, seed=4)
    change = {i: {"ratio_reject_rate": float(r)} for i, r in enumerate(rej)}
    for i in range(150, 200):
        change[i] = {"ratio_reject_rate": 0.65, "n_keypoints": 500, "keypoint_fill": 0.5}
    res = evaluate(frames(300, change), ruleset)
    assert not hits(res, "repetitive_structure").any()


def test_a_recording_that_is_one_long_aisle_reads_the_absolute_line(ruleset) -> None:
    res = evaluate(frames(120, {range(120): {"ratio_reject_rate": 0.82,
                                                  "in_frame_twin_rate": 0.3}}), ruleset)
    assert np.isnan(res.table["ratio_reject_base"]).all()
    assert hits(res, "repetitive_structure")[5:].all()


# --- exposure against the scene's own residual ------------------------------------------------

def _residual_run(level: float, step: float) -> dict[int, dict[str, float]]:
    res = _noisy(200, level, 0.1 * level, seed=5)
    change = {i: {"photo_residual_med": float(r)} for i, r in enumerate(res)}
    change[100] = {"photo_residual_med": step, "d_mean_intensity": 12.0}
    return change


def test_a_residual_far_above_the_scene_is_the_exposure_signature(ruleset) -> None:
    """A quiet scene (residual 2) steps to 6: under the absolute 8, three times its own level."""
    res = evaluate(frames(200, _residual_run(2.0, 6.0)), ruleset)
    exp = hits(res, "exposure_step")
    assert exp[100] and exp.sum() == 1
    lines = next(e for e in explain_row(res, 100) if e.rule.id == "FD-EXP-001").check_lines
    assert any("relative (decides the residual reading)" in ln and "exposure signature" in ln
               for ln in lines)


def test_a_residual_at_the_scene_level_is_not_a_step(ruleset) -> None:
    """A busy scene (residual 12) whose mean moves by 12: the residual 14 is its own level,
    although it is above the absolute 8."""
    res = evaluate(frames(200, _residual_run(12.0, 14.0)), ruleset)
    assert not hits(res, "exposure_step").any()


# --- steps into darkness ----------------------------------------------------------------------

def test_lights_out_and_back_are_exposure_steps_though_detection_fails_after(ruleset) -> None:
    dark = {"n_keypoints": 40, "keypoint_fill": 0.04, "ratio_reject_rate": np.nan,
            "photo_residual_med": np.nan, "d_mean_intensity": 0.1, "mean_intensity": 3.0,
            "h_over_e": np.nan, "parallax_med_deg": np.nan}
    change: dict[int | range, dict[str, float]] = {range(60, 90): dark}
    change[60] = {**dark, "d_mean_intensity": -110.0}
    change[90] = {"d_mean_intensity": 112.0, "ratio_reject_rate": np.nan,
                  "photo_residual_med": np.nan}
    res = evaluate(frames(150, change), ruleset)
    exp = hits(res, "exposure_step")
    assert exp[60] and exp[90] and exp.sum() == 2
    assert hits(res, "detection_failure")[61:90].all()
    lines = next(e for e in explain_row(res, 60) if e.rule.id == "FD-EXP-001").check_lines
    assert any("into darkness" in ln for ln in lines)


def test_a_bright_scene_cut_is_not_a_darkness_step(ruleset) -> None:
    """The mean jumps as far, but features are found on both sides: not a step into darkness."""
    res = evaluate(frames(100, {50: {"d_mean_intensity": -90.0, "ratio_reject_rate": 0.99,
                                     "photo_residual_med": 60.0}}), ruleset)
    assert not hits(res, "exposure_step").any()


# --- the same surfaces brighter: photographs far apart ------------------------------------------

def test_brightness_ratio_reads_the_gain_where_patches_do_not_align() -> None:
    """A 25 % gain between two views 3 px apart: the pixel residual is large (misalignment), the
    ratio of patch means still reads the gain; without a gain it reads 1."""
    from frontdiag.camera.photometric import photometric

    rng = np.random.default_rng(4)
    img = cv2.GaussianBlur(rng.uniform(40, 160, (240, 320)).astype(np.float32), (0, 0), 3)
    xy = np.column_stack([rng.uniform(20, 300, 200), rng.uniform(20, 220, 200)])
    shifted = xy + 3.0  # the matched keypoints sit 3 px off the same surface point
    same = photometric(img.astype(np.uint8), img.astype(np.uint8), xy, shifted)
    brighter = photometric(img.astype(np.uint8), np.clip(img * 1.25, 0, 255).astype(np.uint8),
                           xy, shifted)
    assert same.brightness_ratio == pytest.approx(1.0, abs=0.02)
    assert brighter.brightness_ratio == pytest.approx(1.25, abs=0.03)
    assert brighter.residual_med > 8  # the residual alone cannot tell it from misalignment
    few = photometric(img.astype(np.uint8), img.astype(np.uint8), xy[:10], shifted[:10])
    assert np.isnan(few.brightness_ratio)  # a median of ten patch ratios is not read


def test_a_brightness_ratio_step_between_photographs_is_an_exposure_step(ruleset) -> None:
    """1 Hz photographs: no residual baseline, no clean frames around the step, the frame mean
    barely moves; the same surfaces 18 % darker with most matches verified is a step, the same
    ratio with most matches wrong (a chequerboard) or a 4 % change is not."""
    base = {"photo_residual_med": 18.0, "ratio_reject_rate": 0.8, "d_mean_intensity": -3.0,
            "inlier_ratio": 0.8, "brightness_ratio": 1.0}
    change = {i: dict(base) for i in range(1, 6)}
    change[2] = {**base, "brightness_ratio": 0.82}
    change[3] = {**base, "brightness_ratio": 1.34}
    change[4] = {**base, "brightness_ratio": 0.82, "inlier_ratio": 0.3}
    change[5] = {**base, "brightness_ratio": 1.04}
    res = evaluate(frames(6, change, rate_hz=1.0), ruleset)
    exp = hits(res, "exposure_step")
    assert exp.tolist() == [False, False, True, True, False, False]
    lines = next(e for e in explain_row(res, 4) if e.rule.id == "FD-EXP-001").check_lines
    assert any("not trusted" in ln for ln in lines)
    assert any(ln.endswith("not an exposure step") for ln in lines)
    # where the ratio calls the step, the residual reading's look-alikes (matching collapsed at
    # 80 % rejection) say why that reading alone would not, not that there is no step
    lines = next(e for e in explain_row(res, 2) if e.rule.id == "FD-EXP-001").check_lines
    assert any("the brightness ratio above decides" in ln for ln in lines)
    assert not any("not an exposure step" in ln or "not an auto-exposure step" in ln
                   for ln in lines)


def test_the_brightness_ratio_carries_the_standard_error_of_its_median() -> None:
    """A uniform gain scales every patch alike: the log ratios barely scatter and the median is
    known to a fraction of a percent. Surfaces that change brightness each their own way (a
    glossy surface seen from elsewhere) scatter: the error grows with the scatter and falls as
    one over the square root of the patches."""
    from frontdiag.camera.photometric import photometric

    rng = np.random.default_rng(5)
    img = cv2.GaussianBlur(rng.uniform(40, 160, (240, 320)).astype(np.float32), (0, 0), 3)
    xy = np.column_stack([rng.uniform(20, 300, 200), rng.uniform(20, 220, 200)])
    gain = photometric(img.astype(np.uint8), np.clip(img * 1.2, 0, 255).astype(np.uint8),
                       xy, xy)
    assert gain.brightness_ratio == pytest.approx(1.2, abs=0.02)
    assert gain.brightness_ratio_se < 0.005
    # every 24x24 block its own brightness change, log-normal with sigma 0.15 around 0.93
    blocks = np.exp(rng.normal(np.log(0.93), 0.15, (10, 14)))
    field = cv2.resize(blocks, (320, 240), interpolation=cv2.INTER_NEAREST).astype(np.float32)
    uneven = np.clip(img * field, 0, 255).astype(np.uint8)
    many = photometric(img.astype(np.uint8), uneven, xy, xy)
    few = photometric(img.astype(np.uint8), uneven, xy[:50], xy[:50])
    assert 0.005 < many.brightness_ratio_se < few.brightness_ratio_se
    # sqrt(pi/2) x sigma / sqrt(n): about 0.013 for 200 patches at sigma 0.15
    assert many.brightness_ratio_se == pytest.approx(1.2533 * 0.15 / np.sqrt(200), rel=0.35)


def test_a_ratio_past_the_line_by_less_than_its_own_scatter_is_not_a_step(ruleset) -> None:
    """6.7 % darker from patches scattered by a standard error of 1.2 % (a glossy print seen
    from elsewhere) does not clear the 6.7 % line by two errors; the same ratio known to 0.2 %
    does, and so does an 18 % step with the same scatter."""
    base = {"photo_residual_med": 18.0, "ratio_reject_rate": 0.8, "d_mean_intensity": -3.0,
            "inlier_ratio": 0.9, "brightness_ratio": 1.0, "brightness_ratio_se": 0.01}
    change = {i: dict(base) for i in range(1, 6)}
    change[2] = {**base, "brightness_ratio": 0.93, "brightness_ratio_se": 0.012}
    change[3] = {**base, "brightness_ratio": 0.93, "brightness_ratio_se": 0.002}
    change[4] = {**base, "brightness_ratio": 0.82, "brightness_ratio_se": 0.012}
    res = evaluate(frames(6, change, rate_hz=1.0), ruleset)
    assert hits(res, "exposure_step").tolist() == [False, False, False, True, True, False]
    lines = next(e for e in explain_row(res, 2) if e.rule.id == "FD-EXP-001").check_lines
    assert any("uncertain to 1.2%" in ln for ln in lines)


# --- rotation without trusting K ----------------------------------------------------------------

def _scene(n: int, seed: int, depth: tuple[float, float] = (2.0, 8.0)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    z = rng.uniform(*depth, n)
    x = rng.uniform(-0.6, 0.6, n) * z
    y = rng.uniform(-0.4, 0.4, n) * z
    return np.column_stack([x, y, z])


def _project(P: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray,
             noise: float, seed: int) -> np.ndarray:
    q = (P @ R.T + t) @ K.T
    xy = q[:, :2] / q[:, 2:3]
    return xy + np.random.default_rng(seed).normal(0, noise, xy.shape)


K_TRUE = np.array([[700.0, 0, 640], [0, 700.0, 360], [0, 0, 1]])


@pytest.mark.parametrize("focal_error", [0.85, 1.0, 1.18])
def test_a_wide_pan_reads_as_rotation_with_an_approximate_focal(focal_error: float) -> None:
    P = _scene(400, seed=6)
    R = cv2.Rodrigues(np.array([0.02, np.radians(25.0), 0.01]))[0]
    p0 = _project(P, K_TRUE, np.eye(3), np.zeros(3), 0.7, seed=7)
    p1 = _project(P, K_TRUE, R, np.zeros(3), 0.7, seed=8)
    keep = (p1[:, 0] > 0) & (p1[:, 0] < 1280) & (p1[:, 1] > 0) & (p1[:, 1] < 720)
    K = K_TRUE.copy()
    K[0, 0] *= focal_error
    K[1, 1] *= focal_error
    resid, scale = rotation_only_fit(p0[keep], p1[keep], K)
    assert resid <= homography_threshold_px(1.0)
    assert scale * focal_error == pytest.approx(1.0, abs=0.08)
    if focal_error != 1.0:  # the de-rotated angle with the wrong K reads as parallax
        tv = two_view(p0[keep], p1[keep], K)
        assert tv.parallax_med_deg > 0.3


def test_a_translating_3d_scene_does_not_read_as_rotation() -> None:
    P = _scene(400, seed=9)
    R = cv2.Rodrigues(np.array([0.0, np.radians(3.0), 0.0]))[0]
    p0 = _project(P, K_TRUE, np.eye(3), np.zeros(3), 0.7, seed=10)
    p1 = _project(P, K_TRUE, R, np.array([-0.3, 0.0, 0.1]), 0.7, seed=11)
    resid, _ = rotation_only_fit(p0, p1, K_TRUE * np.array([[1.1], [1.1], [1]]))
    assert resid > 3 * homography_threshold_px(1.0)


@pytest.mark.parametrize("n", [150, 400])
def test_the_rotation_fit_residual_is_over_every_correspondence(n: int) -> None:
    # the focal is searched on at most ROT_SEARCH_POINTS of them; the residual reported is over
    # all of them, also when the search already used all of them (then it is not recomputed)
    from frontdiag.camera.geometry import _rotation_residuals_px

    P = _scene(n, seed=12)
    R = cv2.Rodrigues(np.array([0.0, np.radians(4.0), 0.0]))[0]
    p0 = _project(P, K_TRUE, np.eye(3), np.zeros(3), 0.7, seed=13)
    p1 = _project(P, K_TRUE, R, np.array([-0.2, 0.0, 0.05]), 0.7, seed=14)
    resid, scale = rotation_only_fit(p0, p1, K_TRUE)
    assert resid == float(_rotation_residuals_px(p0, p1, K_TRUE, np.array([scale]))[0])


def test_h_over_e_high_with_a_rotation_fit_reads_rotation_not_planar(ruleset) -> None:
    """An approximate K leaves 2 deg of apparent parallax after a pan: the angle alone would say
    planar; the rotation-only fit says the views differ by a rotation only."""
    pan = {"h_over_e": 0.95, "parallax_med_deg": 2.0, "parallax_med_px": 25.0, "rot_deg": 25.0}
    res = evaluate(frames(40, {range(10, 30): {**pan, "rot_only_px": 1.1}}), ruleset)
    assert hits(res, "pure_rotation")[12:28].all() and not hits(res, "planar_degeneracy").any()
    res = evaluate(frames(40, {range(10, 30): {**pan, "rot_only_px": 14.0}}), ruleset)
    assert hits(res, "planar_degeneracy")[12:28].all() and not hits(res, "pure_rotation").any()


def _turn_with_baseline(baseline_m: float, noise: float) -> tuple[float, float]:
    """A 6 deg turn through the test scene (2-8 m deep) with a sideways baseline: the
    rotation-only residual (px) and E's median Sampson residual (px) over E's inliers."""
    P = _scene(400, seed=21)
    R = cv2.Rodrigues(np.array([0.01, np.radians(6.0), 0.0]))[0]
    p0 = _project(P, K_TRUE, np.eye(3), np.zeros(3), noise, seed=22)
    p1 = _project(P, K_TRUE, R, np.array([-baseline_m, 0.0, 0.0]), noise, seed=23)
    tv = two_view(p0, p1, K_TRUE)
    assert tv.inlier_mask is not None
    resid, _ = rotation_only_fit(p0[tv.inlier_mask], p1[tv.inlier_mask], K_TRUE)
    return resid, tv.epi_residual_px


def test_e_leaves_the_localisation_noise_and_a_rotation_two_and_a_half_times_it() -> None:
    """With noise sigma in each coordinate of both images a correct E's Sampson residual is
    |N(0, sigma^2)| (median 0.674 sigma) and a rotation that is the whole motion leaves a 2-D
    transfer error of median 1.665 sigma: 2.47 times E's, the noise-only ratio FD-ROT-001's
    rot_fit_noise_ratio is read against."""
    resid, epi = _turn_with_baseline(0.0, 0.7)
    assert epi == pytest.approx(0.674 * 0.7, rel=0.1)
    assert resid == pytest.approx(1.665 * 0.7, rel=0.1)
    assert resid / epi == pytest.approx(2.47, rel=0.1)


def test_a_turn_with_a_measurable_baseline_is_told_from_a_turn_by_es_residual() -> None:
    """3 cm of baseline in a 6 deg turn: the rotation still fits within the 2.45 px line, but at
    over 4 times E's residual; the turn alone stays near 2.5 times it."""
    resid, epi = _turn_with_baseline(0.03, 0.7)
    assert resid <= homography_threshold_px(1.0)
    assert resid / epi > 4.0
    resid0, epi0 = _turn_with_baseline(0.0, 0.7)
    assert resid0 / epi0 < 3.0


@pytest.mark.parametrize(("epi", "want"), [
    (np.nan, ["pure_rotation"]),   # no E residual (an older table): the pixel line decides
    (0.6, ["pure_rotation"]),      # 1.5 px is 2.5x E's 0.6 px: the noise a rotation leaves
    (0.3, []),                     # 5x E's 0.3 px: a translation E absorbs and no rotation does
])
def test_a_rotation_fit_counts_only_within_a_multiple_of_es_own_residual(ruleset, epi,
                                                                         want) -> None:
    """A hand-held 30 Hz walk turns 2-10 deg per keyframe interval while moving: its rotation
    fits within 2.45 px (1.5-2.4 px) at 3-6 times E's residual of 0.3-0.6 px. The pixel line
    assumes 1 px of noise; E's residual measures the noise these correspondences have."""
    row = {"h_over_e": 0.7, "parallax_med_deg": 6.0, "parallax_med_px": 50.0, "rot_deg": 20.0,
           "rot_only_px": 1.5, "epi_residual_px": epi}
    res = evaluate(frames(20, {range(5, 15): row}), ruleset)
    assert hits(res, "pure_rotation")[10] == bool(want)
    lines = next(e for e in explain_row(res, 10) if e.rule.id == "FD-ROT-001").check_lines
    rel = [ln for ln in lines if "E's own residual" in ln]
    assert len(rel) == (0 if np.isnan(epi) else 1)
    if rel:
        assert f"{1.5 / epi:.2g}x" in rel[0]
        assert ("beyond what the localisation noise explains" in rel[0]) == (not want)


@pytest.mark.parametrize(("parallax_deg", "parallax_px", "rot_deg", "want"), [
    (0.01, 0.1, 0.01, ["pure_rotation"]),  # still: read on the motion, whatever the spread
    (0.2, 2.0, 2.0, []),                   # a turn read by H/E: not on clustered inliers
])
def test_standing_still_is_read_on_clustered_features_and_h_over_e_is_not(
        ruleset, parallax_deg, parallax_px, rot_deg, want) -> None:
    """A tripod shooting a street at night keeps only its lamps: 104-181 inliers whose spread
    reads 0.51-0.58, under the 0.6 line below which any scene fits a homography. That line
    guards H/E; standing still is decided on the motion alone, and a view that did not move
    has no baseline however its features lie."""
    row = {"h_over_e": 0.97, "parallax_med_deg": parallax_deg, "parallax_med_px": parallax_px,
           "rot_deg": rot_deg, "entropy_inliers_norm": 0.55}
    res = evaluate(frames(20, {range(5, 15): row}), ruleset)
    assert hits(res, "pure_rotation")[10] == bool(want)
    assert not hits(res, "planar_degeneracy").any()
    lines = next(e for e in explain_row(res, 10) if e.rule.id == "FD-ROT-001").check_lines
    assert any(ln.startswith("not read: entropy") for ln in lines) != bool(want)
    assert any("standing still is read on the motion alone" in ln for ln in lines) == bool(want)


@pytest.mark.parametrize(("span_px", "span_epi", "want"), [
    (np.nan, np.nan, True),   # no span reading (an interval of 0.33 s or more): as before
    (0.65, 0.25, True),       # a pan over 0.33 s: 2.6x E's residual, as a rotation leaves
    (0.10, 0.02, True),       # standing still: E fits sub-pixel jitter, the ratio means nothing
    (3.1, 0.25, False),       # a slow walk: 3.1 px, 12x E's residual over 0.33 s
    (3.1, 0.90, True),        # 3.1 px, but only 3.4x a residual that large: noise, not motion
])
def test_a_short_interval_is_not_rotation_when_the_camera_translated_over_its_span(
        ruleset, span_px, span_epi, want) -> None:
    """A hand-held camera at 30 Hz makes keyframes 1-4 frames apart; a walk over so short an
    interval reads like a turn (H/E 0.95, parallax 0.1 deg). Over 0.33 s the rotation-only
    model shows the translation: beyond the homography threshold and 4x E's residual."""
    row = {"h_over_e": 0.95, "parallax_med_deg": 0.1, "parallax_med_px": 1.0, "rot_deg": 2.0,
           "span_frame": 0, "span_dt_s": 0.34, "rot_only_px_span": span_px,
           "epi_residual_px_span": span_epi}
    res = evaluate(frames(20, {range(5, 15): row}), ruleset)
    assert hits(res, "pure_rotation")[10] == want
    assert not hits(res, "planar_degeneracy").any()
    lines = next(e for e in explain_row(res, 10) if e.rule.id == "FD-ROT-001").check_lines
    span = [ln for ln in lines if ln.startswith("over 0.34 s")]
    assert len(span) == (0 if np.isnan(span_px) else 1)
    if span:
        assert ("the camera translated" in span[0]) == (not want)
        assert f"{span_px:.2g} px" in span[0]
    assert any("shorter than the motion it is part of" in ln for ln in lines) == (not want)
