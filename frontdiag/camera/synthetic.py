"""Tiny renderer of textured planar scenes with known camera motion, for tests and benchmarks.

Each plane is a textured rectangle in the world; a view is rendered by warping every texture
through the plane-induced homography K [R a, R b, R o + t] and painting far planes first.
Geometry is exact (no approximation beyond bilinear resampling), so recovered motion can be
compared with the truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


def texture(h: int, w: int, seed: int, shapes: int = 400) -> np.ndarray:
    """A natural-looking 8-bit texture: smooth shading, random shapes, a little grain."""
    rng = np.random.default_rng(seed)
    low = rng.integers(40, 216, (max(h // 64, 2), max(w // 64, 2)), dtype=np.uint8)
    img = cv2.resize(low, (w, h), interpolation=cv2.INTER_CUBIC)
    for _ in range(shapes):
        x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
        s = int(rng.integers(4, max(min(h, w) // 12, 6)))
        col = int(rng.integers(0, 256))
        kind = int(rng.integers(0, 3))
        if kind == 0:
            cv2.rectangle(img, (x, y), (x + s, y + int(rng.integers(4, 2 * s))), col, -1)
        elif kind == 1:
            cv2.circle(img, (x, y), s // 2, col, -1, lineType=cv2.LINE_AA)
        else:
            pts = (rng.integers(-s, s, (3, 2)) + np.array([x, y])).astype(np.int32)
            cv2.fillConvexPoly(img, pts, col, lineType=cv2.LINE_AA)
    img = cv2.GaussianBlur(img, (0, 0), 0.8)
    grain = rng.normal(0, 2.0, img.shape)
    return np.clip(img + grain, 0, 255).astype(np.uint8)


@dataclass(frozen=True)
class Plane:
    """Rectangle origin + s*a + t*b for s in [0, tex width], t in [0, tex height] (metres/pixel)."""

    origin: np.ndarray
    a: np.ndarray
    b: np.ndarray
    tex: np.ndarray

    def depth_key(self, R: np.ndarray, t: np.ndarray) -> float:
        h, w = self.tex.shape
        c = self.origin + self.a * (w / 2) + self.b * (h / 2)
        return float((R @ c + t)[2])


def look_K(width: int, height: int, hfov_deg: float = 70.0) -> np.ndarray:
    f = (width / 2) / np.tan(np.radians(hfov_deg) / 2)
    return np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1.0]])


def rot(axis: tuple[float, float, float], deg: float) -> np.ndarray:
    v = np.asarray(axis, float)
    v = v / np.linalg.norm(v) * np.radians(deg)
    R, _ = cv2.Rodrigues(v)
    return R


def render(planes: list[Plane], K: np.ndarray, R: np.ndarray, t: np.ndarray,
           size: tuple[int, int], background: int = 0) -> np.ndarray:
    """Grey image of ``planes`` seen by the camera x_cam = R X + t (all planes in front)."""
    w, h = size
    out = np.full((h, w), background, np.uint8)
    for p in sorted(planes, key=lambda q: -q.depth_key(R, t)):
        H = K @ np.column_stack([R @ p.a, R @ p.b, R @ p.origin + t])
        warped = cv2.warpPerspective(p.tex, H, (w, h), flags=cv2.INTER_LINEAR)
        mask = cv2.warpPerspective(np.full(p.tex.shape, 255, np.uint8), H, (w, h),
                                   flags=cv2.INTER_NEAREST)
        np.copyto(out, warped, where=mask > 0)
    return out


def _plane(o: tuple[float, float, float], a: tuple[float, float, float],
           b: tuple[float, float, float], extent: tuple[float, float], px: float,
           seed: int) -> Plane:
    """A plane spanning ``extent`` metres along unit a and b, textured at ``px`` metres/pixel."""
    w, h = int(extent[0] / px), int(extent[1] / px)
    return Plane(np.asarray(o, float), np.asarray(a, float) * px, np.asarray(b, float) * px,
                 texture(h, w, seed))


def room(seed: int = 0, px: float = 0.006) -> list[Plane]:
    """A corridor-like box: back wall, floor, ceiling, side walls and a few boxes at many depths."""
    s = seed * 100
    return [
        _plane((-4, -2.5, 9), (1, 0, 0), (0, 1, 0), (8, 5), px, s + 1),  # back wall z=9
        _plane((-4, 1.5, 0.5), (1, 0, 0), (0, 0, 1), (8, 8.5), px, s + 2),  # floor y=1.5
        _plane((-4, -2.5, 0.5), (1, 0, 0), (0, 0, 1), (8, 8.5), px, s + 3),  # ceiling
        _plane((-3, -2.5, 0.5), (0, 0, 1), (0, 1, 0), (8.5, 5), px, s + 4),  # left wall x=-3
        _plane((3, -2.5, 9), (0, 0, -1), (0, 1, 0), (8.5, 5), px, s + 5),  # right wall x=3
        _plane((-1.6, -0.4, 3.0), (1, 0, 0), (0, 1, 0), (0.9, 1.0), px / 2, s + 6),
        _plane((0.7, 0.2, 4.0), (1, 0, 0), (0, 1, 0), (1.2, 0.9), px / 2, s + 7),
        _plane((-0.4, -1.2, 5.5), (1, 0, 0), (0, 1, 0), (1.0, 0.8), px / 2, s + 8),
    ]


def wall(seed: int = 0, z: float = 5.0, px: float = 0.006) -> list[Plane]:
    """One large textured wall at depth z: the planar degeneracy."""
    return [_plane((-6, -4, z), (1, 0, 0), (0, 1, 0), (12, 8), px, seed * 100 + 11)]


def cluster(seed: int = 0, z: float = 4.0, size_m: float = 0.5,
            center: tuple[float, float] = (-1.0, -0.3)) -> list[Plane]:
    """One small textured patch on a blank background: every feature in one place."""
    x, y = center
    return [_plane((x, y, z), (1, 0, 0), (0, 1, 0), (size_m, size_m * 0.6), 0.002,
                   seed * 100 + 21)]


def walk(n: int, size: tuple[int, int] = (1280, 720), step_deg: float = 0.15,
         step_m: float = 0.02, seed: int = 0) -> tuple[list[np.ndarray], np.ndarray]:
    """``n`` views of :func:`room` from a camera walking forward and yawing a little each
    frame (a healthy, small-motion sequence), and the intrinsics K they were rendered with."""
    K = look_K(*size)
    planes = room(seed)
    frames = []
    for k in range(n):
        R = rot((0, 1, 0), step_deg * k)
        C = np.array([0.3 * step_m * k, 0.0, step_m * k])
        frames.append(render(planes, K, R, -R @ C, size))
    return frames, K
