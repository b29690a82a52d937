"""A camera sliding sideways past a flat wall is a plane under translation, not a turn.

Its image motion is nearly a pure shift, which a rotation-only model reproduces at an ever
longer focal: the fit climbs to the end of the focal range searched and fits there. The
sample log ``side_wall.mcap`` (simulated: a side camera passing a wall of cartons at 3 m and
0.8 m/s, labelled planar_degeneracy by construction) is read planar with the default rules,
and as pure rotation when a fit at the edge of the range is allowed to count and the fit is not
also held to a multiple of E's own residual, which tells the slide from a turn on its own.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from frontdiag.api import AnalysisOptions, run_analysis
from frontdiag.verdicts import evaluate, load_ruleset

LOG = Path(__file__).resolve().parent.parent / "sample_logs" / "side_wall.mcap"


@pytest.fixture(scope="module")
def table():
    return run_analysis(LOG, AnalysisOptions(use_lidar=False)).table


def _frames_with(res, cond: str) -> int:
    cam = res.table[res.table["sensor"] == "camera"]
    return int(sum(cond in list(c) for c in cam["conditions"]))


def test_the_side_wall_reads_planar_not_rotation(table) -> None:
    res = evaluate(table, load_ruleset())
    cam = table[table["sensor"] == "camera"]
    # the rotation-only fits of this recording sit at the longest focal searched
    scales = cam["rot_focal_scale"].dropna().to_numpy()
    assert scales.size > 0 and np.all(scales >= 2.0 * (1 - 1e-6))
    assert _frames_with(res, "planar_degeneracy") >= 0.8 * len(cam) - 1
    assert _frames_with(res, "pure_rotation") == 0


def test_counting_a_fit_at_the_edge_of_the_range_reads_the_slide_as_rotation(table,
                                                                             tmp_path) -> None:
    # the rotation fit must also be within rot_fit_noise_ratio of E's own residual; that line
    # is lifted too, to see what the focal range alone decides
    ov = tmp_path / "edge.toml"
    ov.write_text("".join(f"[{r}]\nthreshold.rot_fit_focal_min = 0\n"
                          f"threshold.rot_fit_focal_max = 1e9\n"
                          f"threshold.rot_fit_noise_ratio = 1e9\n"
                          for r in ("FD-PLN-001", "FD-ROT-001")))
    res = evaluate(table, load_ruleset(overrides=ov))
    assert _frames_with(res, "pure_rotation") > _frames_with(res, "planar_degeneracy")


def test_es_own_residual_also_tells_the_slide_from_a_turn(table, tmp_path) -> None:
    """Without the focal range's guard, the slide's rotation fits (within the 2.45 px line at
    the longest focal) leave several times E's residual: E absorbs the translation, a rotation
    does not."""
    ov = tmp_path / "edge.toml"
    ov.write_text("".join(f"[{r}]\nthreshold.rot_fit_focal_min = 0\n"
                          f"threshold.rot_fit_focal_max = 1e9\n"
                          for r in ("FD-PLN-001", "FD-ROT-001")))
    res = evaluate(table, load_ruleset(overrides=ov))
    cam = table[table["sensor"] == "camera"]
    assert _frames_with(res, "planar_degeneracy") >= 0.8 * len(cam) - 1
    assert _frames_with(res, "pure_rotation") == 0
