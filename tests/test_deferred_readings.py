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
EVERY_FRAME = CameraParams(rot_fit_he=0.0, rot_fit_parallax_deg=0.0)


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
    else:  # mostly H/E low, or parallax under the split: few frames need it
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
    # a line set lower by the caller is kept
    own = AnalysisOptions(camera_params=replace(CameraParams(), rot_fit_he=0.5))
    assert _read_intervals_for(load_ruleset(overrides=ov), own).camera_params.rot_fit_he == 0.5
