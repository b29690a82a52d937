"""Rigid-motion helpers. Twists are ordered (wx, wy, wz, vx, vy, vz): rotation first."""

from __future__ import annotations

import numpy as np


def skew(w: np.ndarray) -> np.ndarray:
    """[w]x, so that skew(w) @ p == cross(w, p)."""
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def se3_exp_batch(xi: np.ndarray) -> np.ndarray:
    """exp of many twists (M, 6) -> (M, 4, 4), exact (Rodrigues and the left Jacobian)."""
    xi = np.atleast_2d(np.asarray(xi, dtype=np.float64))
    w, v = xi[:, :3], xi[:, 3:]
    th = np.linalg.norm(w, axis=1)
    small = th < 1e-9
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th**2 / 6.0, np.sin(ths) / ths)
    b = np.where(small, 0.5 - th**2 / 24.0, (1.0 - np.cos(ths)) / ths**2)
    c = np.where(small, 1.0 / 6.0 - th**2 / 120.0, (ths - np.sin(ths)) / ths**3)
    W = np.zeros((len(xi), 3, 3))
    W[:, 0, 1], W[:, 0, 2], W[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    W[:, 1, 0], W[:, 2, 0], W[:, 2, 1] = w[:, 2], -w[:, 1], w[:, 0]
    W2 = W @ W
    eye = np.eye(3)[None]
    R = eye + a[:, None, None] * W + b[:, None, None] * W2
    V = eye + b[:, None, None] * W + c[:, None, None] * W2
    T = np.tile(np.eye(4), (len(xi), 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = np.einsum("nij,nj->ni", V, v)
    return T


def se3_exp(xi: np.ndarray) -> np.ndarray:
    return se3_exp_batch(np.asarray(xi, dtype=np.float64)[None])[0]


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector of R (angle in [0, pi])."""
    cos = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    th = float(np.arccos(cos))
    vee = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if th < 1e-9:
        return 0.5 * vee
    if np.pi - th < 1e-6:  # near pi: axis from the symmetric part
        M = (R + np.eye(3)) / 2.0
        k = int(np.argmax(np.diag(M)))
        axis = M[:, k] / np.sqrt(max(M[k, k], 1e-12))
        return axis * th
    return vee * th / (2.0 * np.sin(th))


def se3_log(T: np.ndarray) -> np.ndarray:
    w = so3_log(T[:3, :3])
    th = float(np.linalg.norm(w))
    W = skew(w)
    if th < 1e-9:
        Vinv = np.eye(3) - 0.5 * W
    else:
        Vinv = np.eye(3) - 0.5 * W + (1.0 - th * np.sin(th) / (2.0 * (1.0 - np.cos(th)))) / th**2 * W @ W
    return np.concatenate([w, Vinv @ T[:3, 3]])


def inv(T: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    R = T[:3, :3]
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ T[:3, 3]
    return out


def rotation_angle_deg(R: np.ndarray) -> float:
    return float(np.rad2deg(np.arccos(np.clip((np.trace(R[:3, :3]) - 1.0) / 2.0, -1.0, 1.0))))


def interpolate_pose(t_query: int, stamps: np.ndarray, poses: np.ndarray) -> np.ndarray | None:
    """Pose at ``t_query`` from time-sorted poses: geodesic interpolation between the two
    neighbours; None outside the covered interval (no extrapolation)."""
    if len(stamps) == 0 or t_query < stamps[0] or t_query > stamps[-1]:
        return None
    i = int(np.searchsorted(stamps, t_query, side="right"))
    if i >= len(stamps):
        return poses[-1].copy()
    i0 = i - 1
    span = float(stamps[i] - stamps[i0])
    alpha = 0.0 if span <= 0 else float(t_query - stamps[i0]) / span
    return poses[i0] @ se3_exp(alpha * se3_log(inv(poses[i0]) @ poses[i]))
