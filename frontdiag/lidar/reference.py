"""Small reference implementations of the registration formulas, checked against the worked
examples (closed form with the reflection guard, the 2D angle shortcut, one point-to-plane step,
the NDT voxel Gaussian). The frontend uses a library backend; these exist so the maths the
diagnosis rests on is executable and tested."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def best_rigid(A: np.ndarray, B: np.ndarray, *, guard: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """R, t minimising sum ||R a + t - b||^2 (Arun/Kabsch/Umeyama), any dimension.

    The translation decouples (t = mean(B) - R mean(A)); R maximises tr(R H) with H the
    cross-covariance, so R = V U^T from H = U S V^T. ``guard`` flips the last singular direction
    when det(V U^T) = -1, returning the best proper rotation instead of a reflection (collinear
    or mirrored points).
    """
    A = np.asarray(A, dtype=np.float64)
    B = np.asarray(B, dtype=np.float64)
    ca, cb = A.mean(axis=0), B.mean(axis=0)
    H = (A - ca).T @ (B - cb)
    U, _S, Vt = np.linalg.svd(H)
    V = Vt.T
    D = np.eye(A.shape[1])
    if guard:
        D[-1, -1] = np.sign(np.linalg.det(V @ U.T)) or 1.0
    R = V @ D @ U.T
    return R, cb - R @ ca


@dataclass(frozen=True)
class Planar:
    theta_rad: float
    t: np.ndarray
    sum_cross: float
    sum_dot: float


def best_rigid_2d(A: np.ndarray, B: np.ndarray) -> Planar:
    """The plane's shortcut: theta = atan2(sum a x b, sum a . b) on centred points, no SVD."""
    A = np.asarray(A, dtype=np.float64)
    B = np.asarray(B, dtype=np.float64)
    ca, cb = A.mean(axis=0), B.mean(axis=0)
    a, b = A - ca, B - cb
    cross = float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]))
    dot = float(np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]))
    th = float(np.arctan2(cross, dot))
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    return Planar(th, cb - R @ ca, cross, dot)


def nearest(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Index of the nearest ``dst`` point for every ``src`` point (brute force; small inputs)."""
    d2 = ((np.asarray(src)[:, None, :] - np.asarray(dst)[None, :, :]) ** 2).sum(-1)
    return d2.argmin(axis=1)


def point_to_point_translation_step(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Translation-only point-to-point step: the mean of (target - source) over nearest pairs."""
    j = nearest(src, dst)
    return (np.asarray(dst)[j] - np.asarray(src)).mean(axis=0)


def point_to_plane_translation_step(src: np.ndarray, dst: np.ndarray,
                                    normals: np.ndarray) -> np.ndarray:
    """One Gauss-Newton step of sum [n^T (p + dt - q)]^2 over nearest pairs, translation only.

    Directions without information (sliding along a wall) get no step: the minimum-norm
    solution of the normal equations.
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    j = nearest(src, dst)
    n = np.asarray(normals, dtype=np.float64)[j]
    r = np.einsum("ij,ij->i", n, src - dst[j])  # signed distance to the target plane
    return -np.linalg.pinv(n.T @ n) @ (n.T @ r)


def ndt_voxel(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and sample covariance (divided by n - 1) of the points in one NDT voxel."""
    P = np.asarray(points, dtype=np.float64)
    mu = P.mean(axis=0)
    C = P - mu
    return mu, C.T @ C / (len(P) - 1)


def ndt_score(d: np.ndarray, cov: np.ndarray) -> float:
    """Likelihood term exp(-1/2 d^T Sigma^-1 d) of an offset ``d`` from the voxel mean."""
    d = np.asarray(d, dtype=np.float64)
    return float(np.exp(-0.5 * d @ np.linalg.solve(cov, d)))
