"""Two-view geometry on rendered scenes with known motion (docs/derivations.md §4)."""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import cache

import cv2
import numpy as np
import pytest

from frontdiag.camera import synthetic as S
from frontdiag.camera.features import OrbExtractor
from frontdiag.camera.frontend import CameraFrontend, CameraParams
from frontdiag.camera.geometry import two_view, undistort_points
from frontdiag.camera.matching import match
from frontdiag.records import CameraFrame, Intrinsics

SIZE = (800, 600)
K = S.look_K(*SIZE)


SCENES: dict[str, Callable[..., list[S.Plane]]] = {"room": S.room, "wall": S.wall,
                                                    "cluster": S.cluster}


@cache
def scene(name: str) -> list[S.Plane]:
    return SCENES[name](seed=1)


def view(name: str, R: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Camera with orientation R (world -> camera) and centre C."""
    return S.render(scene(name), K, R, -R @ C, SIZE)


def pair_row(name: str, R1: np.ndarray, C1: np.ndarray) -> dict:
    """Row of the second frame; the first one (identity pose) is the reference keyframe."""
    fe = CameraFrontend(CameraParams(), Intrinsics(K=K))
    fe.process(CameraFrame(0, 0, 0, "/cam", view(name, np.eye(3), np.zeros(3)), "mono8"))
    return fe.process(CameraFrame(1, 1, 0, "/cam", view(name, R1, C1), "mono8"))


def rel_motion(R1: np.ndarray, C1: np.ndarray) -> tuple[float, np.ndarray]:
    """Rotation angle and translation direction of x1 = R x0 + t for a camera at (R1, C1)."""
    t = -R1 @ C1
    return math.degrees(np.linalg.norm(cv2.Rodrigues(R1)[0])), t / np.linalg.norm(t)


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(float(np.clip(np.dot(a, b), -1, 1))))


@pytest.mark.parametrize(("axis", "deg", "C"), [
    ((0, 1, 0), 2.0, (0.15, 0.0, 0.25)),
    ((1, 0.3, 0), 1.5, (-0.2, 0.05, 0.1)),
    ((0, 0, 1), 3.0, (0.0, -0.1, 0.3)),
])
def test_rotation_and_translation_recovered_in_3d_scene(axis, deg, C) -> None:
    R1, C1 = S.rot(axis, deg), np.asarray(C, float)
    row = pair_row("room", R1, C1)
    assert row["status"] == "ok"
    assert abs(row["rot_deg"] - deg) < 0.5
    assert row["h_over_e"] < 0.9
    assert row["parallax_med_deg"] > 0.5
    assert row["inlier_ratio"] > 0.8
    assert row["ransac_iters_required"] <= row["ransac_iters_run"]
    # the translation direction, through the same pieces the frontend uses
    ex = OrbExtractor()
    f0 = ex.detect_and_compute(view("room", np.eye(3), np.zeros(3)))
    f1 = ex.detect_and_compute(view("room", R1, C1))
    m = match(f1.des, f0.des)
    tv = two_view(f0.xy[m.train], f1.xy[m.query], K)
    _, t_true = rel_motion(R1, C1)
    assert tv.t_dir is not None and angle_deg(tv.t_dir, t_true) < 3.0


@pytest.mark.parametrize("C", [(0.3, 0.0, 0.2), (0.2, 0.0, 0.2), (0.0, 0.0, 0.3)])
def test_planar_scene_is_flagged_by_h_over_e(C) -> None:
    row = pair_row("wall", S.rot((0, 1, 0), 1.0), np.asarray(C, float))
    assert row["h_over_e"] > 0.9
    # E is not identifiable on a plane (its rotation can be off), but the translation still
    # leaves parallax well above the pure-rotation level: the quadrant
    assert row["parallax_med_deg"] > 0.3


def test_pure_rotation_has_no_parallax() -> None:
    row = pair_row("room", S.rot((0.2, 1, 0), 3.0), np.zeros(3))
    assert row["parallax_med_deg"] < 0.1
    assert row["h_over_e"] > 0.9
    assert abs(row["rot_deg"] - 3.0) < 0.5


def test_clustered_features_have_low_entropy_and_ill_conditioned_pose() -> None:
    motion = (S.rot((0, 1, 0), 1.0), np.array([0.2, 0.0, 0.2]))
    spread = pair_row("room", *motion)
    clustered = pair_row("cluster", *motion)
    assert spread["entropy_norm"] > 0.9
    assert clustered["entropy_norm"] < 0.6
    assert clustered["occupied_cells"] < spread["occupied_cells"]
    assert spread["pose_info_cond"] < 200
    assert clustered["pose_info_cond"] > 10 * spread["pose_info_cond"]


def test_without_intrinsics_only_k_free_metrics_are_filled() -> None:
    fe = CameraFrontend(CameraParams(), None)
    fe.process(CameraFrame(0, 0, 0, "/cam", view("room", np.eye(3), np.zeros(3)), "mono8"))
    row = fe.process(CameraFrame(1, 1, 0, "/cam",
                                 view("room", S.rot((0, 1, 0), 1.0), np.array([0.1, 0, 0.2])),
                                 "mono8"))
    assert row["status"] == "no_intrinsics"
    assert row["n_matches"] > 100 and row["inliers_h"] > 0
    assert math.isfinite(row["photo_residual_med"]) and math.isfinite(row["entropy_norm"])
    for col in ("inliers_e", "h_over_e", "inlier_ratio", "rot_deg", "parallax_med_deg",
                "pose_info_cond", "ransac_iters_required", "ransac_iters_run"):
        assert math.isnan(row[col]), col


@pytest.mark.parametrize(("model", "D"), [
    ("plumb_bob", np.array([-0.28, 0.07, 0.0005, -0.0003, 0.0])),
    ("rational_polynomial", np.array([-0.2, 0.05, 0.0002, 0.0001, 0.0, 0.01, 0.002, 0.0])),
    ("equidistant", np.array([-0.01, 0.02, -0.005, 0.001])),
])
def test_keypoints_are_undistorted_to_the_ideal_pinhole(model: str, D: np.ndarray) -> None:
    rng = np.random.default_rng(3)
    ideal = rng.uniform([50, 50], [750, 550], (200, 2))
    rays = cv2.undistortPoints(ideal.reshape(-1, 1, 2), K, None).reshape(-1, 2)
    obj = np.column_stack([rays, np.ones(len(rays))]).reshape(-1, 1, 3)
    if model == "equidistant":
        distorted, _ = cv2.fisheye.projectPoints(obj, np.zeros(3), np.zeros(3), K, D)
    else:
        distorted, _ = cv2.projectPoints(obj, np.zeros(3), np.zeros(3), K, D)
    back = undistort_points(distorted.reshape(-1, 2).astype(np.float32),
                            Intrinsics(K=K, D=D, model=model))
    assert np.abs(back - ideal).max() < 0.05


def test_two_view_without_the_homography_gives_the_same_essential_reading() -> None:
    # the span reading skips H; E, its inliers, the pose and the residual must not change
    rng = np.random.default_rng(4)
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    X = np.column_stack([rng.uniform(-2, 2, 150), rng.uniform(-1.5, 1.5, 150),
                         rng.uniform(3, 9, 150)])
    R, _ = cv2.Rodrigues(np.array([0.0, 0.03, 0.01]))
    t = np.array([0.2, 0.0, 0.05])

    def project(P: np.ndarray) -> np.ndarray:
        q = P @ K.T
        return q[:, :2] / q[:, 2:]

    a = project(X) + rng.normal(0, 0.5, (150, 2))
    b = project(X @ R.T + t) + rng.normal(0, 0.5, (150, 2))
    full, bare = two_view(a, b, K), two_view(a, b, K, homography=False)
    assert full.ok_e and bare.ok_e and full.inliers_h > 0 and np.isnan(bare.inliers_h)
    assert bare.H is None
    for name in ("inliers_e", "rot_deg", "parallax_med_deg", "epi_residual_px", "pose_info_cond"):
        assert getattr(bare, name) == getattr(full, name), name
    assert np.array_equal(bare.inlier_mask, full.inlier_mask)
