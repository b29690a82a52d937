"""Simulator geometry with known answers: projection through K, LiDAR ranges, sweep skew."""

from __future__ import annotations

import numpy as np
import pytest

from frontdiag.sim.lidar import LidarSpec, cast, sweep
from frontdiag.sim.render import AutoExposure, Intrinsics, render
from frontdiag.sim.run import CAM_XYZ, camera_T
from frontdiag.sim.world import World


def _square_world(centre: np.ndarray, half: float = 0.05) -> World:
    """A white square facing -x centred on ``centre``, in front of a dark wall."""
    w = World(background=0.0)
    tex = np.full((40, 40), 255, np.uint8)
    cx, cy, cz = centre
    # eu = -y (left to right as seen from -x), ev = -z (rows downwards)
    w.quad([cx, cy + half, cz + half], [0, -1, 0], [0, 0, -1], 2 * half, 2 * half, tex)
    w.quad([cx + 5, 20, 10], [0, -1, 0], [0, 0, -1], 40, 20, np.full((8, 8), 10, np.uint8))
    return w


@pytest.mark.parametrize("centre", [(5.25, 0.5, 1.3), (3.25, -0.8, 0.6), (8.25, 0.0, 1.1)])
def test_point_projects_where_K_says(centre: tuple[float, float, float]) -> None:
    intr = Intrinsics.from_hfov(320, 240, 70.0)
    world = _square_world(np.array(centre))
    img, sid = render(world, intr, camera_T((0.0, 0.0, 0.0, 0.0)))
    mask = sid == 0
    assert mask.sum() > 4
    ys, xs = np.nonzero(mask)
    # camera at CAM_XYZ looking along +x: X_c = -(y), Y_c = -(z - h), Z_c = x - x_cam
    X, Y, Z = -(centre[1] - CAM_XYZ[1]), -(centre[2] - CAM_XYZ[2]), centre[0] - CAM_XYZ[0]
    u = intr.fx * X / Z + intr.cx
    v = intr.fy * Y / Z + intr.cy
    assert xs.mean() == pytest.approx(u, abs=0.35)
    assert ys.mean() == pytest.approx(v, abs=0.35)
    assert img[mask].mean() == pytest.approx(1.0, abs=0.02)  # white paper, normal lights


def test_pan_rotates_about_the_optical_centre() -> None:
    a = camera_T((1.0, 2.0, 0.3, 0.0))
    b = camera_T((1.0, 2.0, 0.3, 0.4))
    np.testing.assert_allclose(a[:3, 3], b[:3, 3], atol=1e-12)
    assert not np.allclose(a[:3, :3], b[:3, :3])


def test_occlusion_keeps_the_nearer_surface() -> None:
    intr = Intrinsics.from_hfov(64, 48)
    w = World(background=0.0)
    w.quad([10, 5, 5], [0, -1, 0], [0, 0, -1], 10, 10, np.full((4, 4), 50, np.uint8))
    w.quad([5, 5, 5], [0, -1, 0], [0, 0, -1], 10, 10, np.full((4, 4), 200, np.uint8))
    _, sid = render(w, intr, camera_T((0.0, 0.0, 0.0, 0.0)))
    assert (sid == 1).all()


def _walls() -> World:
    w = World()
    tex = np.full((8, 8), 128, np.uint8)
    w.quad([10, 30, 10], [0, -1, 0], [0, 0, -1], 60, 20, tex)   # front wall, x = 10
    w.quad([-10, -30, 10], [0, 1, 0], [0, 0, -1], 60, 20, tex)  # back wall, x = -10
    return w


def test_lidar_ray_hits_wall_at_known_range() -> None:
    w = _walls()
    o = np.array([[0.0, 0.0, 1.5], [0.0, 0.0, 1.5], [2.0, 1.0, 1.5]])
    d = np.array([[1.0, 0, 0], [np.cos(0.3), np.sin(0.3), 0], [-1.0, 0, 0]])
    r, refl = cast(w, o, d, max_range=100.0)
    np.testing.assert_allclose(r, [10.0, 10.0 / np.cos(0.3), 12.0], atol=1e-9)
    assert (refl > 0).all()


def test_sweep_applies_motion_during_the_sweep() -> None:
    """Moving +x at 5 m/s: the column facing forward fires first, the one facing back 50 ms
    later, 0.25 m further on; each point is in the sensor frame of its own instant."""
    w = _walls()
    spec = LidarSpec(beams=16, columns=360, range_noise=0.0)

    def pose(dt: float) -> np.ndarray:
        T = np.eye(4)
        T[:3, 3] = (5.0 * dt, 0.0, 1.5)
        return T

    pts = sweep(w, spec, pose, np.random.default_rng(0))
    el = spec.elevations()
    ring = int(np.argmin(np.abs(el)))  # the beam closest to horizontal
    sel = pts["ring"] == ring
    x, y, t = pts["x"][sel], pts["y"][sel], pts["time"][sel]
    fwd = np.argmin(np.abs(np.arctan2(y, x)))
    back = np.argmin(np.abs(np.abs(np.arctan2(y, x)) - np.pi))
    cos_el = np.cos(el[ring])
    assert t[fwd] == pytest.approx(0.0, abs=1e-6)
    assert x[fwd] == pytest.approx(10.0, abs=1e-3)
    assert t[back] == pytest.approx(0.05, abs=1e-3)
    assert x[back] == pytest.approx(-(10.0 + 5.0 * t[back]), abs=1e-3)
    assert pts["ring"].dtype == np.uint16 and pts["time"].dtype == np.float32
    assert np.isclose(cos_el, 1.0, atol=0.01)


def test_auto_exposure_steps_only_outside_its_window() -> None:
    ae = AutoExposure(target=100.0, deadband=0.15, step=0.2)
    assert not ae.update(110.0)
    assert ae.update(120.0) and ae.gain == pytest.approx(0.8)
    assert not ae.update(120.0 * 0.8)  # one step lands inside the window: no hunting
    off = AutoExposure(enabled=False)
    assert not off.update(250.0) and off.gain == 1.0
