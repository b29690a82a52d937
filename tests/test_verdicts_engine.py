"""The engine on hand-made tables: operators, persistence, named checks, episodes."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from test_verdicts_support import frames

from frontdiag.verdicts import evaluate, load_ruleset
from frontdiag.verdicts.engine import persist
from frontdiag.verdicts.operators import OPERATORS, apply, check_value


@pytest.fixture(scope="module")
def ruleset():
    return load_ruleset()


def conds(result, frame: int) -> list[str]:
    t = result.table
    return list(t.loc[t["frame"] == frame, "conditions"].iloc[0])


# --- operators ----------------------------------------------------------------------------------

@pytest.mark.parametrize(("op", "value", "expected"), [
    ("<", 2.0, [True, False, False, False]),
    ("<=", 2.0, [True, True, False, False]),
    (">", 2.0, [False, False, True, False]),
    (">=", 2.0, [False, True, True, False]),
    ("==", 2.0, [False, True, False, False]),
    ("!=", 2.0, [True, False, True, False]),
    ("between", [1.0, 2.0], [True, True, False, False]),
    ("outside", [1.5, 2.5], [True, False, True, False]),
    ("is_nan", None, [False, False, False, True]),
    ("not_nan", None, [True, True, True, False]),
])
def test_operators_on_a_column_with_nan(op, value, expected) -> None:
    x = np.array([1.0, 2.0, 3.0, np.nan])
    assert apply(op, x, value).tolist() == expected


def test_abs_clause_reads_magnitude() -> None:
    assert apply(">", np.array([-24.0, 3.0, 9.0]), 8, use_abs=True).tolist() == [True, False, True]


def test_operator_set_is_closed_and_values_checked() -> None:
    assert check_value("~=", 1.0) is not None
    assert check_value("between", [2.0, 1.0]) is not None
    assert check_value("<", [1.0, 2.0]) is not None
    assert check_value("is_nan", 1.0) is not None
    assert set(OPERATORS) >= {"<", "<=", ">", ">=", "==", "!=", "between", "is_nan", "not_nan"}


# --- persistence windows ------------------------------------------------------------------------

def test_persistence_k_of_n_keeps_runs_and_drops_blips() -> None:
    raw = np.array([0, 1, 0, 0, 0, 1, 1, 1, 0, 0, 0, 1, 0, 1, 0], dtype=bool)
    kept = persist(raw, 3, 5)
    assert np.flatnonzero(kept).tolist() == [5, 6, 7]


def test_persistence_does_not_extend_an_episode() -> None:
    raw = np.array([0, 0, 1, 1, 1, 1, 0, 0], dtype=bool)
    assert (persist(raw, 3, 5) == raw).all()


def test_persistence_with_gaps_inside_the_window() -> None:
    raw = np.array([1, 0, 1, 0, 1, 0, 0, 0], dtype=bool)
    assert persist(raw, 3, 5).tolist() == [True, False, True, False, True, False, False, False]
    assert not persist(raw, 3, 4).any()


def test_persistence_shorter_group_than_window() -> None:
    """A topic shorter than the window is one window, and the same share must hit:
    ceil(k * rows / n) rows, so a condition that fills three panorama shots is reported."""
    b = lambda *v: np.array(v, dtype=bool)  # noqa: E731
    assert persist(b(0, 1, 1), 3, 5).tolist() == [False, True, True]  # 2 of 3 >= ceil(1.8)
    assert persist(b(0, 1, 0), 3, 5).tolist() == [False, False, False]  # a lone hit stays out
    assert persist(b(1, 1), 3, 5).tolist() == [True, True]  # ceil(1.2) = 2 of 2
    assert persist(b(0, 1), 3, 5).tolist() == [False, False]
    assert persist(b(1, 1, 0, 1), 3, 5).tolist() == [True, True, False, True]  # 3 of 4
    assert persist(b(1, 0, 0, 1), 3, 5).tolist() == [False, False, False, False]
    assert persist(b(1), 3, 5).tolist() == [True]  # one row: its own reading
    # from n rows on, k of n as before
    assert persist(b(1, 1, 0, 0, 0), 3, 5).tolist() == [False] * 5


def test_persistence_windows_stay_inside_a_stretch_the_frontend_ran_through() -> None:
    raw = np.isin(np.arange(20), [8, 9, 10])
    assert persist(raw, 3, 5).sum() == 3  # 3 of 5 in one stretch
    at_10 = np.arange(20) == 10  # the frontend restarted at row 10
    assert not persist(raw, 3, 5, breaks=at_10).any()  # 2 of 5 before it, 1 of 5 after
    assert (persist(raw, 3, 5, breaks=np.arange(20) == 0) == raw).all()  # row 0 starts anyway
    # a short stretch is read like a short recording: 2 of its 2 rows
    assert persist(raw, 3, 5, breaks=np.arange(20) == 12).tolist() == raw.tolist()


def test_a_gap_or_a_size_change_splits_episodes_and_persistence(ruleset) -> None:
    lows = {"h_over_e": 0.98, "parallax_med_deg": 0.04}
    for status in ("after_gap", "size_changed"):
        t = frames(20, {range(6, 10): lows, range(11, 15): lows}, rate_hz=15.0)  # 3 of 5 rows
        t.loc[10:, "t_ns"] += 30_000_000_000  # 30 s without frames
        t.loc[10, "status"] = status
        for c in lows:
            t.loc[10, c] = np.nan  # nothing compared across it
        eps = evaluate(t, ruleset).episodes
        rot = eps[eps["condition"] == "pure_rotation"]
        assert sorted(zip(rot.start_frame, rot.end_frame, strict=True)) == [(6, 9), (11, 14)]
        assert (rot["duration_s"] < 1.0).all()
        # two rows before it and one after are not 3 of 5
        t2 = frames(20, {range(8, 10): lows, 11: lows}, rate_hz=15.0)
        t2.loc[10:, "t_ns"] += 30_000_000_000
        t2.loc[10, "status"] = status
        assert not evaluate(t2, ruleset).hits["FD-ROT-001"].any()
        t2.loc[10, "status"] = "ok"  # the same rows read as one stretch
        assert evaluate(t2, ruleset).hits["FD-ROT-001"].sum() == 3


def test_persistence_window_spans_a_time_not_a_number_of_rows(ruleset) -> None:
    rot = next(r for r in ruleset.rules if r.id == "FD-ROT-001")
    p = rot.persistence
    assert p is not None and p.span_s == pytest.approx(0.33)
    # 5 rows at the 15 Hz the window was set at and below; as many rows as 0.33 s holds above
    assert p.window(15.0) == (3, 5) and p.window(10.0) == (3, 5) and p.window(1.0) == (3, 5)
    assert p.window(30.0) == (6, 10)
    assert p.window(200.0) == (40, 66)  # ceil(3 * 66 / 5)
    assert p.window(float("nan")) == (3, 5)  # no stamps: the rows as written

    # the same bursts of "rotation" (0.13 s and 0.2 s) and the same 1 s pan, at 15 and 30 Hz
    def run(rate: float) -> list[int]:
        short = range(round(1.0 * rate), round(1.0 * rate) + round(0.4 * rate / 3))
        burst = range(round(2.0 * rate), round(2.2 * rate))
        pan = range(round(3.0 * rate), round(4.0 * rate))
        lows = {"h_over_e": 0.98, "parallax_med_deg": 0.04}
        t = frames(round(5 * rate), {short: lows, burst: lows, pan: lows}, rate_hz=rate)
        hit = evaluate(t, ruleset).hits["FD-ROT-001"]
        return [len(short), int(hit[short].sum()), len(burst), int(hit[burst].sum()),
                int(hit[pan].sum()) == len(pan)]

    # 0.13 s is 2 rows of 5 at 15 Hz and 4 of 10 at 30 Hz: a blip at both rates (a 5-row
    # window kept those 4 rows at 30 Hz); 0.2 s is 3 of 5 and 6 of 10: kept at both
    assert run(15.0) == [2, 0, 3, 3, True]
    assert run(30.0) == [4, 0, 6, 6, True]
    # the 4 rows at 30 Hz, which a window of 5 rows alone keeps
    assert persist(np.isin(np.arange(150), range(30, 34)), 3, 5).sum() == 4


def test_frame_rate_from_the_stamps() -> None:
    from frontdiag.verdicts.engine import frame_rate
    assert frame_rate(frames(20, rate_hz=30.0)) == pytest.approx(30.0, rel=1e-5)
    shuffled = frames(20, rate_hz=12.5).sample(frac=1.0, random_state=1)
    assert frame_rate(shuffled) == pytest.approx(12.5, rel=1e-5)
    one = frames(1)
    assert np.isnan(frame_rate(one))


# --- named checks on the reference rows ----------------------------------------------------------

def test_healthy_table_has_no_findings(ruleset) -> None:
    res = evaluate(frames(60), ruleset)
    assert (res.table["verdict"] == "ok").all()
    assert res.episodes.empty


def test_matching_table_repetitive_vs_detection_vs_exposure(ruleset) -> None:
    t = frames(60, {
        range(5, 15): {"n_keypoints": 1000, "ratio_reject_rate": 0.85,       # repetitive aisle
                        "in_frame_twin_rate": 0.3},
        range(25, 35): {"n_keypoints": 120, "ratio_reject_rate": 0.30},      # dark / blank
        40: {"d_mean_intensity": 24.0, "photo_residual_med": 22.0, "ratio_reject_rate": 0.55,
             "affine_gain": 1.2},                                            # exposure step
        41: {"ratio_reject_rate": 0.55}, 42: {"ratio_reject_rate": 0.50},     # recovers in 2-3
    })
    res = evaluate(t, ruleset)
    for f in range(5, 15):
        assert conds(res, f) == ["repetitive_structure"]
    for f in range(25, 35):
        assert conds(res, f) == ["detection_failure"]
    assert conds(res, 40) == ["exposure_step"]
    assert "repetitive_structure" not in conds(res, 41)
    assert all(not conds(res, f) for f in (20, 45, 50))


@pytest.mark.parametrize(("rate_hz", "expected"), [(30.0, True), (3.0, True), (1.0, False)])
def test_repetition_is_read_between_frames_of_a_tracking_rate(ruleset, rate_hz, expected) -> None:
    # ~85% rejection at unchanged feature count: repetition at 30 Hz and at the 3 Hz of a
    # relocalisation path; frames 1 s apart reject that much from viewpoint change alone
    t = frames(20, {range(5, 15): {"ratio_reject_rate": 0.85, "in_frame_twin_rate": 0.3}},
               rate_hz=rate_hz)
    res = evaluate(t, ruleset)
    assert all(("repetitive_structure" in conds(res, f)) == expected for f in range(7, 15))


def test_where_no_level_forms_nearby_the_baseline_widens_to_the_recordings_own(ruleset) -> None:
    """A drive at 10 Hz whose rejection sits at 72 % for 20 s (no twins) inside a recording
    that runs at 60 % elsewhere: within 10 s no level forms (three quarters of the rows at or
    over the 70 % line), the window widens until one does, and the stretch is read against the
    recording's 60 %, not the absolute line. A recording that is one aisle throughout has no
    level at any width, and the absolute line still reads it."""
    from frontdiag.verdicts.explain import explain_row

    rej = np.full(400, 0.60)
    rej[150:350] = 0.72
    t = frames(400, {i: {"ratio_reject_rate": float(rej[i]), "ratio_ambiguous_rate": 0.1}
                     for i in range(400)}, rate_hz=10.0)
    res = evaluate(t, ruleset)
    mid = res.table.loc[250]
    assert mid["ratio_reject_base_window_s"] > 10 and 0.55 < mid["ratio_reject_base"] < 0.65
    assert not any("repetitive_structure" in conds(res, f) for f in range(400))
    lines = next(e for e in explain_row(res, 250) if e.rule.id == "FD-REP-001").check_lines
    assert any("the window widened to the nearest level" in ln for ln in lines)
    aisle = evaluate(frames(100, {range(100): {"ratio_reject_rate": 0.85,
                                               "ratio_ambiguous_rate": 0.03,
                                               "in_frame_twin_rate": 0.3}}, rate_hz=10.0),
                     ruleset)
    assert np.isnan(aisle.table["ratio_reject_base"]).all()
    assert all("repetitive_structure" in conds(aisle, f) for f in range(5, 95))


def test_a_gap_the_frontend_restarted_after_is_not_a_declined_row(ruleset) -> None:
    # after a gap the frontend matches nothing (no rejection reading): nothing was declined
    t = frames(20)
    t.loc[10:, "t_ns"] += 2_000_000_000
    t.loc[10, ["status", "ratio_reject_rate"]] = ["after_gap", np.nan]
    assert not [n for n in evaluate(t, ruleset).notes if n.startswith("FD-REP-001")]
    t.loc[10, "ratio_reject_rate"] = 0.5    # a reading across the same 2 s is declined
    assert [n for n in evaluate(t, ruleset).notes if n.startswith("FD-REP-001")]


def test_exposure_window_keeps_a_rejection_spike_from_reading_as_repetition(ruleset) -> None:
    # the rejection spike of the 2-3 frames after an exposure step is the step's
    t = frames(30, {10: {"d_mean_intensity": -20.0, "photo_residual_med": 21.0,
                         "ratio_reject_rate": 0.60},
                    11: {"ratio_reject_rate": 0.86}, 12: {"ratio_reject_rate": 0.86}})
    res = evaluate(t, ruleset)
    assert "repetitive_structure" not in set().union(*map(set, res.table["conditions"]))
    assert conds(res, 10) == ["exposure_step"]


def test_exposure_step_needs_the_residual_to_jump_not_just_the_scene(ruleset) -> None:
    # scene brightness changes (a bright floor enters the view) without a gain step: tracked
    # features keep their intensity, so the photometric residual stays at ~4
    t = frames(30, {10: {"d_mean_intensity": 12.0, "photo_residual_med": 4.2}})
    assert conds(evaluate(t, ruleset), 10) == []


def test_exposure_step_is_one_frame_wide_unlike_motion_blur(ruleset) -> None:
    # blur degrades the residual over several frames: the frame before is already disturbed
    t = frames(30, {8: {"photo_residual_med": 12.0}, 9: {"photo_residual_med": 16.0},
                    10: {"d_mean_intensity": 9.0, "photo_residual_med": 20.0}})
    assert conds(evaluate(t, ruleset), 10) == []


def test_exposure_step_recovers_within_three_frames_a_ramp_does_not(ruleset) -> None:
    step = {10: {"d_mean_intensity": 20.0, "photo_residual_med": 22.0},
            11: {"photo_residual_med": 15.0}}               # one disturbed frame, then clean
    res = evaluate(frames(30, step), ruleset)
    assert [f for f in range(30) if conds(res, f)] == [10, 11]
    ramp = {i: {"d_mean_intensity": -20.0, "photo_residual_med": 21.0} for i in range(10, 15)}
    res = evaluate(frames(30, ramp), ruleset)                # lights fading over five frames
    assert (res.table["verdict"] == "ok").all()


def test_a_scene_cut_is_not_an_exposure_step(ruleset) -> None:
    # the view changes completely: the mean jumps, the residual explodes and nothing matches
    t = frames(30, {10: {"d_mean_intensity": 13.0, "photo_residual_med": 50.0,
                         "ratio_reject_rate": 0.98}})
    assert conds(evaluate(t, ruleset), 10) == []


@pytest.mark.parametrize(("res_aff", "expected"), [
    (3.6, ["exposure_step"]),   # the affine model explains it: only the gain changed
    (45.0, []),                 # unrelated views at a scene cut keep their residual
    (np.nan, []),               # no affine fit: the rejection alone speaks, and says collapse
])
def test_a_step_where_the_scene_already_rejects_much(ruleset, res_aff, expected) -> None:
    # Approaching a bright doorway the base rejection is ~57%; a gain step adds its ~15-25
    # points on top and crosses the 70% line. Whether the affine brightness model removes the
    # residual (distinguishing value) tells the step from a scene cut.
    base = {range(30): {"ratio_reject_rate": 0.57}}
    base[10] = {"d_mean_intensity": -16.9, "photo_residual_med": 16.0, "ratio_reject_rate": 0.73,
                "photo_residual_affine_med": res_aff, "affine_gain": 0.85}
    assert conds(evaluate(frames(30, base), ruleset), 10) == expected


def test_a_rule_file_without_the_affine_level_reads_rejection_alone(tmp_path) -> None:
    # rules written before residual_affine_max still load; the 70% line then decides alone
    import shutil

    from frontdiag.verdicts.loader import default_rules_dir

    rules = tmp_path / "rules"
    shutil.copytree(default_rules_dir(), rules)
    toml = rules / "photometric.toml"
    toml.write_text("".join(line for line in toml.read_text().splitlines(keepends=True)
                            if not line.startswith("residual_affine_max")))
    base = {range(30): {"ratio_reject_rate": 0.57}}
    base[10] = {"d_mean_intensity": -16.9, "photo_residual_med": 16.0, "ratio_reject_rate": 0.73,
                "photo_residual_affine_med": 3.6}
    assert conds(evaluate(frames(30, base), load_ruleset(rules)), 10) == []
    base[10]["ratio_reject_rate"] = 0.60
    assert conds(evaluate(frames(30, base), load_ruleset(rules)), 10) == ["exposure_step"]


def test_exposure_step_recovery_is_relative_to_the_scene(ruleset) -> None:
    # a close-up texture runs at a residual of ~9; after the step it returns there, not to 4
    base = {i: {"photo_residual_med": 9.0} for i in range(30)}
    base[10] = {"d_mean_intensity": 23.0, "photo_residual_med": 26.0}
    assert conds(evaluate(frames(30, base), ruleset), 10) == ["exposure_step"]


def test_exposure_step_without_photometric_residual_uses_rejection(ruleset) -> None:
    t = frames(30, {10: {"d_mean_intensity": 15.0, "ratio_reject_rate": 0.55}})
    t["photo_residual_med"] = np.nan
    assert conds(evaluate(t, ruleset), 10) == ["exposure_step"]


@pytest.mark.parametrize(("he", "parallax", "expected"), [
    (0.98, 0.04, "pure_rotation"),
    (0.95, 2.5, "planar_degeneracy"),
    (0.42, 2.1, None),          # healthy
    (0.42, 0.04, None),         # nearly stationary with 3D structure: safe
])
def test_he_parallax_quadrants(ruleset, he, parallax, expected) -> None:
    t = frames(20, {range(5, 15): {"h_over_e": he, "parallax_med_deg": parallax}})
    got = conds(evaluate(t, ruleset), 10)
    assert got == ([expected] if expected else [])


@pytest.mark.parametrize(("px", "expected"), [(12.0, ["planar_degeneracy"]), (3.5, [])])
def test_a_planar_reading_on_few_pixels_is_declined_and_said_so(ruleset, px, expected) -> None:
    # at 320x240 and 30 Hz a keyframe interval can span ~3.5 px: a 3D scene fits H there too
    plane = {"h_over_e": 0.96, "parallax_med_deg": 0.8, "parallax_med_px": px}
    res = evaluate(frames(30, {range(5, 25): plane}), ruleset)
    assert conds(res, 15) == expected
    declined = [n for n in res.notes if n.startswith("FD-PLN-001")]
    if expected:
        assert not declined
    else:
        assert len(declined) == 1 and "did not read 20 row(s)" in declined[0]
        assert "4.9 px" in declined[0]


@pytest.mark.parametrize(("he2", "px2", "expected"), [
    (0.94, 7.0, ["planar_degeneracy"]),  # two intervals: enough parallax, still degenerate
    (0.74, 7.0, []),                     # two intervals tell a 3D scene (healthy at 320x240)
    (0.94, 4.0, []),                     # still too few pixels: declined, with the note
])
def test_a_short_interval_is_read_two_keyframes_back(ruleset, he2, px2, expected) -> None:
    # at 320x240 and 30 Hz one interval spans ~3.5 px; the frontend then also reads each frame
    # against the keyframe before its reference (h_over_e_2kf, parallax_med_px_2kf)
    short = {"h_over_e": 0.96, "parallax_med_deg": 0.8, "parallax_med_px": 3.5,
             "h_over_e_2kf": he2, "parallax_med_deg_2kf": 1.6, "parallax_med_px_2kf": px2,
             "ref2_frame": 0}
    res = evaluate(frames(30, {range(5, 25): short}), ruleset)
    assert conds(res, 15) == expected
    declined = [n for n in res.notes if n.startswith("FD-PLN-001")]
    assert bool(declined) == (px2 < 4.9)


def test_the_two_interval_read_fills_only_short_intervals(ruleset) -> None:
    # an interval that spans 12 px is read on its own, whatever the two-interval columns say
    plane = {"h_over_e": 0.96, "parallax_med_deg": 0.8, "parallax_med_px": 12.0,
             "h_over_e_2kf": 0.5, "parallax_med_deg_2kf": 1.6, "parallax_med_px_2kf": 20.0}
    assert conds(evaluate(frames(30, {range(5, 25): plane}), ruleset), 15) == \
        ["planar_degeneracy"]


@pytest.mark.parametrize(("rot", "still"), [(3.0, False), (0.05, True)])
def test_standing_still_is_reported_as_pure_rotation_with_its_reason(ruleset, rot, still) -> None:
    """H/E ~1 and no parallax in both cases: a panning camera and one that neither turns nor
    moves. Neither has a baseline to triangulate from, so both read pure_rotation; only the one
    standing still carries the reason "standing still"."""
    from frontdiag.verdicts.explain import explain_row

    row = {"h_over_e": 0.98, "parallax_med_deg": 0.02, "parallax_med_px": 0.3, "rot_deg": rot}
    res = evaluate(frames(20, {range(5, 15): row}), ruleset)
    assert conds(res, 10) == ["pure_rotation"]
    rot_rule = next(e for e in explain_row(res, 10) if e.rule.id == "FD-ROT-001")
    assert rot_rule.fired
    assert any("standing still" in line for line in rot_rule.check_lines) == still
    assert "standing still" in rot_rule.rule.title


@pytest.mark.parametrize(("he", "par_deg", "par_px", "rot", "want"), [
    (0.6, 0.05, 0.8, 0.05, ["pure_rotation"]),   # still, people crossing: H/E not read
    (0.6, 0.05, 3.5, 0.05, []),                  # moved more than the 2.45 px noise bound
    (0.6, 0.05, 0.8, 0.5, []),                   # turned: not still, and H/E is low
    (0.6, 0.4, 0.8, 0.05, []),                   # parallax over the 0.3 deg split
])
def test_standing_still_is_decided_without_h_over_e(ruleset, he, par_deg, par_px, rot,
                                                    want) -> None:
    """With no motion every static point is an inlier of any E with R = I, so E also takes the
    points moving through the view and H/E falls: standing still is read on the motion alone,
    parallax under the split and under 2.45 px in the image, rotation under 0.3 deg."""
    row = {"h_over_e": he, "parallax_med_deg": par_deg, "parallax_med_px": par_px,
           "rot_deg": rot}
    lines = _rotation_reading(ruleset, row, want)
    assert not want or any("standing still" in ln for ln in lines)
    assert not want or any("is not read when standing still" in ln for ln in lines)


def _rotation_reading(ruleset, row: dict, want: list[str]) -> list[str]:
    """Conditions of the middle of ten frames reading ``row``, checked against ``want``, and
    FD-ROT-001's explain lines there."""
    from frontdiag.verdicts.explain import explain_row

    res = evaluate(frames(20, {range(5, 15): row}), ruleset)
    assert conds(res, 10) == want
    return next(e for e in explain_row(res, 10) if e.rule.id == "FD-ROT-001").check_lines


@pytest.mark.parametrize(("he", "rot", "rot_px", "want"), [
    (0.7, 20.0, 1.2, ["pure_rotation"]),   # a panorama: E absorbs mismatches, H/E falls
    (0.7, 20.0, 6.0, []),                  # turned and translated: no rotation explains it
    (0.7, 1.0, 1.2, []),                   # 8.4 px at this focal: within E's scatter
    (0.7, 1.4, 1.2, ["pure_rotation"]),    # 11.7 px: over the 10 px line
])
def test_a_turn_explained_by_rotation_is_rotation_whatever_h_over_e(ruleset, he, rot, rot_px,
                                                                    want) -> None:
    # parallax 6 deg reading 50 px: a focal of 476 px, so the turn moves the image
    # 476 tan(rot) px
    row = {"h_over_e": he, "parallax_med_deg": 6.0, "parallax_med_px": 50.0, "rot_deg": rot,
           "rot_only_px": rot_px}
    lines = _rotation_reading(ruleset, row, want)
    assert not want or any("rotation alone explains" in ln for ln in lines)


@pytest.mark.parametrize(("shared", "want"), [
    (np.nan, []),                 # the shared view unknown: inliers read over the whole grid
    (0.85, ["pure_rotation"]),    # the inliers fill the band both shots saw: spread
    (0.45, []),                   # a patch inside the band: clustered however it is read
])
def test_inliers_in_the_overlap_of_a_turn_are_read_over_that_overlap(ruleset, shared,
                                                                     want) -> None:
    """A panorama shot turned 40 deg shares a third of its view with the one before, so its
    inliers read 0.43 over the whole grid, under the 0.6 line below which a homography fits
    whatever the scene. Over the part of the view both shots saw they are spread."""
    row = {"h_over_e": 0.87, "parallax_med_deg": 6.0, "parallax_med_px": 50.0, "rot_deg": 40.0,
           "rot_only_px": 1.5, "rot_focal_scale": 1.0, "entropy_inliers_norm": 0.43,
           "entropy_inliers_shared_norm": shared}
    lines = _rotation_reading(ruleset, row, want)
    assert any("not read: entropy" in ln for ln in lines) == (not want)
    assert any("over the part the reference keyframe also saw" in ln for ln in lines) == \
        bool(want)


@pytest.mark.parametrize(("he", "rot", "scale", "want"), [
    (0.7, 20.0, 1.1, ["pure_rotation"]),   # a turn through a K 10 % off: a rotation
    (0.7, 20.0, 2.0, []),                  # best at the longest focal searched: not a turn
    (0.7, 20.0, 0.5, []),                  # or at the shortest
    (0.97, 0.05, 1.1, ["pure_rotation"]),  # H/E high, and a rotation fits inside the range
    (0.97, 0.05, 2.0, ["planar_degeneracy"]),  # ...or at its edge: the plane stays a plane
])
def test_a_rotation_fit_counts_only_with_its_focal_inside_the_range(ruleset, he, rot, scale,
                                                                     want) -> None:
    """As the focal grows, x' ~ K R K^-1 x tends to a pure image shift, which is what a camera
    sliding sideways past a flat surface sees: a fit that climbs to the end of the focal range
    is that slide, not a turn through an approximate K."""
    row = {"h_over_e": he, "parallax_med_deg": 6.0, "parallax_med_px": 50.0, "rot_deg": rot,
           "rot_only_px": 1.2, "rot_focal_scale": scale}
    res = evaluate(frames(20, {range(5, 15): row}), ruleset)
    assert conds(res, 10) == want
    if scale in (0.5, 2.0):
        from frontdiag.verdicts.explain import explain_row

        lines = next(e for e in explain_row(res, 10) if e.rule.id == "FD-ROT-001").check_lines
        assert any("an end of the 0.5-2x focal range searched" in ln for ln in lines)


@pytest.mark.parametrize(("w", "required", "want"), [
    (0.85, 12, ["planar_degeneracy"]),               # a plane keeps its correspondences
    (0.125, 226_350, ["ransac_starved"]),            # a chequerboard's chance consensus
    (0.125, np.nan, ["planar_degeneracy"]),          # a table without the columns: as before
])
def test_a_starved_ransac_gives_no_h_over_e_reading(ruleset, w, required, want) -> None:
    """A hand-held chequerboard's ratio-test survivors are 10-30 % right: 1000 iterations fit E
    and H to a chance consensus of 8-28 points, and H/E 0.94-1.67 from them said planar. The
    row is RANSAC starvation (FD-RAN-001), not a reading of the scene."""
    from frontdiag.verdicts.explain import explain_row

    row = {"h_over_e": 1.4, "parallax_med_deg": 8.0, "parallax_med_px": 80.0, "rot_deg": 5.0,
           "inliers_e": 14, "inliers_h": 20, "inlier_ratio": w,
           "ransac_iters_required": required, "ransac_iters_run": 1000}
    res = evaluate(frames(20, {range(5, 15): row}), ruleset)
    assert conds(res, 10) == want
    for rid in ("FD-PLN-001", "FD-ROT-001"):
        lines = next(e for e in explain_row(res, 10) if e.rule.id == rid).check_lines
        assert any("not read: RANSAC was starved" in ln for ln in lines) == \
            (want == ["ransac_starved"])
    starved_note = [n for n in res.notes if n.startswith("FD-PLN-001") and "starved" in n]
    assert len(starved_note) == (1 if want == ["ransac_starved"] else 0)
    if starved_note:
        assert "did not read 10 row(s)" in starved_note[0]


@pytest.mark.parametrize(("rot_px", "scale", "want"), [
    (np.nan, np.nan, ["pure_rotation"]),    # no fit taken: the angle decides
    (0.8, 1.1, ["pure_rotation"]),          # a rotation fits inside the range
    (0.8, 2.0, ["planar_degeneracy"]),      # only a pure shift fits: a plane sliding past
])
def test_a_low_angle_on_a_plane_whose_fit_sits_at_the_edge_is_planar(ruleset, rot_px, scale,
                                                                     want) -> None:
    """On a plane E is not unique: the simulator's side wall at 640x480 read 1-3 deg of
    rotation and 0.13-0.32 deg of parallax over a keyframe interval, the pure-rotation quadrant,
    while the rotation-only fit sat at 2x. A homography that only a pure image shift explains
    is a plane under translation, whatever share of it E calls rotation."""
    # f = 1260 px (1280x720): 0.25 deg is 5.5 px, over the 4.9 px H/E needs to read a plane
    row = {"h_over_e": 0.98, "parallax_med_deg": 0.25, "parallax_med_px": 5.5, "rot_deg": 2.0,
           "rot_only_px": rot_px, "rot_focal_scale": scale}
    res = evaluate(frames(20, {range(5, 15): row}), ruleset)
    assert conds(res, 10) == want


def test_fits_at_the_edge_of_the_focal_range_outvote_a_lone_fit_inside_it(ruleset) -> None:
    """Over a keyframe interval the fit is read as the median over its higher-parallax frames.
    A fit at the end of the range counts against a rotation, not as a missing reading: on the
    simulator's side wall at 320x240 one frame of an interval found its best focal at 1.59x and
    three at 2x, and the lone fit inside the range used to decide the interval."""
    changes = {}
    for i in range(1, 41):
        k = (i - 1) % 4
        changes[i] = {"ref_frame": 4 * ((i - 1) // 4), "h_over_e": 0.97,
                      "parallax_med_deg": 1.0 + 0.5 * k, "parallax_med_px": 4.0 + 2.0 * k,
                      "rot_deg": 0.1, "rot_only_px": np.nan if k == 0 else 0.4,
                      "rot_focal_scale": np.nan if k == 0 else 1.59 if k == 3 else 2.0}
    # the upper half by parallax is k = 2 (at 2x) and k = 3 (inside): the edge is not ignored
    res = evaluate(frames(41, changes), ruleset)
    assert conds(res, 20) == ["planar_degeneracy"]
    from frontdiag.verdicts.explain import explain_row

    for f in (20, 21, 23):  # k = 3 (inside), k = 0 (no fit of its own), k = 2 (at the edge)
        lines = next(e for e in explain_row(res, f) if e.rule.id == "FD-PLN-001").check_lines
        edge = [ln for ln in lines if "focal range searched" in ln]
        assert len(edge) == 1 and "nan" not in edge[0]
        assert ("this frame's fit is best at 2x" in edge[0]) == (f == 23)
    for i in range(1, 41):
        changes[i]["rot_focal_scale"] = 1.2
        changes[i]["rot_only_px"] = 0.4
    res = evaluate(frames(41, changes), ruleset)  # every fit inside the range: a rotation
    assert conds(res, 20) == ["pure_rotation"]


def _keyframe_intervals(he_first: float, he_last: float, n: int = 40) -> pd.DataFrame:
    """Intervals of 4 frames per reference keyframe, parallax growing 0.5 -> 1.4 deg in each."""
    changes = {}
    for i in range(1, n):
        k = (i - 1) % 4
        changes[i] = {"ref_frame": 4 * ((i - 1) // 4), "parallax_med_deg": 0.5 + 0.3 * k,
                      "h_over_e": he_first + (he_last - he_first) * k / 3}
    return frames(n, changes)


def test_h_over_e_is_read_where_the_keyframe_saw_most_parallax(ruleset) -> None:
    # healthy driving: right after each keyframe change H/E reads 0.95 at 0.5 deg of parallax
    # (any scene fits a homography at a tiny baseline) and falls to 0.55 as parallax grows
    res = evaluate(_keyframe_intervals(0.95, 0.55), ruleset)
    assert (res.table["verdict"] == "ok").all()
    # a plane: H/E stays above 0.9 as the parallax grows, so every frame of the interval is planar
    res = evaluate(_keyframe_intervals(0.96, 0.93), ruleset)
    assert all(conds(res, f) == ["planar_degeneracy"] for f in range(5, 35))


def test_reading_per_frame_is_an_override_away(ruleset, tmp_path) -> None:
    ov = tmp_path / "ov.toml"
    ov.write_text('[FD-PLN-001]\nthreshold.read_at = "frame"\n')
    res = evaluate(_keyframe_intervals(0.95, 0.55, n=80), load_ruleset(overrides=ov))
    assert res.rule_frames("FD-PLN-001") == 0      # isolated frames: persistence drops them
    ov.write_text('[FD-PLN-001]\nthreshold.read_at = "frame"\npersistence = false\n')
    res = evaluate(_keyframe_intervals(0.95, 0.55, n=80), load_ruleset(overrides=ov))
    assert res.rule_frames("FD-PLN-001") > 0


def test_clustering_confirmed_by_pose_information(ruleset) -> None:
    t = frames(20, {range(5, 15): {"entropy_norm": 0.36, "pose_info_cond": 5000.0}})
    res = evaluate(t, ruleset)
    assert conds(res, 10) == ["feature_clustering"]
    assert "FD-CLU-001" in res.table.loc[10, "rules"]
    assert res.table.loc[10, "verdict"] == "fail"


def test_low_entropy_with_a_healthy_pose_is_not_clustering(ruleset) -> None:
    t = frames(20, {range(5, 15): {"entropy_norm": 0.36, "pose_info_cond": 60.0}})
    assert conds(evaluate(t, ruleset), 10) == []


def test_clustering_without_intrinsics_is_an_unconfirmed_warning(ruleset) -> None:
    t = frames(20, {range(5, 15): {"entropy_norm": 0.36, "pose_info_cond": np.nan}})
    res = evaluate(t, ruleset)
    assert list(res.table.loc[10, "rules"]) == ["FD-CLU-002"]
    assert res.table.loc[10, "verdict"] == "warn"


def test_few_clustered_features_are_a_detection_failure_not_clustering(ruleset) -> None:
    t = frames(20, {range(5, 15): {"n_keypoints": 120, "entropy_norm": 0.3,
                                   "pose_info_cond": 9000.0}})
    assert conds(evaluate(t, ruleset), 10) == ["detection_failure"]


def test_ransac_starvation_marks_the_frame(ruleset) -> None:
    t = frames(10, {4: {"inlier_ratio": 0.14, "ransac_iters_required": 233,
                        "ransac_iters_run": 40}})
    res = evaluate(t, ruleset)
    assert conds(res, 4) == ["ransac_starved"]
    assert res.table.loc[4, "verdict"] == "fail"
    assert conds(res, 5) == []


def test_registration_degeneracy_on_lidar_rows_only(ruleset) -> None:
    cam = frames(30)
    lidar = frames(20, {range(5, 15): {"lidar_eig_min": 12.0, "lidar_cond": 1500.0,
                                       "icp_fitness": 0.97, "icp_rmse_m": 0.021}},
                   sensor="lidar", rate_hz=10)
    res = evaluate(pd.concat([cam, lidar], ignore_index=True), ruleset)
    lid = res.table[res.table["sensor"] == "lidar"]
    hit = lid[lid["conditions"].map(len) > 0]
    assert sorted(hit["frame"]) == list(range(5, 15))
    assert (res.table[res.table["sensor"] == "camera"]["verdict"] == "ok").all()
    ep = res.episodes.iloc[0]
    assert ep["condition"] == "registration_degeneracy" and ep["sensor"] == "lidar"
    assert ep["peak_lidar_eig_min"] == 12.0


def test_nan_metrics_never_fire_a_threshold(ruleset) -> None:
    t = frames(20)
    for c in ("h_over_e", "parallax_med_deg", "pose_info_cond", "ratio_reject_rate",
              "ransac_iters_required", "photo_residual_med", "d_mean_intensity"):
        t[c] = np.nan
    assert (evaluate(t, ruleset).table["verdict"] == "ok").all()


def test_missing_columns_read_as_not_computable(ruleset) -> None:
    t = frames(10)[["frame", "t_ns", "sensor", "topic", "n_keypoints", "status"]]
    t.loc[3, "n_keypoints"] = 50
    assert conds(evaluate(t, ruleset), 3) == ["detection_failure"]


def test_keypoint_fill_is_derived_for_tables_written_without_it(ruleset) -> None:
    """Older tables: the floor is prorated by the image area and the manifest's budget."""
    t = frames(10).drop(columns=["keypoint_fill"])
    t[["width", "height"]] = (320, 240)                       # 1/12 of 1280x720
    t.loc[3, "n_keypoints"] = 200                            # a clustered small view: fine
    t.loc[5, "n_keypoints"] = 20                             # 20 of an expected 83: failed
    out = evaluate(t, ruleset).table
    assert out.loc[3, "keypoint_fill"] == pytest.approx(200 / (1000 / 12))
    assert conds(evaluate(t, ruleset), 3) == [] and conds(evaluate(t, ruleset), 5) == [
        "detection_failure"]
    t.attrs["manifest"] = {"params": {"camera": {"n_features": 2000}}}
    assert evaluate(t, ruleset).table.loc[3, "keypoint_fill"] == pytest.approx(200 / (2000 / 12))


# --- run-level correlation ----------------------------------------------------------------------

def test_pose_increment_correlates_with_exposure_steps(ruleset) -> None:
    rng = np.random.default_rng(0)
    n = 90
    rot = np.cumsum(rng.normal(0.2, 0.02, n))
    dmean = rng.normal(0, 0.5, n)
    for step in (20, 50, 75):
        dmean[step] = 20.0
        rot[step:] += 3.0            # the pose jumps exactly at the step
    t = frames(n, {range(n): {"ref_frame": 0}})
    t["rot_deg"], t["d_mean_intensity"] = rot, dmean
    f = next(f for f in evaluate(t, ruleset).run_findings if f.rule == "FD-RUN-001")
    assert f.fired and f.value > 0.9
    assert 20 in f.frames


def test_healthy_run_has_near_zero_correlation(ruleset) -> None:
    rng = np.random.default_rng(1)
    n = 90
    t = frames(n, {range(n): {"ref_frame": 0}})
    t["rot_deg"] = np.cumsum(rng.normal(0.2, 0.05, n))
    t["d_mean_intensity"] = rng.normal(0, 0.5, n)
    t.loc[40, "d_mean_intensity"] = 12.0        # a step the pose ignores
    f = next(f for f in evaluate(t, ruleset).run_findings if f.rule == "FD-RUN-001")
    assert not f.fired and abs(f.value) < 0.5


# --- episodes -----------------------------------------------------------------------------------

def test_consecutive_frames_merge_into_one_episode_across_a_one_frame_gap(ruleset) -> None:
    t = frames(60, {range(10, 20): {"n_keypoints": 100}, range(21, 26): {"n_keypoints": 100},
                    range(40, 43): {"n_keypoints": 100}})
    res = evaluate(t, ruleset)
    eps = res.episodes
    assert len(eps) == 2
    first = eps.iloc[0]
    assert (first["start_frame"], first["end_frame"], first["n_frames"]) == (10, 25, 15)
    assert first["n_rows"] == 16
    assert first["start_t_ns"] == int(t.loc[10, "t_ns"])      # exact, not via float
    assert first["peak_n_keypoints"] == 100
    assert "detection_failure" in first["summary"]
    # the gap row itself is not marked: frame precision is unaffected
    assert conds(res, 20) == []


def test_two_clean_rows_split_episodes(ruleset) -> None:
    t = frames(40, {range(10, 15): {"n_keypoints": 100}, range(17, 20): {"n_keypoints": 100}})
    assert len(evaluate(t, ruleset).episodes) == 2


def test_episodes_are_per_topic_and_worst_first(ruleset) -> None:
    a = frames(40, {range(5, 10): {"ratio_reject_rate": 0.9,
                                   "in_frame_twin_rate": 0.3}}, topic="/cam_left", rate_hz=15)
    b = frames(40, {range(20, 23): {"n_keypoints": 90}, range(30, 38): {"n_keypoints": 90}},
               topic="/cam_right")
    res = evaluate(pd.concat([a, b], ignore_index=True), ruleset)
    eps = res.episodes
    assert list(eps["severity"]) == ["fail", "fail", "warn"]
    assert list(eps["n_frames"][:2]) == [8, 3]          # longer first within a severity
    assert set(eps["topic"]) == {"/cam_left", "/cam_right"}


def test_rows_are_grouped_by_topic_and_time_not_table_order(ruleset) -> None:
    t = frames(30, {range(10, 20): {"h_over_e": 0.98, "parallax_med_deg": 0.04}})
    shuffled = t.sample(frac=1.0, random_state=3).reset_index(drop=True)
    res = evaluate(shuffled, ruleset)
    hit = res.table[res.table["conditions"].map(len) > 0]
    assert sorted(hit["frame"]) == list(range(10, 20))


def test_evaluate_keeps_input_columns_and_replaces_old_verdicts(ruleset) -> None:
    t = frames(10)
    t["conditions"] = [["stale"]] * 10
    res = evaluate(t, ruleset)
    assert list(res.table.columns[: len(t.columns) - 1]) == [c for c in t.columns
                                                             if c != "conditions"]
    assert all(c == [] for c in res.table["conditions"])


def test_at_a_low_rate_the_twins_reading_still_reads_and_only_the_rest_is_declined(
        ruleset) -> None:
    """At 1 Hz (a hand-held photograph set) FD-REP-001's rejection lines are not read, but its
    twins reading holds at any interval: a stretch with twins and copies in the view is
    reported, and the note counts only the rows nothing read (not the reported ones, which a
    note saying the rule did not read them would contradict)."""
    board = {"ratio_reject_rate": 0.9, "ratio_ambiguous_rate": 0.6, "in_frame_twin_rate": 0.3}
    wall = {"ratio_reject_rate": 0.8, "ratio_ambiguous_rate": 0.1}
    res = evaluate(frames(20, {range(1, 12): board, range(12, 20): wall}, rate_hz=1.0), ruleset)
    assert conds(res, 6) == ["repetitive_structure"]
    assert conds(res, 15) == []
    note = [n for n in res.notes if n.startswith("FD-REP-001")]
    assert len(note) == 1 and "did not read 8 row(s)" in note[0]
    assert "0.34 s" in note[0] and "twins reading" in note[0]


@pytest.mark.parametrize("log", ["dock_corridor.mcap", "lights_out.mcap"])
def test_the_rules_leave_the_table_they_read_as_it_was(ruleset, log, monkeypatch) -> None:
    """evaluate shares the input's columns where pandas copies on write, and copies the input
    otherwise: the input is unchanged either way, and both give the same verdicts."""
    from pathlib import Path

    from frontdiag.api import AnalysisOptions, run_analysis
    from frontdiag.verdicts import engine

    path = Path(__file__).resolve().parents[1] / "sample_logs" / log
    table = run_analysis(path, AnalysisOptions(rules=False)).table
    before = table.copy(deep=True)
    shared = evaluate(table, ruleset)
    pd.testing.assert_frame_equal(table, before)
    monkeypatch.setattr(engine, "copy_on_write", lambda: False)
    copied = evaluate(table, ruleset)
    pd.testing.assert_frame_equal(table, before)
    assert table.attrs == before.attrs
    pd.testing.assert_frame_equal(shared.table, copied.table)
    assert shared.table["conditions"].map(len).sum() > 0  # the rules did fire on it
