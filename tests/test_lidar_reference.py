"""The reference registration worked examples, as oracles for the reference implementations."""

from __future__ import annotations

import numpy as np
import pytest

from frontdiag.lidar.reference import (
    best_rigid,
    best_rigid_2d,
    ndt_score,
    ndt_voxel,
    point_to_plane_translation_step,
    point_to_point_translation_step,
)

P = np.array([[0.0, 0.0], [2.0, 0.0], [1.0, 3.0]])
R_TRUE = np.array([[0.8, -0.6], [0.6, 0.8]])
Q = P @ R_TRUE.T + np.array([2.0, -1.0])


def test_three_point_closed_form_by_the_2d_shortcut() -> None:
    # The reference figures lists the third target point as (1.0, 1.4) and the target centroid as
    # (2.2, 0.2); R (1, 3) + t is (1.0, 2.0) and the centroid (2.2, 0.4). Its centred b_i, its
    # sums 4.8 and 6.4 and its t = (2, -1) all follow from the corrected values.
    np.testing.assert_allclose(Q, [[2.0, -1.0], [3.6, 0.2], [1.0, 2.0]], atol=1e-12)
    np.testing.assert_allclose(Q.mean(0), [2.2, 0.4], atol=1e-12)
    np.testing.assert_allclose(Q - Q.mean(0), [[-0.2, -1.4], [1.4, -0.2], [-1.2, 1.6]],
                               atol=1e-12)
    sol = best_rigid_2d(P, Q)
    assert sol.sum_cross == pytest.approx(4.8)
    assert sol.sum_dot == pytest.approx(6.4)
    assert np.rad2deg(sol.theta_rad) == pytest.approx(36.8699, abs=1e-4)
    np.testing.assert_allclose(sol.t, [2.0, -1.0], atol=1e-12)


def test_three_point_closed_form_by_svd_agrees() -> None:
    a = P - P.mean(0)
    b = Q - Q.mean(0)
    np.testing.assert_allclose(a.T @ b, [[1.6, 1.2], [-3.6, 4.8]], atol=1e-12)
    R, t = best_rigid(P, Q)
    np.testing.assert_allclose(R, R_TRUE, atol=1e-12)
    np.testing.assert_allclose(t, [2.0, -1.0], atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_reflection_guard_on_a_mirrored_configuration() -> None:
    mirrored = P * np.array([1.0, -1.0])  # a mirror image: the best orthogonal map is a reflection
    R_raw, _ = best_rigid(P, mirrored, guard=False)
    assert np.linalg.det(R_raw) == pytest.approx(-1.0)
    R, _ = best_rigid(P, mirrored)
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_reflection_guard_on_collinear_points() -> None:
    # points along a corridor wall: H has rank one, so the singular vectors across the line
    # are arbitrary and V U^T comes back a reflection for some headings
    A = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [3.0, 0.0, 0.0]])
    raw_dets = []
    for th in np.linspace(0.1, 3.0, 12):
        Rz = np.array([[np.cos(th), -np.sin(th), 0.0], [np.sin(th), np.cos(th), 0.0],
                       [0.0, 0.0, 1.0]])
        B = A @ Rz.T + np.array([0.5, 0.2, 0.0])
        R_raw, _ = best_rigid(A, B, guard=False)
        raw_dets.append(np.linalg.det(R_raw))
        R, t = best_rigid(A, B)
        assert np.linalg.det(R) == pytest.approx(1.0)
        np.testing.assert_allclose(A @ R.T + t, B, atol=1e-9)
    assert min(raw_dets) == pytest.approx(-1.0)  # without the guard, reflections do come back


WALL = np.array([[x, 0.0] for x in range(5)], dtype=float)
SOURCE = WALL + np.array([0.70, 0.10])


def test_point_to_point_step_slides_the_wrong_way() -> None:
    step = point_to_point_translation_step(SOURCE, WALL)
    np.testing.assert_allclose(step, [0.10, -0.10], atol=1e-12)  # x is +0.10; the truth is -0.70


def test_point_to_plane_step_is_exact_in_y_and_silent_in_x() -> None:
    normals = np.tile([0.0, 1.0], (5, 1))
    step = point_to_plane_translation_step(SOURCE, WALL, normals)
    assert step[1] == pytest.approx(-0.10, abs=1e-12)
    assert step[0] == pytest.approx(0.0, abs=1e-12)


def test_ndt_voxel_covariance_and_scores() -> None:
    pts = np.array([[0.1, 0.2], [0.3, 0.1], [0.2, 0.4], [0.5, 0.3], [0.4, 0.5]])
    mu, cov = ndt_voxel(pts)
    np.testing.assert_allclose(mu, [0.30, 0.30], atol=1e-12)
    np.testing.assert_allclose(cov, [[0.025, 0.0075], [0.0075, 0.025]], atol=1e-12)
    np.testing.assert_allclose(np.linalg.inv(cov), [[43.956, -13.187], [-13.187, 43.956]],
                               atol=1e-3)
    along = ndt_score(np.array([0.1, 0.1]), cov)
    across = ndt_score(np.array([0.1, -0.1]), cov)
    assert along == pytest.approx(0.735, abs=5e-4)
    assert across == pytest.approx(0.565, abs=5e-4)
