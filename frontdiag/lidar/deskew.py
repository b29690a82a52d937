"""Motion compensation of one sweep under a constant body-frame twist.

Point ``i`` was measured ``s_i`` seconds after the scan stamp, in the sensor frame of that
instant. Under a constant twist ``xi = (w, v)`` the sensor at ``s`` sits at ``exp(s xi)`` relative
to the sensor at the stamp, so the point in the stamp's frame is ``exp(s_i xi) p_i``.

The exact SE(3) exponential is evaluated at ``BINS`` evenly spaced times across the sweep and each
point takes the transform of its nearest time. With 1024 bins over a 100 ms sweep the time error is
at most 0.05 ms: 0.07 mm at 1.5 m/s, 5 mm for a point 100 m away while turning at 1 rad/s. That
keeps the cost at a dozen vector operations over the cloud instead of a 4x4 matrix per point.
"""

from __future__ import annotations

import numpy as np

from frontdiag.lidar.se3 import se3_exp_batch

BINS = 1024


def deskew(xyz: np.ndarray, time_rel_s: np.ndarray, twist: np.ndarray,
           ref_s: float = 0.0) -> tuple[np.ndarray, float]:
    """Points moved to the sensor frame at time ``ref_s`` (seconds after the stamp), and the
    largest displacement applied (metres)."""
    p = np.asarray(xyz, dtype=np.float64)
    if len(p) == 0:
        return p.copy(), 0.0
    s = np.asarray(time_rel_s, dtype=np.float64) - ref_s
    lo, hi = float(s.min()), float(s.max())
    xi = np.asarray(twist, dtype=np.float64)
    if hi > lo:
        idx = np.rint((s - lo) * ((BINS - 1) / (hi - lo))).astype(np.intp)
        tb = lo + (hi - lo) * np.arange(BINS) / (BINS - 1)
    else:
        idx = np.zeros(len(s), dtype=np.intp)
        tb = np.array([lo])
    M = se3_exp_batch(tb[:, None] * xi[None, :])[:, :3, :]  # (B, 3, 4)
    M[:, :, :3] -= np.eye(3)  # displacement = (R - I) p + t
    cols = M.reshape(len(tb), 12).T  # (12, B), rows contiguous for fast gathers
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    d = [cols[4 * r][idx] * x + cols[4 * r + 1][idx] * y + cols[4 * r + 2][idx] * z
         + cols[4 * r + 3][idx] for r in range(3)]
    out = np.empty_like(p)
    out[:, 0], out[:, 1], out[:, 2] = x + d[0], y + d[1], z + d[2]
    return out, float(np.sqrt(np.max(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])))


def sweep_displacement(points: np.ndarray, span_s: float, twist: np.ndarray) -> float:
    """How far the scene moves in the sensor frame over one sweep: the largest
    ``|exp(span xi) p - p|`` over ``points``. 1.5 m/s straight ahead over a 100 ms sweep gives
    15 cm, the distance between the first and the last point's view of the same wall; turning
    adds the rotation's arc at each point's range."""
    if len(points) == 0:
        return 0.0
    T = se3_exp_batch(np.asarray(twist, dtype=np.float64)[None] * span_s)[0]
    d = points @ (T[:3, :3] - np.eye(3)).T + T[:3, 3]
    return float(np.sqrt(np.max(np.einsum("ij,ij->i", d, d))))
