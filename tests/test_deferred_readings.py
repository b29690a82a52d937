"""Readings the camera frontend takes only where they can change a verdict give the verdicts of
taking them on every frame."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from frontdiag.api import AnalysisOptions, _read_intervals_for, run_analysis
from frontdiag.camera.frontend import CameraParams
from frontdiag.verdicts import load_ruleset

SAMPLES = Path(__file__).resolve().parents[1] / "sample_logs"
EVERY_FRAME = CameraParams(rot_fit_he=0.0, rot_fit_parallax_deg=0.0, rot_fit_turn_px=0.0)


@pytest.mark.parametrize("name", ["parked_panning", "planar_approach.mcap", "healthy_loop.mcap"])
def test_the_rotation_fit_where_it_can_matter_gives_the_verdicts_of_every_frame(name: str) -> None:
    lazy = run_analysis(SAMPLES / name, AnalysisOptions())
    full = run_analysis(SAMPLES / name, AnalysisOptions(camera_params=EVERY_FRAME))
    a, b = lazy.table, full.table
    assert a["verdict"].tolist() == b["verdict"].tolist()
    assert a["conditions"].astype(str).tolist() == b["conditions"].astype(str).tolist()
    assert lazy.verdicts.episodes.equals(full.verdicts.episodes)
    taken = a["rot_only_px"].notna().to_numpy()
    # where it is taken it is the value taken on every frame
    np.testing.assert_array_equal(a["rot_only_px"].to_numpy()[taken],
                                  b["rot_only_px"].to_numpy()[taken])
    every = b["rot_only_px"].notna().sum()
    if name == "planar_approach.mcap":  # the planar quadrant throughout: every frame needs it
        assert taken.sum() == every
    elif name == "parked_panning":  # a pan: the turning intervals' upper halves need it
        assert every // 4 <= taken.sum() < every, (taken.sum(), every)
    else:  # a drive: H/E low, or parallax under the split, no sharp turn: few frames need it
        assert every >= 20 and taken.sum() <= every // 4, (taken.sum(), every)


def test_rules_set_the_rotation_fit_lines(tmp_path: Path) -> None:
    shipped = _read_intervals_for(load_ruleset(), AnalysisOptions())
    assert shipped.camera_params is None  # 0.9 and 0.3 deg: the frontend's defaults
    ov = tmp_path / "ov.toml"
    ov.write_text("[FD-ROT-001]\nthreshold.he_degenerate = 0.8\n"
                  "threshold.parallax_split_deg = 0.2\n")
    lowered = _read_intervals_for(load_ruleset(overrides=ov), AnalysisOptions())
    assert lowered.camera_params is not None
    assert (lowered.camera_params.rot_fit_he, lowered.camera_params.rot_fit_parallax_deg) == \
        (0.8, 0.2)
    ov.write_text("[FD-ROT-001]\nthreshold.rot_fit_turn_px = 4.0\n")
    turn = _read_intervals_for(load_ruleset(overrides=ov), AnalysisOptions())
    assert turn.camera_params is not None and turn.camera_params.rot_fit_turn_px == 4.0
    # a line set lower by the caller is kept
    own = AnalysisOptions(camera_params=replace(CameraParams(), rot_fit_he=0.5))
    assert _read_intervals_for(load_ruleset(overrides=ov), own).camera_params.rot_fit_he == 0.5


def _frontend_by_hand(path: Path, params: CameraParams) -> dict[int, dict[str, float]]:
    """Every row of the camera frontend driven frame by frame, with every completion applied
    to the row it names, including the row of the frame that closed the interval."""
    from frontdiag.api import resolve_intrinsics
    from frontdiag.camera.frontend import CameraFrontend
    from frontdiag.io.readers import open_recording
    from frontdiag.io.topics import choose_topics
    from frontdiag.runner import iter_camera_frames

    rows: dict[int, dict[str, float]] = {}
    with open_recording(path) as rec:
        choice = choose_topics(rec.topics)
        intr = resolve_intrinsics(rec, choice, AnalysisOptions(), [])
        front = CameraFrontend(params, intr)
        for frame in iter_camera_frames(rec, choice.camera, choice.camera_type):
            rows[frame.index] = front.process(frame)
            for f, values in front.take_updates():
                rows[f].update({k: v for k, v in values.items() if not k.startswith("ms_")})
        front.finish()
        for f, values in front.take_updates():
            rows[f].update({k: v for k, v in values.items() if not k.startswith("ms_")})
    return rows


@pytest.mark.parametrize("name", ["planar_approach.mcap", "parked_panning"])
def test_the_table_keeps_the_readings_completed_by_the_frame_that_closes_an_interval(
        name: str) -> None:
    """A keyframe is made on the frame with the most parallax of its interval; the readings
    taken when the interval closes belong to that frame's row as well."""
    params = replace(EVERY_FRAME, two_interval_px=1e6)  # every interval read two back too
    by_hand = _frontend_by_hand(SAMPLES / name, params)
    table = run_analysis(SAMPLES / name, AnalysisOptions(camera_params=params)).table
    closing = [f for f, r in by_hand.items() if r["keyframe_reason"] not in ("", "first_frame")]
    assert len(closing) >= 3
    got = table.set_index("frame")
    for col in ("rot_only_px", "h_over_e_2kf", "parallax_med_px_2kf"):
        want = np.array([by_hand[f].get(col, np.nan) for f in got.index], dtype=float)
        np.testing.assert_array_equal(got[col].to_numpy(dtype=float), want, err_msg=col)
        # and the closing frames do carry them where the frontend took them
        taken = [f for f in closing if by_hand[f].get(col, np.nan) == by_hand[f].get(col)]
        assert all(got.loc[f, col] == got.loc[f, col] for f in taken)
    assert any(by_hand[f].get("rot_only_px", np.nan) == by_hand[f].get("rot_only_px")
               for f in closing)
