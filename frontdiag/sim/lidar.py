"""A spinning multi-beam LiDAR ray-cast against the same world the camera sees.

Beams are spread evenly over the vertical field of view (±15° for up to 32 beams, like a
VLP-16/32; ±22.5° above, like a 128-beam Ouster), columns evenly over 360°. Column ``k`` fires
at ``k / columns`` of the sweep, from wherever the sensor is at that instant, and its points are
expressed in the sensor frame *of that instant* — exactly the skew a driver publishes and a
frontend must deskew with the per-point ``time`` field (seconds after the header stamp).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from frontdiag.sim.world import World


@dataclass(frozen=True)
class LidarSpec:
    beams: int = 16
    columns: int = 1024
    rate_hz: float = 10.0
    max_range: float = 40.0
    min_range: float = 0.3
    range_noise: float = 0.01

    @property
    def vfov_deg(self) -> float:
        return 30.0 if self.beams <= 32 else 45.0

    def elevations(self) -> np.ndarray:
        half = np.radians(self.vfov_deg / 2.0)
        return np.linspace(-half, half, self.beams)


def cast(world: World, origins: np.ndarray, dirs: np.ndarray, max_range: float,
         min_range: float = 0.0, azimuth: np.ndarray | None = None
         ) -> tuple[np.ndarray, np.ndarray]:
    """Ray-cast rays (N,3 origins, N,3 unit directions) against every surface.

    Returns ``(range, reflectivity)``; ``range`` is ``inf`` where nothing is hit within
    ``max_range``. ``azimuth`` (N, sorted ascending in [0, 2π), in the world frame) lets each
    surface test only the rays whose azimuth falls in the sector it subtends, which is what
    makes a hall of two thousand carton faces affordable.
    """
    n = len(dirs)
    best = np.full(n, np.inf)
    refl = np.zeros(n)
    if n == 0 or not world.surfaces:
        return best, refl
    sa = world.surface_arrays()
    centre = origins.mean(axis=0)
    spread = float(np.linalg.norm(origins - centre, axis=1).max())
    rel = sa["corners"] - centre  # (S, 4, 3)
    # distance from the sweep centre to each rectangle (clamped projection)
    d0 = centre - sa["origin"]
    s_ = np.clip((d0 * sa["eu"]).sum(1), 0, sa["size"][:, 0])
    q_ = np.clip((d0 * sa["ev"]).sum(1), 0, sa["size"][:, 1])
    closest = sa["origin"] + sa["eu"] * s_[:, None] + sa["ev"] * q_[:, None]
    dist = np.linalg.norm(closest - centre, axis=1)
    in_range = dist - spread <= max_range
    # one-sided faces seen from behind by the whole sweep are skipped
    back = ((centre - sa["corners"].mean(1)) * sa["facing"]).sum(1) < -spread
    cand = np.nonzero(in_range & ~back)[0]
    for si in cand:
        if azimuth is not None and dist[si] > 3 * spread + 0.5:
            a = np.arctan2(rel[si, :, 1], rel[si, :, 0])
            a = np.unwrap(a)
            lo, hi = a.min(), a.max()
            if hi - lo < np.pi:
                pad = np.arcsin(min(1.0, (spread + 1e-3) / dist[si]))
                lo, hi = (lo - pad) % (2 * np.pi), (hi + pad) % (2 * np.pi)
                i0, i1 = np.searchsorted(azimuth, lo), np.searchsorted(azimuth, hi)
                idx = (np.arange(i0, i1) if i0 <= i1
                       else np.concatenate([np.arange(i0, n), np.arange(0, i1)]))
            else:
                idx = np.arange(n)
        else:
            idx = np.arange(n)
        if len(idx) == 0:
            continue
        nrm = sa["normal"][si]
        o_s = sa["origin"][si]
        denom = dirs[idx] @ nrm
        num = (o_s - origins[idx]) @ nrm
        with np.errstate(divide="ignore", invalid="ignore"):
            t = num / denom
        ok = (np.abs(denom) > 1e-9) & (t > min_range) & (t < best[idx]) & (t <= max_range)
        if not ok.any():
            continue
        idx, t = idx[ok], t[ok]
        hit = origins[idx] + dirs[idx] * t[:, None] - o_s
        sv = hit @ sa["eu"][si]
        qv = hit @ sa["ev"][si]
        w, h = sa["size"][si]
        inside = (sv >= 0) & (sv <= w) & (qv >= 0) & (qv <= h)
        idx = idx[inside]
        best[idx] = t[inside]
        refl[idx] = sa["refl"][si]
    return best, refl


def sweep(world: World, spec: LidarSpec, pose_at: Callable[[float], np.ndarray],
          rng: np.random.Generator) -> dict[str, np.ndarray]:
    """One 360° sweep starting at time 0 (relative), ``pose_at(dt)`` -> 4x4 sensor pose.

    Returns per-point arrays ``x, y, z, intensity, ring, time`` (sensor frame at each point's
    own time), misses dropped.
    """
    el = spec.elevations()
    cols = np.arange(spec.columns)
    az = 2.0 * np.pi * cols / spec.columns
    dt = cols / (spec.columns * spec.rate_hz)
    # local ray directions, (columns, beams, 3)
    ce, se = np.cos(el), np.sin(el)
    d_loc = np.stack([np.cos(az)[:, None] * ce[None, :], np.sin(az)[:, None] * ce[None, :],
                      np.broadcast_to(se[None, :], (spec.columns, spec.beams))], axis=-1)
    # sensor pose per column: interpolate between a few poses across the sweep
    knots = np.linspace(0.0, dt[-1] if len(dt) else 0.0, 5)
    poses = np.stack([pose_at(float(k)) for k in knots])
    origins_k = poses[:, :3, 3]
    yaw_k = np.unwrap(np.arctan2(poses[:, 1, 0], poses[:, 0, 0]))
    ox = np.interp(dt, knots, origins_k[:, 0])
    oy = np.interp(dt, knots, origins_k[:, 1])
    oz = np.interp(dt, knots, origins_k[:, 2])
    yaw = np.interp(dt, knots, yaw_k)
    cy, sy = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    dw = np.stack([cy * d_loc[..., 0] - sy * d_loc[..., 1],
                   sy * d_loc[..., 0] + cy * d_loc[..., 1], d_loc[..., 2]], axis=-1)
    origins = np.broadcast_to(np.stack([ox, oy, oz], axis=1)[:, None, :], dw.shape)
    az_w = np.mod(np.arctan2(dw[..., 1], dw[..., 0]), 2 * np.pi).reshape(-1)
    order = np.argsort(az_w, kind="stable")
    o_flat = origins.reshape(-1, 3)[order]
    d_flat = dw.reshape(-1, 3)[order]
    r_sorted, refl_sorted = cast(world, o_flat, d_flat, spec.max_range, spec.min_range,
                                 azimuth=az_w[order])
    rng_m = np.empty_like(r_sorted)
    refl = np.empty_like(refl_sorted)
    rng_m[order] = r_sorted
    refl[order] = refl_sorted
    hit = np.isfinite(rng_m)
    r = np.where(hit, rng_m + spec.range_noise * rng.standard_normal(rng_m.shape), 0.0)
    pts = d_loc.reshape(-1, 3) * r[:, None]
    ring = np.broadcast_to(np.arange(spec.beams)[None, :], (spec.columns, spec.beams)).reshape(-1)
    tt = np.broadcast_to(dt[:, None], (spec.columns, spec.beams)).reshape(-1)
    inten = np.clip(255.0 * refl * np.minimum(1.0, 10.0 / np.maximum(rng_m, 1e-3)) ** 0.5
                    + rng.normal(0, 2.0, r.shape), 0, 255)
    return {"x": pts[hit, 0].astype(np.float32), "y": pts[hit, 1].astype(np.float32),
            "z": pts[hit, 2].astype(np.float32), "intensity": inten[hit].astype(np.float32),
            "ring": ring[hit].astype(np.uint16), "time": tt[hit].astype(np.float32)}
