"""SE(2) / SE(3) in homogeneous matrices, batched over a leading axis.

Tangent vectors are ordered translation first, rotation last: (x, y, θ) in 2D and
(x, y, z, φx, φy, φz) in 3D, the order of g2o's information matrices. Perturbations are on the
right, ``T_true = T · Exp(ξ)`` (g2o's and GTSAM's convention for relative-pose edges), so a
covariance lives in the frame of the pose it perturbs and moves between frames with the adjoint:
``X · Exp(ξ) = Exp(Ad(X) ξ) · X``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

F = NDArray[np.float64]


def tangent_dim(d: int) -> int:
    """Tangent dimension of SE(d): 3 for d = 2, 6 for d = 3."""
    return 3 if d == 2 else 6


def se2(x: F, y: F, theta: F) -> F:
    """(n,) arrays -> (n, 3, 3) homogeneous matrices."""
    n = np.shape(x)[0]
    c, s = np.cos(theta), np.sin(theta)
    out = np.zeros((n, 3, 3))
    out[:, 0, 0], out[:, 0, 1], out[:, 0, 2] = c, -s, x
    out[:, 1, 0], out[:, 1, 1], out[:, 1, 2] = s, c, y
    out[:, 2, 2] = 1.0
    return out


def se3(t: F, quat_xyzw: F) -> F:
    """(n, 3) translations and (n, 4) unit quaternions (x, y, z, w) -> (n, 4, 4)."""
    n = t.shape[0]
    out = np.zeros((n, 4, 4))
    out[:, :3, :3] = Rotation.from_quat(quat_xyzw).as_matrix()
    out[:, :3, 3] = t
    out[:, 3, 3] = 1.0
    return out


def inv(T: F) -> F:
    """Inverse of rigid transforms (..., d+1, d+1)."""
    d = T.shape[-1] - 1
    R = T[..., :d, :d]
    t = T[..., :d, d]
    out = np.zeros_like(T)
    Rt = np.swapaxes(R, -1, -2)
    out[..., :d, :d] = Rt
    out[..., :d, d] = -np.einsum("...ij,...j->...i", Rt, t)
    out[..., d, d] = 1.0
    return out


def _skew(v: F) -> F:
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def adjoint(T: F) -> F:
    """Ad(T) for tangent vectors ordered translation first: (..., k, k)."""
    d = T.shape[-1] - 1
    R = T[..., :d, :d]
    t = T[..., :d, d]
    k = tangent_dim(d)
    out = np.zeros((*T.shape[:-2], k, k))
    if d == 2:
        out[..., :2, :2] = R
        out[..., 0, 2] = t[..., 1]
        out[..., 1, 2] = -t[..., 0]
        out[..., 2, 2] = 1.0
    else:
        out[..., :3, :3] = R
        out[..., :3, 3:] = _skew(t) @ R
        out[..., 3:, 3:] = R
    return out


def _series(th: F, exact: F, small: F) -> F:
    """``exact`` where |θ| is not small, else its Taylor value ``small`` (same shapes)."""
    return np.where(np.abs(th) < 1e-4, small, exact)


def right_jacobian_inv(xi: F) -> F:
    """J_r⁻¹(ξ), exact: ``Log(Exp(ξ)·Exp(δ)) ≈ ξ + J_r⁻¹(ξ) δ``, (..., k) -> (..., k, k).

    SE(2): the inverse of J_r in Solà, Deray & Atchuthan 2018 ("A micro Lie theory for state
    estimation in robotics", eq. 163), block-triangular with the inverse of a scaled rotation
    on the diagonal. SE(3): J_r(ξ) = J_l(−ξ), and J_l = [[J, Q], [0, J]] with the SO(3) left
    Jacobian J and Barfoot's Q(ρ, φ) (Barfoot 2017, "State Estimation for Robotics",
    sec. 7.1.5), inverted block-wise: [[J⁻¹, −J⁻¹QJ⁻¹], [0, J⁻¹]], J⁻¹ in closed form. To first
    order it is ``I + ad(ξ)/2`` (ad the adjoint of the Lie algebra), which is off by tenths at the radians of a false loop's
    residual."""
    k = xi.shape[-1]
    out = np.zeros((*xi.shape[:-1], k, k))
    if k == 3:
        r1, r2, th = xi[..., 0], xi[..., 1], xi[..., 2]
        t = np.where(np.abs(th) < 1e-4, 1.0, th)
        s, c = np.sin(t), np.cos(t)
        a = _series(th, s / t, 1.0 - th**2 / 6.0)
        b = _series(th, (1.0 - c) / t, th / 2.0)
        # J_r = [[a, b, x], [-b, a, y], [0, 0, 1]]
        x = _series(th, (t * r1 - r2 + r2 * c - r1 * s) / t**2, -r2 / 2.0 + r1 * th / 6.0)
        y = _series(th, (r1 + t * r2 - r1 * c - r2 * s) / t**2, r1 / 2.0 + r2 * th / 6.0)
        den = a * a + b * b
        ia, ib = a / den, b / den  # [[a, b], [-b, a]]⁻¹ = [[ia, -ib], [ib, ia]]
        out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1] = ia, -ib, ib, ia
        out[..., 0, 2] = -(ia * x - ib * y)
        out[..., 1, 2] = -(ib * x + ia * y)
        out[..., 2, 2] = 1.0
        return out
    rho, phi = -xi[..., :3], -xi[..., 3:]  # J_r(ξ) = J_l(−ξ)
    th = np.linalg.norm(phi, axis=-1)
    t = np.where(th < 1e-4, 1.0, th)
    s, c = np.sin(t), np.cos(t)
    A = _skew(phi)
    B = _skew(rho)
    A2 = A @ A
    ABA = A @ B @ A
    c2 = _series(th, (t - s) / t**3, np.full_like(th, 1.0 / 6.0))
    c3 = _series(th, (t**2 + 2.0 * c - 2.0) / (2.0 * t**4), np.full_like(th, 1.0 / 24.0))
    c4 = _series(th, (2.0 * t - 3.0 * s + t * c) / (2.0 * t**5), np.full_like(th, 1.0 / 120.0))
    # 1/θ² − (1 + cos θ)/(2θ sin θ), with (1 + cos θ)/sin θ = cot(θ/2): finite at θ = π
    c5 = _series(th, 1.0 / t**2 - np.cos(t / 2) / (2.0 * t * np.sin(t / 2)),
                 np.full_like(th, 1.0 / 12.0))
    Q = (0.5 * B + c2[..., None, None] * (A @ B + B @ A + ABA)
         + c3[..., None, None] * (A2 @ B + B @ A2 - 3.0 * ABA)
         + c4[..., None, None] * (ABA @ A + A2 @ B @ A))
    Jinv = np.eye(3) - 0.5 * A + c5[..., None, None] * A2
    out[..., :3, :3] = Jinv
    out[..., :3, 3:] = -Jinv @ Q @ Jinv
    out[..., 3:, 3:] = Jinv
    return out


def log(T: F) -> F:
    """Log map (..., d+1, d+1) -> (..., k): exact, translation first."""
    d = T.shape[-1] - 1
    t = T[..., :d, d]
    if d == 2:
        th = np.arctan2(T[..., 1, 0], T[..., 0, 0])
        small = np.abs(th) < 1e-9
        ths = np.where(small, 1.0, th)
        a = np.where(small, 1.0 - th**2 / 6.0, np.sin(ths) / ths)  # sin θ / θ
        b = np.where(small, th / 2.0, (1.0 - np.cos(ths)) / ths)  # (1 - cos θ) / θ
        den = a * a + b * b
        # V = [[a, -b], [b, a]]; V^-1 = [[a, b], [-b, a]] / (a² + b²)
        rx = (a * t[..., 0] + b * t[..., 1]) / den
        ry = (-b * t[..., 0] + a * t[..., 1]) / den
        return np.stack([rx, ry, th], axis=-1)
    shape = T.shape[:-2]
    R = T[..., :3, :3].reshape(-1, 3, 3)
    phi = Rotation.from_matrix(R).as_rotvec().reshape((*shape, 3))
    ang = np.linalg.norm(phi, axis=-1)
    W = _skew(phi)
    small = ang < 1e-6
    angs = np.where(small, 1.0, ang)
    # V^-1 = I - W/2 + (1/θ² - (1+cos θ)/(2θ sin θ)) W²
    coef = np.where(small, 1.0 / 12.0,
                    1.0 / angs**2 - (1.0 + np.cos(angs)) / (2.0 * angs * np.sin(angs)))
    Vinv = np.eye(3) - 0.5 * W + coef[..., None, None] * (W @ W)
    rho = np.einsum("...ij,...j->...i", Vinv, t)
    return np.concatenate([rho, phi], axis=-1)


def rotation_angle(T: F) -> F:
    """The rotation angle of each transform, radians in [0, π]."""
    d = T.shape[-1] - 1
    if d == 2:
        return np.abs(np.arctan2(T[..., 1, 0], T[..., 0, 0]))
    tr = np.trace(T[..., :3, :3], axis1=-2, axis2=-1)
    return np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0))


def prefix_products(steps: F) -> F:
    """P[k] = steps[0] · ... · steps[k-1], P[0] = I: (n+1, d+1, d+1), by a log-depth scan."""
    n, m = steps.shape[0], steps.shape[-1]
    P = np.empty((n + 1, m, m))
    P[0] = np.eye(m)
    P[1:] = steps
    shift = 1
    while shift <= n:
        P[shift + 1:] = P[1:n + 1 - shift] @ P[shift + 1:]
        shift *= 2
    return P


def exp(xi: F, d: int) -> F:
    """Exp map (..., k) -> (..., d+1, d+1), translation first."""
    shape = xi.shape[:-1]
    if d == 2:
        rho, th = xi[..., :2], xi[..., 2]
        small = np.abs(th) < 1e-9
        ths = np.where(small, 1.0, th)
        a = np.where(small, 1.0 - th**2 / 6.0, np.sin(ths) / ths)
        b = np.where(small, th / 2.0, (1.0 - np.cos(ths)) / ths)
        x = a * rho[..., 0] - b * rho[..., 1]
        y = b * rho[..., 0] + a * rho[..., 1]
        flat = se2(x.reshape(-1), y.reshape(-1), th.reshape(-1))
        return flat.reshape((*shape, 3, 3))
    rho, phi = xi[..., :3].reshape(-1, 3), xi[..., 3:].reshape(-1, 3)
    ang = np.linalg.norm(phi, axis=-1)
    W = _skew(phi)
    small = ang < 1e-6
    angs = np.where(small, 1.0, ang)
    c1 = np.where(small, 0.5, (1.0 - np.cos(angs)) / angs**2)
    c2 = np.where(small, 1.0 / 6.0, (angs - np.sin(angs)) / angs**3)
    V = np.eye(3) + c1[:, None, None] * W + c2[:, None, None] * (W @ W)
    out = np.zeros((rho.shape[0], 4, 4))
    out[:, :3, :3] = Rotation.from_rotvec(phi).as_matrix()
    out[:, :3, 3] = np.einsum("nij,nj->ni", V, rho)
    out[:, 3, 3] = 1.0
    return out.reshape((*shape, 4, 4))
