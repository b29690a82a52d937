"""The derived budget lands on the reference docs/derivations.md §1 table and docs/derivations.md §6 LiDAR numbers."""

from __future__ import annotations

import dataclasses

import pytest

from frontdiag.budget.model import Workload, apply_what_if, budget, compare
from frontdiag.budget.targets import (
    available_targets,
    load_target,
    parse_target,
    target_to_toml,
)
from frontdiag.errors import ConfigError


@pytest.fixture(scope="module")
def orin():
    return load_target("orin-nano")


def test_reference_stage_table(orin) -> None:
    cam = budget(Workload(), orin).camera
    reference = {"pyramid": 2.0, "fast": 8.6, "describe": 1.8, "match": 2.6, "pnp": 0.9}
    for key, ms in reference.items():
        assert cam.stage(key).ms == pytest.approx(ms, abs=0.05), key
    # the reference cost model, not the reference table's rounded 2.2 ms
    assert cam.stage("ransac").ms == pytest.approx(2.6, abs=0.05)
    assert cam.period_ms == pytest.approx(33.33, abs=0.01)
    assert 17.5 < cam.total_ms < 19.0
    assert 0.54 <= cam.utilisation <= 0.56
    assert cam.margin_ms == pytest.approx(15, abs=0.5)
    running = [s.running_ms for s in cam.stages]
    assert running == sorted(running) and running[-1] == pytest.approx(cam.total_ms)


def test_report_derives_and_footnotes(orin) -> None:
    r = budget(Workload(), orin)
    assert r.derived["pyramid_px"] / 1e6 == pytest.approx(2.85, abs=0.005)
    assert r.derived["candidates_per_query"] == pytest.approx(2.13, abs=0.005)
    assert r.derived["ransac_iterations"] == 218
    assert r.derived["descriptor_mb_s"] == pytest.approx(0.96)
    assert any("2.2 ms" in n for n in r.footnotes)
    assert "2.85 Mpx" in r.camera.stage("pyramid").work


@pytest.mark.parametrize(("icp", "ms"), [("point-to-point", 192.0), ("point-to-plane", 48.0)])
def test_reference_lidar_budget(orin, icp: str, ms: float) -> None:
    lidar = budget(Workload(lidar_beams=128, lidar_columns=1800, lidar_rate_hz=10, icp=icp),
                   orin).lidar
    assert lidar is not None
    assert lidar.total_ms == pytest.approx(ms, abs=0.5)
    assert (lidar.total_ms > lidar.period_ms) == (icp == "point-to-point")


def test_no_lidar_unless_asked(orin) -> None:
    assert budget(Workload(), orin).lidar is None


def test_what_if_directions(orin) -> None:
    cmp = compare(Workload(), orin, ["matching=brute", "inlier-ratio=0.4", "inlier-ratio=0.7",
                                     "features=500,levels=4"])
    base = cmp.baseline.camera
    brute, w04, w07, light = (r for _, r in cmp.variants)
    assert brute.camera.stage("match").ms > base.stage("match").ms
    assert w07.derived["ransac_iterations"] < w04.derived["ransac_iterations"]
    assert w07.camera.stage("ransac").ms < w04.camera.stage("ransac").ms
    assert light.camera.total_ms < base.total_ms
    # a what-if changes only what it names
    assert brute.camera.stage("fast").ms == base.stage("fast").ms


def test_what_if_parsing() -> None:
    w, target = apply_what_if(Workload(), "camera=640x480@60, target=orin-nano")
    assert (w.width, w.height, w.rate_hz, target) == (640, 480, 60.0, "orin-nano")
    for bad in ("matching", "colour=red", "features=many", "matching=psychic", "camera=big"):
        with pytest.raises(ConfigError):
            apply_what_if(Workload(), bad)


def test_missing_coefficient_is_refused_not_invented(orin) -> None:
    with pytest.raises(ConfigError, match="solve_8pt_us"):
        budget(Workload(solver="8pt"), orin)


def test_invalid_workload() -> None:
    with pytest.raises(ConfigError):
        Workload(inlier_ratio=1.5).validate()
    with pytest.raises(ConfigError):
        Workload(scale=1.0).validate()


def test_orin_target_has_a_source_for_every_coefficient(orin) -> None:
    assert "orin-nano" in available_targets()
    assert orin.provenance == "reference"
    for c in orin.coefficients.values():
        assert c.value > 0 and c.source and c.how in ("given", "derived")
    assert orin.coefficients["fast_ns_per_px"].how == "given"
    assert orin.coefficients["resample_ns_per_px"].how == "derived"


def test_target_round_trip_and_validation(orin, tmp_path) -> None:
    text = target_to_toml(orin, "header line")
    import tomllib

    again = parse_target(tomllib.loads(text))
    assert {k: c.value for k, c in again.coefficients.items()} == pytest.approx(
        {k: c.value for k, c in orin.coefficients.items()}, rel=1e-5)
    bad = {"target": {"name": "x"}, "coefficients": {"fast_ns_per_px": {"value": 3}}}
    with pytest.raises(ConfigError, match="source"):
        parse_target(bad)
    bad["coefficients"] = {"warp_drive": {"value": 1, "source": "s"}}
    with pytest.raises(ConfigError, match="unknown coefficient"):
        parse_target(bad)
    with pytest.raises(ConfigError, match=r"available targets: .*orin-nano"):
        load_target("no-such-board")
    assert dataclasses.is_dataclass(orin)


def test_a_target_file_that_calls_its_figures_published_reads_as_reference(tmp_path) -> None:
    """Target files written before the rename say provenance = "published"; they load as the
    reference estimates they are, and the report words them so."""
    from frontdiag.budget.targets import PROVENANCE_WORDS, load_target, targets_dir

    text = (targets_dir() / "orin-nano.toml").read_text()
    old = tmp_path / "old.toml"
    old.write_text(text.replace('provenance = "reference"', 'provenance = "published"'))
    assert 'provenance = "published"' in old.read_text()
    assert load_target(str(old)).provenance == "reference"
    assert "not measured by frontdiag" in PROVENANCE_WORDS["reference"]
