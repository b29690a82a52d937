"""The degeneracy spectrum: its matrix against small_gicp's own Hessian, and its invariances."""

from __future__ import annotations

import numpy as np
import pytest
import small_gicp

from frontdiag.lidar.deskew import deskew
from frontdiag.lidar.localmap import LocalMap
from frontdiag.lidar.se3 import se3_exp
from frontdiag.lidar.spectrum import REFERENCE_POINTS, information_matrix, spectrum
from frontdiag.lidar.synth import hall_scene, spinning_scan

TWIST = np.array([0.0, 0.0, 0.05, 1.5, 0.0, 0.0])


def _scan(k: int) -> np.ndarray:
    xyz, t = spinning_scan(hall_scene(), beams=32, columns=1024, pose0=se3_exp(TWIST * 0.1 * k),
                           twist=TWIST, seed=k)
    keep = np.isfinite(xyz).all(axis=-1)
    pts, _ = deskew(xyz[keep], t[keep], TWIST, ref_s=0.05)
    return np.asarray(small_gicp.voxelgrid_sampling(pts, 0.5).points())[:, :3]


def test_information_matrix_is_small_gicps_point_to_plane_hessian() -> None:
    # same rows, same order (rotation, translation), same sensor-frame perturbation: with L = 1
    # and the registration's own correspondences, J^T J is the Hessian small_gicp solved with
    lmap = LocalMap(0.5, 20)
    first = _scan(0)
    lmap.insert(first, first)
    src = _scan(3)
    res = small_gicp.align(lmap.sg_cloud(), small_gicp.PointCloud(src), lmap.sg_tree(),
                           init_T_target_source=se3_exp(TWIST * 0.3),
                           registration_type="PLANE_ICP", max_correspondence_distance=1.0)
    T = np.asarray(res.T_target_source)
    idx, d = lmap.nearest(src @ T[:3, :3].T + T[:3, 3], scoring=False)
    inl = d <= 1.0
    assert int(inl.sum()) == res.num_inliers
    A = information_matrix(src[inl], lmap.normals[idx[inl]] @ T[:3, :3], 1.0)
    ours, theirs = np.linalg.eigvalsh(A), np.linalg.eigvalsh(np.asarray(res.H))
    np.testing.assert_allclose(ours, theirs, rtol=0.12)
    # the translation block is exactly sum n n^T in both
    np.testing.assert_allclose(np.diag(A)[3:], np.diag(np.asarray(res.H))[3:], rtol=0.01)


def _box(n_per_face: int = 400, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Points on the six faces of a 20 x 12 x 6 m box around the sensor, with their normals."""
    rng = np.random.default_rng(seed)
    half = np.array([10.0, 6.0, 3.0])
    pts, nrm = [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            p = rng.uniform(-half, half, size=(n_per_face, 3))
            p[:, axis] = sign * half[axis]
            n = np.zeros((n_per_face, 3))
            n[:, axis] = -sign
            pts.append(p)
            nrm.append(n)
    return np.concatenate(pts), np.concatenate(nrm)


def test_a_closed_box_constrains_everything() -> None:
    p, n = _box()
    s = spectrum(p, n)
    assert s is not None
    assert s.eig_min > 1000 and s.cond < 100


def test_a_floor_alone_leaves_x_y_and_yaw_free() -> None:
    p, n = _box()
    floor = n[:, 2] == 1.0
    s = spectrum(p[floor], n[floor])
    assert s is not None
    assert s.eig_min == pytest.approx(0.0, abs=1e-6)
    assert s.eigvals[2] == pytest.approx(0.0, abs=1e-6)  # three free directions
    free = np.abs(s.weak_vec[[0, 1, 5]])  # roll, pitch, z are constrained by a floor
    assert free.max() < 1e-6


def test_reported_scale_does_not_depend_on_point_count_or_scene_size() -> None:
    p, n = _box()
    base = spectrum(p, n)
    doubled = spectrum(np.concatenate([p, p]), np.concatenate([n, n]))
    larger = spectrum(3.0 * p, n)  # the same box, three times bigger: L grows with it
    assert base is not None and doubled is not None and larger is not None
    np.testing.assert_allclose(doubled.eigvals, base.eigvals, rtol=1e-9)
    np.testing.assert_allclose(larger.eigvals, base.eigvals, rtol=1e-9)
    # and the trace of the translation block is the reference point count (unit normals)
    A = information_matrix(p, n, base.length_m) * (REFERENCE_POINTS / len(p))
    assert np.trace(A[3:, 3:]) == pytest.approx(REFERENCE_POINTS)
