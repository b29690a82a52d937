"""Closed forms behind the latency budget: the arithmetic a frontend engineer does on a whiteboard.

Every function is pure and cheap; the budget model composes them with a target's coefficients.
"""

from __future__ import annotations

import math

#: Bytes per descriptor for the descriptors whose bandwidth the budget reports.
DESCRIPTOR_BYTES: dict[str, int] = {
    "orb": 32,  # 256-bit BRIEF
    "sift": 128,  # 128 x uint8
    "xfeat": 256,  # 64 x float32
    "superpoint-f16": 512,  # 256 x float16
    "superpoint-f32": 1024,  # 256 x float32
}


def pyramid_factor(levels: int, scale: float) -> float:
    """Total pyramid area over the base image area: 1 + a + ... + a^(levels-1), a = 1/scale².

    8 levels at scale 1.2 give 3.096 (the reference figures rounds it to 3.10).
    """
    if levels < 1 or scale <= 1.0:
        raise ValueError("a pyramid needs at least one level and a scale factor above 1")
    a = 1.0 / (scale * scale)
    return (1.0 - a**levels) / (1.0 - a)


def pyramid_pixels(width: int, height: int, levels: int, scale: float) -> float:
    """Pixels the detector touches per frame across all pyramid levels."""
    return width * height * pyramid_factor(levels, scale)


def guided_candidates(features: int, radius_px: float, width: int, height: int) -> float:
    """Expected keypoints inside a circular search window of radius r: n·πr²/(W·H).

    1000 features on 1280×720 with r = 25 px give 2.13 candidates per query.
    """
    return features * math.pi * radius_px**2 / (width * height)


def ransac_iterations(inlier_ratio: float, sample_size: int, confidence: float) -> int:
    """N = ln(1−p) / ln(1−w^s), rounded up: iterations for a clean minimal sample with prob. p."""
    if not 0.0 < inlier_ratio <= 1.0:
        raise ValueError(f"inlier ratio must be in (0, 1], got {inlier_ratio}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    clean = inlier_ratio**sample_size
    if clean >= 1.0:
        return 1
    return max(1, math.ceil(math.log(1.0 - confidence) / math.log(1.0 - clean) - 1e-9))


def ransac_ms(iterations: int, solve_us: float, residuals: int, residual_ns: float) -> float:
    """T = N × (T_solve + M × T_residual), in milliseconds."""
    return iterations * (solve_us * 1e-3 + residuals * residual_ns * 1e-6)


def descriptor_bandwidth_mb_s(features: int, rate_hz: float, descriptor: str = "orb") -> float:
    """Sustained descriptor traffic in MB/s (decimal megabytes), e.g. ORB 1000 kp at 30 Hz: 0.96."""
    return features * DESCRIPTOR_BYTES[descriptor] * rate_hz / 1e6


def image_bandwidth_mb_s(width: int, height: int, rate_hz: float, bytes_per_px: int = 1) -> float:
    """Raw image traffic in MB/s: 1280×720 mono at 30 Hz is 27.6 MB/s."""
    return width * height * bytes_per_px * rate_hz / 1e6


def failed_frames_per_minute(success_rate: float, rate_hz: float) -> float:
    """Frames per minute that fail at a given per-frame success rate: 99 % at 30 Hz is 18."""
    return (1.0 - success_rate) * rate_hz * 60.0


def deskew_spread_m(speed_m_s: float, sweep_s: float) -> float:
    """World-frame distance between the first and last point of one sweep (1.5 m/s, 0.1 s: 0.15 m)."""
    return speed_m_s * sweep_s


def nlogn(n: float) -> float:
    """n·log2(n), the operation count of a KD-tree build (20,000 points: ~286,000)."""
    return n * math.log2(n) if n > 1 else 0.0
