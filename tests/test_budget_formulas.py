"""The numbers drill of the reference figures (docs/derivations.md) as oracles for the budget's closed forms."""

from __future__ import annotations

import pytest

from frontdiag.budget import formulas as f


def test_pyramid_area_is_a_geometric_series() -> None:
    assert round(f.pyramid_factor(8, 1.2), 2) == 3.10
    assert f.pyramid_factor(8, 1.2) == pytest.approx(3.096, abs=5e-4)
    assert f.pyramid_pixels(1280, 720, 8, 1.2) / 1e6 == pytest.approx(2.85, abs=0.005)
    assert f.pyramid_factor(1, 1.2) == 1.0


def test_guided_window_candidates() -> None:
    assert f.guided_candidates(1000, 25, 1280, 720) == pytest.approx(2.13, abs=0.005)
    # after a dropped frame the radius doubles and the candidates quadruple
    assert f.guided_candidates(1000, 50, 1280, 720) == pytest.approx(
        4 * f.guided_candidates(1000, 25, 1280, 720))


def test_descriptor_and_image_bandwidth() -> None:
    assert f.descriptor_bandwidth_mb_s(1000, 30, "orb") == pytest.approx(0.96)
    assert f.descriptor_bandwidth_mb_s(1000, 30, "superpoint-f32") == pytest.approx(30.7,
                                                                                    abs=0.05)
    assert f.image_bandwidth_mb_s(1280, 720, 30) == pytest.approx(27.6, abs=0.05)
    # float32 SuperPoint descriptors outweigh the image they came from
    assert f.descriptor_bandwidth_mb_s(1000, 30, "superpoint-f32") > f.image_bandwidth_mb_s(
        1280, 720, 30)


def test_failed_frames_per_minute() -> None:
    assert f.failed_frames_per_minute(0.99, 30) == pytest.approx(18)
    assert f.failed_frames_per_minute(0.999, 30) == pytest.approx(1.8)


@pytest.mark.parametrize(("w", "s", "p", "n"), [
    (0.4, 2, 0.99, 27),     # 2D line at 60 % outliers
    (0.5, 5, 0.999, 218),   # essential matrix at 50 % outliers
    (0.5, 5, 0.99, 146),
    (0.4, 5, 0.99, 448),
    (0.7, 5, 0.99, 26),
    (0.5, 8, 0.99, 1177),
    (0.6, 3, 0.99, 19),     # P3P in docs/derivations.md §4
])
def test_ransac_iterations(w: float, s: int, p: float, n: int) -> None:
    assert f.ransac_iterations(w, s, p) == n


def test_ransac_cost_model() -> None:
    # 218 × (10 µs + 400 × 5 ns) = 2.6 ms
    assert f.ransac_ms(218, 10.0, 400, 5.0) == pytest.approx(2.616)


def test_ransac_rejects_nonsense() -> None:
    with pytest.raises(ValueError):
        f.ransac_iterations(0.0, 5, 0.99)
    with pytest.raises(ValueError):
        f.ransac_iterations(0.5, 5, 1.0)
    assert f.ransac_iterations(1.0, 5, 0.99) == 1


def test_deskew_and_lidar_points() -> None:
    assert f.deskew_spread_m(1.5, 0.1) == pytest.approx(0.15)
    assert 128 * 1800 == 230_400
    assert f.nlogn(20_000) == pytest.approx(286_000, rel=0.002)
