"""The degeneracy spectrum of a registration: eigenvalues of J^T J at the solution.

Each inlier correspondence contributes one point-to-plane row. With the source point ``p`` and
the target's unit normal ``n`` both in the sensor frame at the solution, and a small motion
(rotation ``w``, translation ``v``) of the sensor, the residual changes by
``n . v + (p x n) . w``. Translation columns are dimensionless (metres of residual per metre);
rotation columns are metres per radian and grow with range, so the two blocks are not comparable
as they stand. We make them comparable by expressing rotation as *arc length at the scan's RMS
range* ``L = sqrt(mean |p|^2)``: the rotation columns are divided by ``L``. A unit step in any
direction of the scaled 6-vector then moves a typical point by one metre, and every entry of
J^T J is a sum of squared, dimensionless sensitivities.

Units of the eigenvalues (``lidar_eig_min``). An eigenvalue of this J^T J counts *points*: a
direction looked at squarely by k unit-normal points has eigenvalue k. Its size therefore grows
with the number of inliers, as it does in the reference figures, whose scans hold "twenty thousand points
each". To make scans of any density read on the reference scale we report
``lambda * 20000 / n_inliers``: the information the scan would carry with the reference 20,000
inlier points at the same geometry. On that scale the reference healthy ~2,400 means 12 % of the
per-point information lies along the weakest direction, and the degenerate ~12 means 0.06 %
(about one point in 1,700 sees that direction at all). The condition number ``lidar_cond`` is
independent of that scaling; it depends only on the choice of ``L``. The reference healthy
``lambda_max / lambda_min`` ~35 and degenerate > 900 are read on it directly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

REFERENCE_POINTS = 20_000
"""The reference scan size: eigenvalues are reported as if the scan had this many inliers."""

_TRANS = ("x (forward)", "y (left)", "z (up)")
_ROT = ("roll", "pitch", "yaw")
_ROT_LONG = ("roll (rotation about x)", "pitch (rotation about y)", "yaw (rotation about z)")


@dataclass(frozen=True)
class Spectrum:
    eigvals: np.ndarray  # ascending, on the reported (20,000-point) scale
    eig_min: float
    cond: float
    weak_vec: np.ndarray  # (rotation..., translation...) in the scaled coordinates
    weak_dir: str
    length_m: float  # L, the RMS range that scales the rotation columns
    n_inliers: int


def information_matrix(p: np.ndarray, n: np.ndarray, length_m: float,
                       planar: bool = False) -> np.ndarray:
    """J^T J with rotation columns scaled by 1/L; order (rotation, translation).

    3D: 6x6 over (roll, pitch, yaw, x, y, z). Planar: 3x3 over (yaw, x, y), from the x-y parts.
    """
    if planar:
        J = np.column_stack([(p[:, 0] * n[:, 1] - p[:, 1] * n[:, 0]) / length_m,
                             n[:, 0], n[:, 1]])
    else:
        J = np.hstack([np.cross(p, n) / length_m, n])
    return J.T @ J


def _words(part: np.ndarray, axes: tuple[int, ...], rotation: bool) -> str:
    u = part / (np.linalg.norm(part) or 1.0)
    k = int(np.argmax(np.abs(u)))
    main = axes[k]
    if u[k] ** 2 >= 0.8:  # within ~27 degrees of one axis
        return _ROT_LONG[main] if rotation else f"translation along {_TRANS[main]}"
    comps = " ".join(f"{c:+.2f}{'xyz'[a]}" for c, a in zip(u, axes, strict=True) if abs(c) >= 0.1)
    if rotation:
        return f"rotation about ({comps}), mostly {_ROT[main]}"
    return f"translation along ({comps}), mostly {_TRANS[main]}"


AXES = ("roll", "pitch", "yaw", "x", "y", "z")
"""Categorical names of the six motion axes (sensor frame: x forward, y left, z up), in the
order of :func:`full_vector`."""


def full_vector(vec: np.ndarray, planar: bool = False) -> np.ndarray:
    """The weak eigenvector as a unit 6-vector (roll, pitch, yaw, x, y, z); a planar (yaw, x, y)
    vector is padded with zeros."""
    v = np.asarray(vec, dtype=np.float64)
    v = v / (np.linalg.norm(v) or 1.0)
    if planar:
        return np.array([0.0, 0.0, v[0], v[1], v[2], 0.0])
    return v


def weak_axis(vec: np.ndarray, planar: bool = False) -> str:
    """The axis carrying the largest share of the weak eigenvector (one of :data:`AXES`).

    Unlike the words of :func:`describe_direction`, which quote the coefficients, this takes
    one of six values, so it can be counted over a run."""
    return AXES[int(np.argmax(np.abs(full_vector(vec, planar))))]


def describe_direction(vec: np.ndarray, planar: bool = False) -> str:
    """Words for an eigenvector in (rotation, translation) order, e.g.
    "translation along x (forward)" or "yaw (rotation about z) coupled with translation ..."."""
    v = np.asarray(vec, dtype=np.float64)
    v = v / (np.linalg.norm(v) or 1.0)
    rot_axes: tuple[int, ...] = (2,) if planar else (0, 1, 2)
    trans_axes: tuple[int, ...] = (0, 1) if planar else (0, 1, 2)
    rot, trans = v[:len(rot_axes)], v[len(rot_axes):]
    share_t = float(trans @ trans)
    t_words = _words(trans, trans_axes, rotation=False)
    r_words = _words(rot, rot_axes, rotation=True)
    if share_t >= 0.8:
        return t_words
    if share_t <= 0.2:
        return r_words
    if share_t >= 0.5:
        return f"{t_words} coupled with {r_words}"
    return f"{r_words} coupled with {t_words}"


def spectrum(p: np.ndarray, n: np.ndarray, planar: bool = False) -> Spectrum | None:
    """Spectrum of the point-to-plane information at the solution, on the reference scale.

    ``p``: inlier source points in the sensor frame; ``n``: unit normals of their targets, rotated
    into the sensor frame. None when there are too few inliers to define it.
    """
    p = np.asarray(p, dtype=np.float64)
    n = np.asarray(n, dtype=np.float64)
    dof = 3 if planar else 6
    if len(p) < dof:
        return None
    length = float(np.sqrt(np.mean(np.einsum("ij,ij->i", p, p))))
    if not np.isfinite(length) or length <= 0:
        return None
    A = information_matrix(p, n, length, planar) * (REFERENCE_POINTS / len(p))
    w, V = np.linalg.eigh(A)
    w = np.clip(w, 0.0, None)
    vec = V[:, 0]
    k = int(np.argmax(np.abs(vec)))
    if vec[k] < 0:  # deterministic sign
        vec = -vec
    cond = float(w[-1] / w[0]) if w[0] > 0 else float("inf")
    return Spectrum(eigvals=w, eig_min=float(w[0]), cond=cond, weak_vec=vec,
                    weak_dir=describe_direction(vec, planar), length_m=length,
                    n_inliers=len(p))
