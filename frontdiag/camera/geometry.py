"""Two-view geometry against the reference keyframe: E and H on the same correspondences.

Thresholds come from the noise model, not from taste: with localisation noise
sigma per coordinate, a squared residual / sigma^2 is chi-square with d degrees of freedom, so

* essential matrix, point-to-epipolar-line (Sampson) distance, d = 1: t = sqrt(3.841) * sigma
  = 1.96 px at sigma = 1;
* homography, transfer error, d = 2: t = sqrt(5.991) * sigma = 2.45 px at sigma = 1.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np

from frontdiag.records import Intrinsics

CHI2_95_1DOF = 3.841
CHI2_95_2DOF = 5.991
E_SAMPLE = 5  # Nister's five-point solver
TRIANGULATION_GATE_DEG = 1.0  # ORB-SLAM's parallax gate for new landmarks (docs/derivations.md §4)
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
    inlier ratio: ``min(max_iters, N(w))`` (rounded up like the reference table; OpenCV truncates,
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


# Fewest grid cells a shared view must cover for the inliers' spread over it to be read: a sixth
# of the 8x6 grid. Under that the two views barely overlap and the spread says nothing.
MIN_SHARED_CELLS = 8
_BORDER_SAMPLES = 16  # points per image side of the reference's outline


@functools.lru_cache(maxsize=16)
def _view_outline(key: tuple[int, int, tuple[int, int], bytes, bytes, str]
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(outline of the image, (M, 2); centres of the grid's cells, (cells, 2)), undistorted.
    ``key`` is (width, height, grid, K bytes, D bytes, model): one per camera."""
    width, height, grid, kb, db, model = key
    intr = Intrinsics(K=np.frombuffer(kb).reshape(3, 3), D=np.frombuffer(db), model=model)
    s = np.linspace(0.0, 1.0, _BORDER_SAMPLES, endpoint=False)
    w1, h1 = width - 1.0, height - 1.0
    border = np.concatenate([np.column_stack([s * w1, np.zeros_like(s)]),
                             np.column_stack([np.full_like(s, w1), s * h1]),
                             np.column_stack([w1 - s * w1, np.full_like(s, h1)]),
                             np.column_stack([np.zeros_like(s), h1 - s * h1])])
    cols, rows = grid
    cx = (np.arange(cols) + 0.5) * (width / cols)
    cy = (np.arange(rows) + 0.5) * (height / rows)
    centres = np.array([(x, y) for y in cy for x in cx], np.float64)
    return undistort_points(border, intr), undistort_points(centres, intr)


def _inside(poly: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Even-odd rule: which points lie inside the closed polygon (vertices in order)."""
    x0, y0 = poly[:, 0][None, :], poly[:, 1][None, :]
    x1, y1 = np.roll(poly[:, 0], -1)[None, :], np.roll(poly[:, 1], -1)[None, :]
    px, py = pts[:, 0][:, None], pts[:, 1][:, None]
    straddle = (y0 > py) != (y1 > py)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_cross = x0 + (py - y0) * (x1 - x0) / (y1 - y0)
    return np.count_nonzero(straddle & (px < x_cross), axis=1) % 2 == 1


def shared_cells(H: np.ndarray | None, und_cur: np.ndarray, intr: Intrinsics | None,
                 width: int, height: int, grid: tuple[int, int]) -> np.ndarray | None:
    """Cells of the current image's ``cols x rows`` grid that the reference view also saw.

    Each cell's centre (undistorted) is taken back through ``H``, the homography of the pair
    (undistorted pixels, reference -> current, as ``two_view`` fitted it); the cell is shared
    when it lands in front of the reference camera and inside the reference image's outline
    (undistorted). For a rotation the homography is exact; under translation it is the overlap
    at the depth of the plane it fits. ``und_cur`` (current points of correspondences) tells
    which side of the homography's horizon is in front. None when there is no homography, it
    is singular, or fewer than ``MIN_SHARED_CELLS`` cells are shared.
    """
    if H is None or len(und_cur) == 0 or not np.all(np.isfinite(H)) \
            or abs(np.linalg.det(H)) < 1e-12:
        return None
    if intr is None or not intr.has_distortion or intr.model == "none":
        key = (width, height, grid, np.eye(3).tobytes(), b"", "none")
    else:
        key = (width, height, grid, np.asarray(intr.K, np.float64).tobytes(),
               np.asarray(intr.D, np.float64).ravel().tobytes(), intr.model)
    outline, centres = _view_outline(key)
    # H maps the reference's rays to the current's up to scale; a centre is in front of the
    # reference camera when its ray there has the sign the correspondences' rays have
    Hinv = np.linalg.inv(H)
    q = np.column_stack([centres, np.ones(len(centres))]) @ Hinv.T
    q_in = np.column_stack([und_cur, np.ones(len(und_cur))]) @ Hinv.T
    front = q[:, 2] * np.sign(np.median(q_in[:, 2])) > 1e-12
    seen = np.zeros(len(centres), bool)
    seen[front] = _inside(outline, q[front, :2] / q[front, 2:3])
    if np.count_nonzero(seen) < MIN_SHARED_CELLS:
        return None
    cols, rows = grid
    return seen.reshape(rows, cols)


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
    inlier_mask: np.ndarray | None = None  # (n_corr,) bool: the essential-matrix inliers
    H: np.ndarray | None = None  # the homography, reference -> current (undistorted pixels)
    epi_residual_px: float = float("nan")  # median Sampson distance of E's inliers (px)

    @property
    def h_over_e(self) -> float:
        if not (self.inliers_e > 0):
            return float("nan")
        return float(self.inliers_h / self.inliers_e)


def fit_homography(p_ref: np.ndarray, p_cur: np.ndarray, thr_px: float, confidence: float,
                   max_iters: int, seed: int) -> tuple[float, np.ndarray | None]:
    """Homography inliers (USAC_MAGSAC) on the given correspondences, and the homography."""
    if len(p_ref) < H_SAMPLE:
        return float("nan"), None
    cv2.setRNGSeed(seed)
    H, mask = cv2.findHomography(p_ref, p_cur, cv2.USAC_MAGSAC, thr_px, maxIters=max_iters,
                                 confidence=confidence)
    if H is None or mask is None:
        return 0.0, None
    return float(np.count_nonzero(mask)), H


def bearings(p: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Unit bearing vectors of pixel points of the ideal pinhole K."""
    f = np.empty((len(p), 3))
    f[:, 0] = (p[:, 0] - K[0, 2]) / K[0, 0]
    f[:, 1] = (p[:, 1] - K[1, 2]) / K[1, 1]
    f[:, 2] = 1.0
    return f / np.linalg.norm(f, axis=1, keepdims=True)


def parallax_deg(f_ref: np.ndarray, f_cur: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Angle between the bearings of each correspondence after removing the rotation R.

    With x_cur = R x_ref + t, a pure rotation makes R^T f_cur parallel to f_ref: angle 0.
    """
    c = np.clip(np.einsum("ij,ij->i", f_ref, f_cur @ R), -1.0, 1.0)  # f_cur @ R = (R^T f_cur)^T
    return np.degrees(np.arccos(c))


def midpoint_depths(f_ref: np.ndarray, f_cur: np.ndarray, R: np.ndarray, t: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Distances along each ray to the closest points of the two rays (midpoint method).

    Ray 1 is lambda1 * f_ref from the reference centre; ray 2 is c2 + lambda2 * R^T f_cur with
    c2 = -R^T t. Both positive: the point is in front of both cameras (cheirality).
    """
    d2 = f_cur @ R
    c2 = -(R.T @ t.reshape(3))
    b = np.einsum("ij,ij->i", f_ref, d2)
    e1 = f_ref @ c2
    e2 = d2 @ c2
    den = 1.0 - b * b  # |f| = |d| = 1
    with np.errstate(divide="ignore", invalid="ignore"):
        lam1 = (e1 - b * e2) / den
        lam2 = (b * e1 - e2) / den
    return lam1, lam2


def pose_information_condition(f_ref: np.ndarray, f_cur: np.ndarray, K: np.ndarray,
                               R: np.ndarray, t: np.ndarray,
                               min_parallax_deg: float = TRIANGULATION_GATE_DEG) -> float:
    """lambda_max / lambda_min of the 6x6 pose information J^T J at the inlier points.

    Monocular scale is unknown, so the units are fixed explicitly: rotation in radians,
    translation in units of the median scene depth (depths are scaled to median 1). A point's
    depth is its two-view triangulation when its parallax clears the 1 deg triangulation gate
    and it lies in front of both cameras; otherwise its depth is not observable
    from these two views and it is placed at the median depth of the triangulated points. When
    fewer than six points, or fewer than 10% of them, clear the gate (pure rotation, or a
    baseline too short to measure), the few that do are stray matches sliding along their
    epipolar lines: every point is then put at depth 1 and the translation, which is noise
    here, is taken as zero. J is the Jacobian of the pixel reprojection in the current view
    with respect to a left-multiplied SE(3) increment [rho, phi]: d(u, v)/d(P_c) times
    [I | -skew(P_c)] (docs/derivations.md §4).
    """
    n = len(f_ref)
    if n < 6:
        return float("nan")
    t = t.reshape(3)
    par = parallax_deg(f_ref, f_cur, R)
    lam1, lam2 = midpoint_depths(f_ref, f_cur, R, t)
    z1 = lam1 * f_ref[:, 2]
    good = np.isfinite(lam1) & (lam1 > 0) & (lam2 > 0) & (par >= min_parallax_deg)
    if np.count_nonzero(good) >= max(6, MIN_TRIANGULATED_SHARE * n):
        scale = float(np.median(z1[good]))
        t_s = t / scale
    else:  # no measurable baseline: unit depths, and t (pure noise here) is taken as zero
        scale, t_s = 1.0, np.zeros(3)
    depth = np.where(good, z1, scale) / scale  # along the optical axis, median scene depth ~ 1
    Pc = (f_ref / f_ref[:, 2:3] * depth[:, None]) @ R.T + t_s
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


def decompose(E: np.ndarray, f_ref: np.ndarray, f_cur: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rotation, unit translation and per-point parallax (deg) from E at its inliers.

    Of E's twisted pair of rotations, keep the one under which the bearings agree best
    (smallest median parallax). recoverPose chooses by cheirality instead, which is a coin
    toss when there is no translation (t is noise); under any real translation the twisted
    partner flips bearings away from the epipole, so both rules choose the same rotation.
    The sign of t is then chosen by cheirality: the sign that puts more points in front of
    both cameras.
    """
    R1, R2, t = cv2.decomposeEssentialMat(E)
    t = t.ravel()
    par1, par2 = parallax_deg(f_ref, f_cur, R1), parallax_deg(f_ref, f_cur, R2)
    R, par = (R1, par1) if np.median(par1) <= np.median(par2) else (R2, par2)
    lam1, lam2 = midpoint_depths(f_ref, f_cur, R, t)
    front = np.count_nonzero((lam1 > 0) & (lam2 > 0))
    behind = np.count_nonzero((lam1 < 0) & (lam2 < 0))
    return R, (t if front >= behind else -t), par


# Focal errors a rotation-only model may absorb: an approximate K (a guessed or nominal focal,
# a zoomed or re-scaled image) is commonly off by tens of percent; a factor of 2 either way
# covers a wrong guess between a wide and a normal lens without letting the focal grow so large
# that every motion looks like a small rotation (the residual is measured in pixels at the
# image's own scale, so a very long focal does not shrink it).
ROT_FOCAL_RANGE = (0.5, 2.0)
ROT_FOCAL_STEPS = 13
ROT_SEARCH_POINTS = 200


def rotation_only_fit(p_ref: np.ndarray, p_cur: np.ndarray, K: np.ndarray
                      ) -> tuple[float, float]:
    """How well a pure rotation explains the correspondences when K may be approximate.

    A camera that only turns maps every point by the homography K R K^-1, whatever the scene's
    depth (Hartley & Zisserman 2004, sec. 8.4.2): K^-1 H K is then a rotation. With an
    approximate K the de-rotated bearings keep a residual that grows with the rotation and the
    focal error, which reads as parallax although there is none. So the rotation is fitted at
    focal lengths from ROT_FOCAL_RANGE times the given one (principal point kept) and the
    smallest median transfer error in pixels is returned with the focal scale that gives it.
    A translating camera leaves a residual that no rotation and focal remove (depth-dependent
    parallax, or the expansion of an approach); a pure rotation leaves localisation noise.
    Every focal of a search step is fitted at once (stacked arrays, one batched SVD).
    """
    if len(p_ref) < E_SAMPLE:
        return float("nan"), float("nan")
    # the focal is searched on an evenly spaced subset (a median needs no more), coarse then
    # fine around the best scale; the residual reported is over every correspondence
    sub = np.linspace(0, len(p_ref) - 1, min(len(p_ref), ROT_SEARCH_POINTS)).astype(np.intp)
    lo, hi = np.log(ROT_FOCAL_RANGE[0]), np.log(ROT_FOCAL_RANGE[1])
    grid = np.linspace(lo, hi, ROT_FOCAL_STEPS)
    step = grid[1] - grid[0]
    res = _rotation_residuals_px(p_ref[sub], p_cur[sub], K, np.exp(grid))
    best_log = float(grid[int(np.argmin(res))])  # first of equals, as a scan in order keeps
    best = float(res.min())
    fine = np.clip(best_log + np.linspace(-step, step, 5), lo, hi)
    res_fine = _rotation_residuals_px(p_ref[sub], p_cur[sub], K, np.exp(fine))
    if float(res_fine.min()) < best:
        best_log = float(fine[int(np.argmin(res_fine))])
        best = float(res_fine.min())
    s_best = float(np.exp(best_log))
    if len(sub) == len(p_ref):  # the subset was every correspondence: that is the residual
        return best, s_best
    return float(_rotation_residuals_px(p_ref, p_cur, K, np.array([s_best]))[0]), s_best


def _rotation_residuals_px(p_ref: np.ndarray, p_cur: np.ndarray, K: np.ndarray,
                           scales: np.ndarray) -> np.ndarray:
    """Per focal scale: the median transfer error (px) of the best rotation
    x_cur ~ K_s R K_s^-1 x_ref, with one re-fit without the points beyond three times the
    median (mismatches)."""
    fx, fy = K[0, 0] * scales, K[1, 1] * scales  # (S,)
    cx, cy = K[0, 2], K[1, 2]

    def bear(p: np.ndarray) -> np.ndarray:  # (S, N, 3) unit bearings at every focal
        f = np.empty((len(scales), len(p), 3))
        f[:, :, 0] = (p[None, :, 0] - cx) / fx[:, None]
        f[:, :, 1] = (p[None, :, 1] - cy) / fy[:, None]
        f[:, :, 2] = 1.0
        return f / np.linalg.norm(f, axis=2, keepdims=True)

    f_ref, f_cur = bear(p_ref), bear(p_cur)

    def wahba(w: np.ndarray) -> np.ndarray:  # (S, 3, 3) rotations, weights (S, N)
        U, _, Vt = np.linalg.svd((f_cur * w[:, :, None]).transpose(0, 2, 1) @ f_ref)
        d = np.sign(np.linalg.det(U @ Vt))
        d[d == 0] = 1.0
        D = np.zeros((len(scales), 3, 3))
        D[:, 0, 0] = D[:, 1, 1] = 1.0
        D[:, 2, 2] = d
        return U @ D @ Vt

    def transfer(R: np.ndarray) -> np.ndarray:  # (S, N) pixels
        q = f_ref @ R.transpose(0, 2, 1)
        with np.errstate(divide="ignore", invalid="ignore"):
            x = fx[:, None] * q[:, :, 0] / q[:, :, 2] + cx
            y = fy[:, None] * q[:, :, 1] / q[:, :, 2] + cy
        r = np.hypot(x - p_cur[None, :, 0], y - p_cur[None, :, 1])
        return np.where(q[:, :, 2] > 0, r, np.inf)

    res = transfer(wahba(np.ones(f_ref.shape[:2])))
    keep = res <= 3.0 * np.maximum(np.median(res, axis=1), 0.5)[:, None]
    refit = keep.sum(axis=1) >= E_SAMPLE
    if refit.any():
        res2 = transfer(wahba(keep.astype(float)))
        res = np.where(refit[:, None], res2, res)
    return np.median(res, axis=1)


def sampson_px(p_ref: np.ndarray, p_cur: np.ndarray, E: np.ndarray, K: np.ndarray
               ) -> np.ndarray:
    """Sampson distance (px) of each correspondence to the epipolar geometry of E: the
    first-order distance, in the joint image space of both points, to the nearest pair that
    satisfies x'^T F x = 0 with F = K^-T E K^-1 (Hartley & Zisserman 2004, sec. 4.2.6). With
    localisation noise sigma in each coordinate of both images it is |N(0, sigma^2)| for a
    correct E: median 0.674 sigma."""
    Ki = np.linalg.inv(K)
    F = Ki.T @ E @ Ki
    x1 = np.column_stack([p_ref, np.ones(len(p_ref))])
    x2 = np.column_stack([p_cur, np.ones(len(p_cur))])
    Fx1, Ftx2 = x1 @ F.T, x2 @ F
    num = np.abs(np.einsum("ij,ij->i", x2, Fx1))
    den = np.sqrt(Fx1[:, 0] ** 2 + Fx1[:, 1] ** 2 + Ftx2[:, 0] ** 2 + Ftx2[:, 1] ** 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(den > 0, num / den, np.inf)


def two_view(p_ref: np.ndarray, p_cur: np.ndarray, K: np.ndarray | None, *,
             sigma_px: float = 1.0, confidence: float = 0.999, max_iters: int = 1000,
             seed: int = 0, pose_information: bool = True,
             homography: bool = True) -> TwoView:
    """E (if K is known) and H with USAC_MAGSAC on the same correspondences, the pose from E,
    parallax and (unless ``pose_information`` is False) the pose information condition.
    ``homography`` False skips H (``inliers_h`` NaN); E does not depend on it (its RANSAC is
    seeded on its own). Points are undistorted pixel coordinates."""
    n = len(p_ref)
    p_ref = np.ascontiguousarray(p_ref, np.float64)
    p_cur = np.ascontiguousarray(p_cur, np.float64)
    inl_h, H = fit_homography(p_ref, p_cur, homography_threshold_px(sigma_px), confidence,
                              max_iters, seed) if homography else (float("nan"), None)
    if K is None or n < E_SAMPLE:
        return TwoView(n, inliers_h=inl_h, H=H)
    cv2.setRNGSeed(seed)
    E, mask = cv2.findEssentialMat(p_ref, p_cur, K, method=cv2.USAC_MAGSAC, prob=confidence,
                                   threshold=epipolar_threshold_px(sigma_px), maxIters=max_iters)
    if E is None or mask is None or E.shape != (3, 3):
        return TwoView(n, inliers_e=0.0, inliers_h=inl_h, inlier_ratio=0.0, H=H)
    sel = mask.ravel() > 0
    inl_e = int(np.count_nonzero(sel))
    w = inl_e / n
    if inl_e < E_SAMPLE:
        return TwoView(n, inliers_e=float(inl_e), inliers_h=inl_h, inlier_ratio=w,
                       inlier_mask=sel, H=H)
    f_ref, f_cur = bearings(p_ref[sel], K), bearings(p_cur[sel], K)
    R, t, par = decompose(E, f_ref, f_cur)
    rot = float(np.degrees(np.linalg.norm(cv2.Rodrigues(R)[0])))
    cond = pose_information_condition(f_ref, f_cur, K, R, t) if pose_information else math.nan
    return TwoView(n, inliers_e=float(inl_e), inliers_h=inl_h, inlier_ratio=w, rot_deg=rot,
                   parallax_med_deg=float(np.median(par)), pose_info_cond=cond,
                   t_dir=t / max(float(np.linalg.norm(t)), 1e-12), ok_e=True, inlier_mask=sel,
                   H=H, epi_residual_px=float(np.median(sampson_px(p_ref[sel], p_cur[sel], E,
                                                                     K))))
