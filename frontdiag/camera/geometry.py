"""Two-view geometry against the reference keyframe: E and H on the same correspondences.

Thresholds come from the noise model of chapter 3, not from taste: with localisation noise
sigma per coordinate, a squared residual / sigma^2 is chi-square with d degrees of freedom, so

* essential matrix, point-to-epipolar-line (Sampson) distance, d = 1: t = sqrt(3.841) * sigma
  = 1.96 px at sigma = 1;
* homography, transfer error, d = 2: t = sqrt(5.991) * sigma = 2.45 px at sigma = 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from frontdiag.records import Intrinsics

CHI2_95_1DOF = 3.841
CHI2_95_2DOF = 5.991
E_SAMPLE = 5  # Nister's five-point solver
TRIANGULATION_GATE_DEG = 1.0  # ORB-SLAM's parallax gate for new landmarks (chapter 6)
MIN_TRIANGULATED_SHARE = 0.1  # below this, the few points past the gate are stray outliers
H_SAMPLE = 4


def epipolar_threshold_px(sigma_px: float) -> float:
    return math.sqrt(CHI2_95_1DOF) * sigma_px


def homography_threshold_px(sigma_px: float) -> float:
    return math.sqrt(CHI2_95_2DOF) * sigma_px


def ransac_iters_required(w: float, s: int = E_SAMPLE, p: float = 0.999) -> float:
    """N = ceil(ln(1-p) / ln(1-w^s)): iterations for a clean sample with probability p.

    s=5, w=0.5, p=0.99 -> 146; p=0.999 -> 218; s=2, w=0.4, p=0.99 -> 27.
    NaN for an unknown w, inf when w <= 0, 1 when w >= 1.
    """
    if w is None or not math.isfinite(w):
        return float("nan")
    if w <= 0.0:
        return float("inf")
    ws = w**s
    if ws >= 1.0:
        return 1.0
    n = math.log(1.0 - p) / math.log1p(-ws)
    # guard against 145.0000000001 from rounding of the logs
    return float(max(1, math.ceil(n - 1e-9)))


def ransac_iters_run(w: float, max_iters: int, s: int = E_SAMPLE, p: float = 0.999) -> float:
    """Iterations OpenCV's USAC ran, as far as can be known from outside.

    USAC does not report its iteration count. Its standard termination criterion
    (calib3d/src/usac/termination.cpp) stops once the iteration counter reaches
    ln(1-p)/ln(1-w^s) evaluated at the best model so far, capped at ``maxIters``. At the end of
    the run the best model is the one returned, so the count is that bound at the returned
    inlier ratio: ``min(max_iters, N(w))`` (rounded up like the lesson's table; OpenCV truncates,
    a difference of at most one iteration). Starvation — the estimator stopped before reaching
    the confidence it was asked for — shows as ``ransac_iters_required > ransac_iters_run``,
    which happens exactly when the cap binds.
    """
    n = ransac_iters_required(w, s, p)
    if not math.isfinite(n):
        return float("nan") if math.isnan(n) else float(max_iters)
    return float(min(n, max_iters))


def undistort_points(xy: np.ndarray, intr: Intrinsics | None) -> np.ndarray:
    """Keypoints to pixel coordinates of the ideal pinhole camera K (images are never warped)."""
    if intr is None or len(xy) == 0 or not intr.has_distortion or intr.model == "none":
        return xy.astype(np.float64)
    pts = xy.reshape(-1, 1, 2).astype(np.float64)
    K = np.asarray(intr.K, np.float64)
    D = np.asarray(intr.D, np.float64).ravel()
    if intr.model == "equidistant":
        out = cv2.fisheye.undistortPoints(pts, K, D[:4], P=K)
    else:  # plumb_bob, rational_polynomial: OpenCV's model takes 4, 5, 8, 12 or 14 coefficients
        out = cv2.undistortPoints(pts, K, D, P=K)
    return out.reshape(-1, 2)


@dataclass(frozen=True)
class TwoView:
    """What E and H say about one pair of views (NaN where not computable)."""

    n_corr: int
    inliers_e: float = float("nan")
    inliers_h: float = float("nan")
    inlier_ratio: float = float("nan")
    rot_deg: float = float("nan")
    parallax_med_deg: float = float("nan")
    pose_info_cond: float = float("nan")
    t_dir: np.ndarray | None = None  # unit translation direction, reference -> current
    ok_e: bool = False

    @property
    def h_over_e(self) -> float:
        if not (self.inliers_e > 0):
            return float("nan")
        return float(self.inliers_h / self.inliers_e)


def fit_homography(p_ref: np.ndarray, p_cur: np.ndarray, thr_px: float, confidence: float,
                   max_iters: int, seed: int) -> float:
    """Homography inliers (USAC_MAGSAC) on the given correspondences."""
    if len(p_ref) < H_SAMPLE:
        return float("nan")
    cv2.setRNGSeed(seed)
    H, mask = cv2.findHomography(p_ref, p_cur, cv2.USAC_MAGSAC, thr_px, maxIters=max_iters,
                                 confidence=confidence)
    if H is None or mask is None:
        return 0.0
    return float(np.count_nonzero(mask))


def bearings(p: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Unit bearing vectors of pixel points of the ideal pinhole K."""
    Kinv = np.linalg.inv(K)
    f = np.column_stack([p, np.ones(len(p))]) @ Kinv.T
    return f / np.linalg.norm(f, axis=1, keepdims=True)


def parallax_deg(p_ref: np.ndarray, p_cur: np.ndarray, K: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Angle between the bearings of each correspondence after removing the rotation R.

    With x_cur = R x_ref + t, a pure rotation makes R^T f_cur parallel to f_ref: angle 0.
    """
    f1 = bearings(p_ref, K)
    f2 = bearings(p_cur, K) @ R  # rows of (R^T f2)
    c = np.clip(np.einsum("ij,ij->i", f1, f2), -1.0, 1.0)
    return np.degrees(np.arccos(c))


def pose_information_condition(p_ref: np.ndarray, p_cur: np.ndarray, K: np.ndarray,
                               R: np.ndarray, t: np.ndarray,
                               min_parallax_deg: float = TRIANGULATION_GATE_DEG) -> float:
    """lambda_max / lambda_min of the 6x6 pose information J^T J at the inlier points.

    Monocular scale is unknown, so the units are fixed explicitly: rotation in radians,
    translation in units of the median scene depth (depths are scaled to median 1). A point's
    depth is its two-view triangulation when its parallax clears the 1 deg triangulation gate of
    chapter 6 and it lies in front of both cameras; otherwise its depth is not observable from
    these two views and it is placed at the median depth of the triangulated points. When fewer
    than six points, or fewer than 10% of them, clear the gate (pure rotation, or a baseline too
    short to measure), the few that do are stray matches sliding along their epipolar lines:
    every point is then put at depth 1 and the translation, which is noise, is taken as zero. J is the Jacobian of the pixel
    reprojection in the current view with respect to a left-multiplied SE(3) increment
    [rho, phi]: d(u, v)/d(P_c) times [I | -skew(P_c)] (lesson, chapter 6, worked example 2).
    """
    n = len(p_ref)
    if n < 6:
        return float("nan")
    t = t.reshape(3)
    f_ref = bearings(p_ref, K)
    par = parallax_deg(p_ref, p_cur, K, R)
    P1 = K @ np.hstack([np.eye(3), np.zeros((3, 1))])
    P2 = K @ np.hstack([R, t.reshape(3, 1)])
    Xh = cv2.triangulatePoints(P1, P2, p_ref.T.astype(np.float64), p_cur.T.astype(np.float64))
    with np.errstate(divide="ignore", invalid="ignore"):
        X = (Xh[:3] / Xh[3]).T
        z1 = X[:, 2]
        z2 = (X @ R.T + t)[:, 2]
        good = np.isfinite(z1) & (z1 > 0) & (z2 > 0) & (par >= min_parallax_deg)
    if np.count_nonzero(good) >= max(6, MIN_TRIANGULATED_SHARE * n):
        scale = float(np.median(z1[good]))
        t_s = t / scale
    else:  # no measurable baseline: unit depths, and t (pure noise here) is taken as zero
        scale, t_s = 1.0, np.zeros(3)
    depth = np.where(good, z1, scale) / scale  # along the optical axis, median scene depth ~ 1
    X = f_ref / f_ref[:, 2:3] * depth[:, None]
    Pc = X @ R.T + t_s
    Pc = Pc[Pc[:, 2] > 1e-6]
    if len(Pc) < 6:
        return float("nan")
    fx, fy = K[0, 0], K[1, 1]
    x, y, z = Pc[:, 0], Pc[:, 1], Pc[:, 2]
    iz = 1.0 / z
    zero = np.zeros_like(z)
    ju = np.column_stack([fx * iz, zero, -fx * x * iz * iz])  # d(u)/d(P_c)
    jv = np.column_stack([zero, fy * iz, -fy * y * iz * iz])  # d(v)/d(P_c)
    # j @ [I | -skew(P)] = [j, P x j] row by row
    J = np.vstack([np.hstack([ju, np.cross(Pc, ju)]), np.hstack([jv, np.cross(Pc, jv)])])
    ev = np.linalg.eigvalsh(J.T @ J)
    if ev[0] <= 0:
        return float("inf")
    return float(ev[-1] / ev[0])


def _rotation_of_least_parallax(E: np.ndarray, R_pose: np.ndarray, p_ref: np.ndarray,
                                p_cur: np.ndarray, K: np.ndarray) -> np.ndarray:
    """The rotation of E's twisted pair under which the inlier bearings agree best.

    recoverPose picks between R and its twisted partner (R rotated 180 deg about t) by
    cheirality, which is meaningless when there is no translation: t is noise and the choice
    is a coin toss. Under any real translation the cheirality choice is also the one with the
    smaller median parallax (the twisted partner flips bearings away from the epipole), so
    taking the smaller one changes nothing there and fixes pure rotation.
    """
    R1, R2, _ = cv2.decomposeEssentialMat(E)
    best, best_par = R_pose, float(np.median(parallax_deg(p_ref, p_cur, K, R_pose)))
    for Rc in (R1, R2):
        par = float(np.median(parallax_deg(p_ref, p_cur, K, Rc)))
        if par < best_par - 1e-9:
            best, best_par = Rc, par
    return best


def two_view(p_ref: np.ndarray, p_cur: np.ndarray, K: np.ndarray | None, *,
             sigma_px: float = 1.0, confidence: float = 0.999, max_iters: int = 1000,
             seed: int = 0) -> TwoView:
    """E (if K is known) and H with USAC_MAGSAC on the same correspondences, recoverPose,
    parallax and the pose information condition. Points are undistorted pixel coordinates."""
    n = len(p_ref)
    p_ref = np.ascontiguousarray(p_ref, np.float64)
    p_cur = np.ascontiguousarray(p_cur, np.float64)
    inl_h = fit_homography(p_ref, p_cur, homography_threshold_px(sigma_px), confidence,
                           max_iters, seed)
    if K is None or n < E_SAMPLE:
        return TwoView(n, inliers_h=inl_h)
    cv2.setRNGSeed(seed)
    E, mask = cv2.findEssentialMat(p_ref, p_cur, K, method=cv2.USAC_MAGSAC, prob=confidence,
                                   threshold=epipolar_threshold_px(sigma_px), maxIters=max_iters)
    if E is None or mask is None or E.shape != (3, 3):
        return TwoView(n, inliers_e=0.0, inliers_h=inl_h, inlier_ratio=0.0)
    mask = mask.ravel().astype(np.uint8)
    inl_e = int(np.count_nonzero(mask))
    w = inl_e / n
    if inl_e < E_SAMPLE:
        return TwoView(n, inliers_e=float(inl_e), inliers_h=inl_h, inlier_ratio=w)
    _, R, t, _ = cv2.recoverPose(E, p_ref, p_cur, K, mask=mask.copy())
    # Parallax and information over all E inliers: recoverPose's cheirality mask is a coin toss
    # under pure rotation and would leave a handful of points.
    sel = mask > 0
    R = _rotation_of_least_parallax(E, R, p_ref[sel], p_cur[sel], K)
    rot = float(np.degrees(np.linalg.norm(cv2.Rodrigues(R)[0])))
    par = parallax_deg(p_ref[sel], p_cur[sel], K, R)
    cond = pose_information_condition(p_ref[sel], p_cur[sel], K, R, t.ravel())
    return TwoView(n, inliers_e=float(inl_e), inliers_h=inl_h, inlier_ratio=w, rot_deg=rot,
                   parallax_med_deg=float(np.median(par)), pose_info_cond=cond,
                   t_dir=t.ravel() / max(np.linalg.norm(t), 1e-12), ok_e=True)
