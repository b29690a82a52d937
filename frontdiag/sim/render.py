"""Pinhole rendering of a :class:`~frontdiag.sim.world.World` and a simple camera model.

Each tile is a textured plane, so image and texture are related by a homography: the tile is
drawn with ``cv2.warpPerspective`` into the bounding box of its projected (near-plane-clipped)
outline, and its inverse depth, which is an affine function of the pixel coordinates for a plane,
drives a z-buffer. That keeps a 640x480 frame in a few tens of milliseconds on one core.

Conventions: optical frame x right, y down, z forward; pixel centres at integer coordinates (as
in OpenCV), so a camera-frame point ``(X, Y, Z)`` lands at ``(fx X/Z + cx, fy Y/Z + cy)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from frontdiag.sim.world import World

NEAR = 0.05


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics for a ``width`` x ``height`` image (no distortion)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def from_hfov(cls, width: int, height: int, hfov_deg: float = 70.0) -> Intrinsics:
        f = (width / 2.0) / np.tan(np.radians(hfov_deg) / 2.0)
        return cls(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0)

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    def project(self, p_cam: np.ndarray) -> np.ndarray:
        """Project camera-frame points (N, 3) to pixels (N, 2)."""
        p = np.atleast_2d(p_cam)
        return np.stack([self.fx * p[:, 0] / p[:, 2] + self.cx,
                         self.fy * p[:, 1] / p[:, 2] + self.cy], axis=1)


def _clip_near(pts: np.ndarray, near: float) -> np.ndarray:
    """Sutherland-Hodgman clip of a polygon (N, 3) against z >= near."""
    out = []
    n = len(pts)
    for i in range(n):
        a, b = pts[i], pts[(i + 1) % n]
        ina, inb = a[2] >= near, b[2] >= near
        if ina:
            out.append(a)
        if ina != inb:
            t = (near - a[2]) / (b[2] - a[2])
            out.append(a + t * (b - a))
    return np.array(out) if out else np.zeros((0, 3))


def render(world: World, intr: Intrinsics, T_wc: np.ndarray, *, lights: float = 1.0
           ) -> tuple[np.ndarray, np.ndarray]:
    """Render scene radiance seen from camera pose ``T_wc`` (4x4, optical frame -> world).

    Returns ``(radiance, surface_id)``: float32 radiance (1.0 = white paper under the normal
    lights) and int32 index into ``world.surfaces`` per pixel (-1 where nothing was hit).
    ``lights`` scales every non-emissive surface (0.03 = lights out).
    """
    W, H = intr.width, intr.height
    R_cw = T_wc[:3, :3].T
    C = T_wc[:3, 3]
    img = np.full((H, W), world.background * lights, np.float32)
    zbuf = np.zeros((H, W), np.float32)  # inverse depth; 0 = infinitely far
    sid = np.full((H, W), -1, np.int32)
    K = intr.K
    index = {id(s): i for i, s in enumerate(world.surfaces)}
    tiles = world.tiles
    if not tiles:
        return img, sid
    arr = world.tile_arrays()
    # vectorised culling: behind the camera, outside one side of the frustum, back faces
    pcs = (arr["corners"] - C) @ R_cw.T
    xz, yz, zc = pcs[..., 0] * intr.fx, pcs[..., 1] * intr.fy, pcs[..., 2]
    out = ((zc < NEAR).all(1) | (xz < -intr.cx * zc - 1e-9).all(1)
           | (xz > (W - intr.cx) * zc).all(1) | (yz < -intr.cy * zc).all(1)
           | (yz > (H - intr.cy) * zc).all(1)
           | (((C - arr["centre"]) * arr["facing"]).sum(1) < 0))
    # near to far, so the z-test rejects most occluded pixels before any warping
    cand = np.nonzero(~out)[0]
    cand = cand[np.argsort(np.linalg.norm(arr["centre"][cand] - C, axis=1))]
    # project the tiles entirely in front of the near plane all at once
    front = (pcs[cand, :, 2] >= NEAR).all(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        uv_all = np.stack([intr.fx * pcs[cand, :, 0] / pcs[cand, :, 2] + intr.cx,
                           intr.fy * pcs[cand, :, 1] / pcs[cand, :, 2] + intr.cy], axis=-1)
    for k, ti in enumerate(cand):
        tile = tiles[ti]
        surf = tile.surface
        o = tile.origin
        if front[k]:
            poly = pcs[ti]
            uv = uv_all[k]
        else:
            poly = _clip_near(pcs[ti], NEAR)
            if len(poly) < 3:
                continue
            uv = intr.project(poly)
        x0 = max(0, int(np.floor(uv[:, 0].min())))
        x1 = min(W, int(np.ceil(uv[:, 0].max())) + 1)
        y0 = max(0, int(np.floor(uv[:, 1].min())))
        y1 = min(H, int(np.ceil(uv[:, 1].max())) + 1)
        if x1 <= x0 or y1 <= y0:
            continue
        bw, bh = x1 - x0, y1 - y0
        mask = np.zeros((bh, bw), np.uint8)
        shift = 4
        pts = np.round((uv - [x0, y0]) * (1 << shift)).astype(np.int32)
        cv2.fillConvexPoly(mask, pts, 1, lineType=cv2.LINE_8, shift=shift)
        # inverse depth of the plane n.X = d (camera frame) is affine in the pixel coordinates
        n_c = R_cw @ surf.normal
        p0c = (o - C) @ R_cw.T
        d = float(n_c @ p0c)
        if abs(d) < 1e-9:
            continue  # seen edge-on
        xs = (np.arange(x0, x1, dtype=np.float32) - intr.cx) / intr.fx
        ys = (np.arange(y0, y1, dtype=np.float32) - intr.cy) / intr.fy
        invz = (np.float32(n_c[0] / d) * xs[None, :] + np.float32(n_c[1] / d) * ys[:, None]
                + np.float32(n_c[2] / d))
        zb = zbuf[y0:y1, x0:x1]
        sel = (mask > 0) & (invz > zb)
        if not sel.any():
            continue
        # mip level from the texel footprint at a representative depth
        zs = poly[:, 2]
        z_rep = min(float(np.sqrt(zs.min() * zs.max())), 2.0 * float(zs.min()))
        footprint = surf.ppm * z_rep / intr.fx
        lvl = int(np.clip(np.floor(np.log2(max(footprint, 1e-6))), 0, 12))
        tex = tile.level(lvl)
        scale_u = tile.width / tex.shape[1]
        scale_v = tile.height / tex.shape[0]
        M = np.column_stack([R_cw @ surf.eu * scale_u, R_cw @ surf.ev * scale_v, p0c])
        # texel centres: texel (i, j) covers [i, i+1) * scale; shift by half a texel
        M[:, 2] += 0.5 * (M[:, 0] + M[:, 1])
        Hm = np.array([[1, 0, -x0], [0, 1, -y0], [0, 0, 1.0]]) @ K @ M
        warped = cv2.warpPerspective(tex, Hm, (bw, bh), flags=cv2.INTER_LINEAR,
                                     borderMode=cv2.BORDER_REPLICATE)
        gain = surf.radiance * (1.0 if surf.emissive else lights) / 255.0
        img[y0:y1, x0:x1][sel] = warped[sel].astype(np.float32) * np.float32(gain)
        zb[sel] = invz[sel]
        sid[y0:y1, x0:x1][sel] = index[id(surf)]
    return img, sid


@dataclass
class AutoExposure:
    """A stepping auto-exposure controller, like the ones that upset direct VO at doorways.

    The gain changes only when the frame mean leaves ``target * (1 +- deadband)``, and then by a
    whole ``step`` (0.2: -20 % / +25 %; the window is wider than one step, so it never
    hunts), applied to the next frame. ``enabled=False``
    keeps the gain fixed.
    """

    target: float = 110.0
    deadband: float = 0.15
    step: float = 0.2
    gain: float = 1.0
    min_gain: float = 0.1
    max_gain: float = 8.0
    enabled: bool = True

    def update(self, mean_level: float) -> bool:
        """Feed this frame's mean grey level; returns True if the gain steps for the next."""
        if not self.enabled:
            return False
        if mean_level > self.target * (1 + self.deadband) and self.gain > self.min_gain:
            self.gain = max(self.min_gain, self.gain * (1 - self.step))
            return True
        if mean_level < self.target / (1 + self.deadband) and self.gain < self.max_gain:
            self.gain = min(self.max_gain, self.gain / (1 - self.step))
            return True
        return False


def expose(radiance: np.ndarray, gain: float, rng: np.random.Generator, *,
           read_noise: float = 1.5, shot: float = 0.025) -> np.ndarray:
    """Radiance -> 8-bit image: gain, photon shot noise, read noise, clipping."""
    sig = radiance * np.float32(gain * 200.0)
    noise_sd = np.sqrt(np.float32(read_noise) ** 2 + np.float32(shot) * np.maximum(sig, 0))
    noisy = sig + noise_sd * rng.standard_normal(sig.shape, dtype=np.float32)
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
