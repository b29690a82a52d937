"""Synthetic LiDAR sweeps by ray casting against boxes, for tests, benchmarks and the simulator.

A scene is a list of axis-aligned boxes. A *room* box is seen from inside (the ray exits through
its walls, floor and ceiling); a *solid* box is seen from outside (shelves, pillars, pallets).
A spinning sensor fires ``beams`` lasers at fixed elevations, ``columns`` times per revolution;
column ``j`` fires at ``j / columns * period_s`` after the sweep starts, and the sensor may move
during the sweep (a body-frame twist), so the returned points carry the real motion skew that
deskewing must remove. Points are expressed, as drivers do, in the sensor frame at the instant
each one was measured.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from frontdiag.lidar.se3 import se3_exp_batch

# sensor_msgs/PointField datatypes
_PF_CODES: dict[str, int] = {
    "int8": 1, "uint8": 2, "int16": 3, "uint16": 4, "int32": 5, "uint32": 6, "float32": 7,
    "float64": 8,
}


@dataclass(frozen=True)
class Box:
    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    inside: bool = False  # True: a room seen from inside


def room(lo: Sequence[float], hi: Sequence[float]) -> Box:
    return Box(tuple(map(float, lo)), tuple(map(float, hi)), inside=True)  # type: ignore[arg-type]


def solid(lo: Sequence[float], hi: Sequence[float]) -> Box:
    return Box(tuple(map(float, lo)), tuple(map(float, hi)), inside=False)  # type: ignore[arg-type]


def corridor_scene(length: float = 400.0, width: float = 3.0, height: float = 3.0) -> list[Box]:
    """A straight corridor along x, open beyond the sensor's range at both ends."""
    return [room((-length / 2, -width / 2, -1.0), (length / 2, width / 2, height - 1.0))]


def hall_scene() -> list[Box]:
    """A 24 x 16 x 6 m hall with a few pillars and crates: every direction is constrained."""
    return [
        room((-10.0, -7.0, -1.0), (14.0, 9.0, 5.0)),
        solid((3.0, 2.0, -1.0), (3.6, 2.6, 5.0)),
        solid((3.0, -4.0, -1.0), (3.6, -3.4, 5.0)),
        solid((-4.0, 3.0, -1.0), (-3.4, 3.6, 5.0)),
        solid((7.0, -1.0, -1.0), (8.5, 0.5, 0.2)),
        solid((-6.0, -5.0, -1.0), (-4.8, -3.5, 0.5)),
    ]


def warehouse_scene() -> list[Box]:
    """A 60 x 40 x 10 m warehouse with rows of racking and a few pallets."""
    boxes = [room((-30.0, -20.0, -1.5), (30.0, 20.0, 8.5))]
    for x0 in (-24.0, -14.0, 6.0, 16.0):
        for y0 in (-16.0, -4.0, 8.0):
            boxes.append(solid((x0, y0, -1.5), (x0 + 6.0, y0 + 1.2, 4.5)))
    rng = np.random.default_rng(7)  # pallets and crates on the floor: fixed clutter
    for _ in range(40):
        x, y = rng.uniform(-28.0, 28.0), rng.uniform(-18.0, 18.0)
        sx, sy, sz = rng.uniform(0.6, 1.6), rng.uniform(0.6, 1.6), rng.uniform(0.3, 2.0)
        boxes.append(solid((x, y, -1.5), (x + sx, y + sy, -1.5 + sz)))
    return boxes


def cast(scene: Sequence[Box], origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Range along each unit ray to the first surface (inf when nothing is hit)."""
    best = np.full(len(dirs), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / dirs
        for box in scene:
            t1 = (np.asarray(box.lo) - origins) * inv
            t2 = (np.asarray(box.hi) - origins) * inv
            tnear = np.minimum(t1, t2).max(axis=1)
            tfar = np.maximum(t1, t2).min(axis=1)
            if box.inside:
                hit = np.where(tfar > 0, tfar, np.inf)
            else:
                hit = np.where((tnear > 0) & (tnear <= tfar), tnear, np.inf)
            np.minimum(best, hit, out=best)
    return best


def beam_elevations(beams: int, fov_deg: tuple[float, float] = (-15.0, 15.0)) -> np.ndarray:
    return np.deg2rad(np.linspace(fov_deg[0], fov_deg[1], beams))


def spinning_scan(scene: Sequence[Box], *, beams: int = 16, columns: int = 360,
                  fov_deg: tuple[float, float] = (-15.0, 15.0), period_s: float = 0.1,
                  pose0: np.ndarray | None = None,
                  twist: Sequence[float] | np.ndarray | None = None, range_noise_m: float = 0.01, max_range_m: float = 100.0,
                  seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """One organised sweep: ``xyz`` (beams, columns, 3) with NaN for no return, and per-point
    time in seconds since the sweep start (beams, columns).

    ``pose0`` is the sensor pose in the scene at the sweep start; ``twist`` = (wx, wy, wz, vx, vy,
    vz) is its constant body-frame velocity (rad/s, m/s) during the sweep.
    """
    rng = np.random.default_rng(seed)
    pose0 = np.eye(4) if pose0 is None else np.asarray(pose0, dtype=np.float64)
    elev = beam_elevations(beams, fov_deg)
    az = 2.0 * np.pi * np.arange(columns) / columns
    t_col = az / (2.0 * np.pi) * period_s
    ce, se = np.cos(elev)[:, None], np.sin(elev)[:, None]
    d_s = np.stack([ce * np.cos(az)[None, :], ce * np.sin(az)[None, :],
                    np.broadcast_to(se, (beams, columns))], axis=-1)  # sensor-frame directions
    # sensor pose at each column's firing time
    xi = np.zeros(6) if twist is None else np.asarray(twist, dtype=np.float64)
    T_col = pose0[None] @ se3_exp_batch(t_col[:, None] * xi[None, :])  # (columns, 4, 4)
    R_col, t_col_w = T_col[:, :3, :3], T_col[:, :3, 3]
    d_w = np.einsum("cij,bcj->bci", R_col, d_s).reshape(-1, 3)
    o_w = np.broadcast_to(t_col_w[None], (beams, columns, 3)).reshape(-1, 3)
    rng_m = cast(scene, o_w, d_w).reshape(beams, columns)
    rng_m = rng_m + rng.normal(0.0, range_noise_m, size=rng_m.shape)
    valid = np.isfinite(rng_m) & (rng_m <= max_range_m) & (rng_m > 0)
    xyz = np.where(valid[..., None], d_s * rng_m[..., None], np.nan)
    times = np.broadcast_to(t_col[None, :], (beams, columns)).copy()
    return xyz, times


def planar_scan(scene: Sequence[Box], *, n_rays: int = 1081, fov_deg: float = 270.0,
                period_s: float = 0.025, pose0: np.ndarray | None = None,
                twist: Sequence[float] | np.ndarray | None = None, range_noise_m: float = 0.005,
                range_max_m: float = 30.0, seed: int = 0) -> dict:
    """Fields of a ``sensor_msgs/LaserScan`` (ranges inf where nothing is hit) from one sweep of a
    2D scanner at height 0."""
    rng = np.random.default_rng(seed)
    pose0 = np.eye(4) if pose0 is None else np.asarray(pose0, dtype=np.float64)
    half = np.deg2rad(fov_deg) / 2.0
    inc = 2.0 * half / (n_rays - 1)
    ang = -half + inc * np.arange(n_rays)
    t_inc = period_s / n_rays
    xi = np.zeros(6) if twist is None else np.asarray(twist, dtype=np.float64)
    T = pose0[None] @ se3_exp_batch((t_inc * np.arange(n_rays))[:, None] * xi[None, :])
    d_s = np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], axis=1)
    d_w = np.einsum("nij,nj->ni", T[:, :3, :3], d_s)
    r = cast(scene, T[:, :3, 3], d_w) + rng.normal(0.0, range_noise_m, size=n_rays)
    r = np.where(r <= range_max_m, r, np.inf).astype(np.float32)
    return {"angle_min": -half, "angle_max": half, "angle_increment": inc,
            "time_increment": t_inc, "scan_time": period_s, "range_min": 0.05,
            "range_max": range_max_m, "ranges": r, "intensities": np.zeros(0, np.float32)}


def pointcloud2_dict(columns: Mapping[str, np.ndarray], *, t_ns: int, frame_id: str = "lidar",
                     height: int = 1, bigendian: bool = False, pad_to: int = 0,
                     row_pad: int = 0) -> dict:
    """Fields of a ``sensor_msgs/PointCloud2`` holding ``columns`` (name -> 1-D array; the array's
    dtype is the field's datatype), packed in the given order.

    ``height`` > 1 makes an organised cloud; ``pad_to`` pads each point to that many bytes;
    ``row_pad`` appends bytes to every row, so ``row_step`` > ``width * point_step``.
    """
    order: Literal[">", "<"] = ">" if bigendian else "<"
    names, formats, offsets, fields = [], [], [], []
    off = 0
    n = None
    for name, arr in columns.items():
        arr = np.asarray(arr)
        n = len(arr) if n is None else n
        if len(arr) != n:
            raise ValueError("all columns must have the same length")
        dt = arr.dtype.newbyteorder(order) if arr.dtype.itemsize > 1 else arr.dtype
        names.append(name)
        formats.append(dt)
        offsets.append(off)
        fields.append({"name": name, "offset": off, "datatype": _PF_CODES[arr.dtype.name],
                       "count": 1})
        off += arr.dtype.itemsize
    n = n or 0
    point_step = max(off, pad_to)
    dt = np.dtype({"names": names, "formats": formats, "offsets": offsets,
                   "itemsize": point_step})
    rec = np.zeros(n, dtype=dt)
    for name, arr in columns.items():
        rec[name] = arr
    if n % height:
        raise ValueError("point count must be a multiple of height")
    width = n // height
    rows = rec.view(np.uint8).reshape(height, width * point_step)
    if row_pad:
        rows = np.concatenate([rows, np.zeros((height, row_pad), np.uint8)], axis=1)
    sec, nsec = divmod(int(t_ns), 1_000_000_000)
    return {"header": {"stamp": {"sec": sec, "nanosec": nsec}, "frame_id": frame_id},
            "height": height, "width": width, "fields": fields, "is_bigendian": bigendian,
            "point_step": point_step, "row_step": width * point_step + row_pad,
            "data": np.ascontiguousarray(rows).reshape(-1), "is_dense": False}
