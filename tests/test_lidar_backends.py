"""Registration backends: selection, Open3D's load path, and small_gicp / Open3D agreement."""

from __future__ import annotations

import importlib

import numpy as np
import pytest
import small_gicp

from frontdiag.errors import ConfigError, OptionalDependencyError
from frontdiag.lidar import backends
from frontdiag.lidar.deskew import deskew
from frontdiag.lidar.frontend import score_alignment
from frontdiag.lidar.localmap import LocalMap
from frontdiag.lidar.se3 import inv, rotation_angle_deg, se3_exp
from frontdiag.lidar.synth import corridor_scene, hall_scene, spinning_scan

TWIST = np.array([0.0, 0.0, 0.05, 1.5, 0.0, 0.0])
VOXEL = 0.5


def open3d_or_skip() -> backends.Backend:
    try:
        return backends.make_backend("open3d")
    except OptionalDependencyError as exc:
        pytest.skip(f"Open3D unavailable: {exc}")


def prepared(scene: list, k: int) -> np.ndarray:
    """Scan k of a drive at 1.5 m/s, deskewed to mid-sweep with the true motion, downsampled."""
    xyz, t = spinning_scan(scene, beams=32, columns=1024, pose0=se3_exp(TWIST * 0.1 * k),
                           twist=TWIST, seed=k)
    keep = np.isfinite(xyz).all(axis=-1)
    pts, _ = deskew(xyz[keep], t[keep], TWIST, ref_s=0.05)
    return np.asarray(small_gicp.voxelgrid_sampling(pts, VOXEL).points())[:, :3]


@pytest.fixture(scope="module", params=["corridor", "hall"])
def case(request: pytest.FixtureRequest) -> tuple[str, LocalMap, np.ndarray, np.ndarray]:
    scene = corridor_scene() if request.param == "corridor" else hall_scene()
    lmap = LocalMap(VOXEL, 20)
    lmap.insert(*[prepared(scene, 0)] * 2)
    truth = se3_exp(TWIST * 0.3)  # scan 3 relative to scan 0 (both at mid-sweep)
    return request.param, lmap, prepared(scene, 3), truth


def test_both_backends_agree_on_pose_and_spectrum(case) -> None:
    name, lmap, src, truth = case
    o3d = open3d_or_skip()
    sg = backends.make_backend("small_gicp")
    init = truth @ se3_exp(np.array([0.0, 0.0, np.deg2rad(1.0), 0.10, -0.05, 0.02]))
    res = {b.name: b.align(lmap, src, init, 1.0, 30) for b in (sg, o3d)}
    a, b = res["small_gicp"].T, res["open3d"].T
    diff = inv(a) @ b
    scores = {k: score_alignment(lmap, src, r.T, 1.0) for k, r in res.items()}
    ea, eb = scores["small_gicp"]["lidar_eig_min"], scores["open3d"]["lidar_eig_min"]
    assert rotation_angle_deg(diff) < 0.1
    assert abs(res["small_gicp"].fitness - res["open3d"].fitness) < 0.02
    if name == "hall":
        # every direction is constrained: the same optimum to within a centimetre, and the
        # spectrum, which depends on the pose only through the correspondences, within 5 %
        assert np.linalg.norm(diff[:3, 3]) < 0.01
        assert np.linalg.norm((inv(truth) @ a)[:3, 3]) < 0.03
        assert abs(ea - eb) <= 0.05 * max(ea, eb)
        assert ea > 500
    else:
        # across the corridor the same optimum; along it the cost is flat, and any position
        # near the start is as good as another: the backends may differ there by up to the
        # 10 cm the initial guess was off, but both must see that there is no information
        assert np.linalg.norm(diff[1:3, 3]) < 0.01
        assert abs(diff[0, 3]) < 0.15
        assert ea < 50 and eb < 50
        assert abs(ea - eb) < 20
        for s in scores.values():
            assert s["lidar_cond"] > 900
            assert s["lidar_weak_dir"] == "translation along x (forward)"


def test_auto_is_the_measured_default() -> None:
    assert backends.DEFAULT_BACKEND == "small_gicp"
    assert backends.make_backend("auto").name == "small_gicp"


def test_unknown_backend_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match="unknown LiDAR backend"):
        backends.make_backend("pcl")


def test_missing_open3d_is_an_actionable_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(backends, "_OPEN3D", None)
    real_import = importlib.import_module

    def no_open3d(name: str, *args, **kwargs):
        if name == "open3d":
            raise ModuleNotFoundError("No module named 'open3d'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(backends.importlib, "import_module", no_open3d)
    with pytest.raises(OptionalDependencyError, match="Open3D is not installed") as info:
        backends.load_open3d()
    assert "frontdiag[open3d]" in (info.value.hint or "")


def test_open3d_without_libusb_anywhere_names_the_library(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(backends, "_OPEN3D", None)
    real_import = importlib.import_module

    def broken(name: str, *args, **kwargs):
        if name == "open3d":
            raise ImportError("libusb-1.0.so.0: cannot open shared object file")
        if name == "libusb_package":
            raise ModuleNotFoundError("No module named 'libusb_package'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(backends.importlib, "import_module", broken)
    with pytest.raises(OptionalDependencyError, match=r"libusb-1\.0") as info:
        backends.load_open3d()
    assert "libusb-package" in (info.value.hint or "")
