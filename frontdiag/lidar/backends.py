"""Registration backends: point-to-plane ICP of a scan against the local map.

Both backends solve the same problem on the same inputs (the map's points and normals are
computed once, by :mod:`frontdiag.lidar.localmap`), so they differ only in the optimiser:

``small_gicp``  small_gicp's ``PLANE_ICP`` (pip ``small-gicp``, a core dependency). Default: on the
                benchmark scans it is several times faster than Open3D at the same accuracy.
``open3d``      Open3D's tensor ``icp`` with ``TransformationEstimationPointToPlane`` (optional
                extra ``frontdiag[open3d]``). Open3D's wheel links the system library
                libusb-1.0; when that is missing, the copy shipped by the ``libusb-package``
                wheel is preloaded, so no system package is needed.
"""

from __future__ import annotations

import ctypes
import importlib
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from frontdiag.errors import ConfigError, OptionalDependencyError

BACKENDS: tuple[str, ...] = ("auto", "small_gicp", "open3d")
DEFAULT_BACKEND = "small_gicp"


@dataclass(frozen=True)
class AlignResult:
    T: np.ndarray  # 4x4, map <- sensor
    iterations: int
    converged: bool
    fitness: float  # share of source points with a map point within the threshold at the end


class Target(Protocol):
    points: np.ndarray
    normals: np.ndarray
    version: int

    def sg_cloud(self) -> Any: ...
    def sg_tree(self) -> Any: ...


class Backend(Protocol):
    name: str

    def align(self, target: Target, source: np.ndarray, init: np.ndarray, max_corr_m: float,
              max_iterations: int) -> AlignResult: ...


class SmallGicpBackend:
    name = "small_gicp"

    def __init__(self, num_threads: int = 1) -> None:
        import small_gicp

        self._sg = small_gicp
        self.num_threads = num_threads

    def align(self, target: Target, source: np.ndarray, init: np.ndarray, max_corr_m: float,
              max_iterations: int) -> AlignResult:
        src = self._sg.PointCloud(np.ascontiguousarray(source, dtype=np.float64))
        res = self._sg.align(target.sg_cloud(), src, target.sg_tree(),
                             init_T_target_source=np.asarray(init, dtype=np.float64),
                             registration_type="PLANE_ICP",
                             max_correspondence_distance=float(max_corr_m),
                             num_threads=self.num_threads, max_iterations=int(max_iterations),
                             rotation_epsilon=1e-4, translation_epsilon=1e-4)
        return AlignResult(np.asarray(res.T_target_source), int(res.iterations),
                           bool(res.converged), int(res.num_inliers) / max(len(source), 1))


_OPEN3D: Any = None


def load_open3d() -> Any:
    """Import Open3D, preloading libusb-1.0 from ``libusb-package`` when the system lacks it."""
    global _OPEN3D
    if _OPEN3D is not None:
        return _OPEN3D
    hint = ("pip install 'frontdiag[open3d]' (Open3D and libusb-package), or use "
            "--lidar-backend small_gicp")
    try:
        _OPEN3D = importlib.import_module("open3d")
        return _OPEN3D
    except ModuleNotFoundError as exc:
        raise OptionalDependencyError("Open3D is not installed", hint=hint) from exc
    except (ImportError, OSError) as exc:
        if "libusb" not in str(exc):
            raise OptionalDependencyError(f"Open3D cannot load: {exc}", hint=hint) from exc
        first = exc
    try:
        libusb_package = importlib.import_module("libusb_package")
        path = libusb_package.get_library_path()
        if path is None:
            raise OSError("libusb-package ships no library for this platform")
        ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)
        _OPEN3D = importlib.import_module("open3d")
        return _OPEN3D
    except (ImportError, OSError) as exc:
        raise OptionalDependencyError(
            f"Open3D cannot load: {first}; the system library libusb-1.0 is missing and no "
            f"preloadable copy was found ({exc})",
            hint="pip install libusb-package (or apt-get install libusb-1.0-0), or use "
                 "--lidar-backend small_gicp") from exc


class Open3dBackend:
    name = "open3d"

    def __init__(self, num_threads: int = 1) -> None:
        self._o3d = load_open3d()
        self.num_threads = num_threads
        self._cache: tuple[int, int, Any] | None = None

    def _target(self, target: Target) -> Any:
        if self._cache is not None and self._cache[:2] == (id(target), target.version):
            return self._cache[2]
        o3c = self._o3d.core
        pc = self._o3d.t.geometry.PointCloud(o3c.Tensor(np.ascontiguousarray(target.points)))
        pc.point.normals = o3c.Tensor(np.ascontiguousarray(target.normals))
        self._cache = (id(target), target.version, pc)
        return pc

    def align(self, target: Target, source: np.ndarray, init: np.ndarray, max_corr_m: float,
              max_iterations: int) -> AlignResult:
        o3d = self._o3d
        reg = o3d.t.pipelines.registration
        src = o3d.t.geometry.PointCloud(o3d.core.Tensor(np.ascontiguousarray(source,
                                                                             dtype=np.float64)))
        crit = reg.ICPConvergenceCriteria(relative_fitness=1e-6, relative_rmse=1e-6,
                                          max_iteration=int(max_iterations))
        res = reg.icp(src, self._target(target), float(max_corr_m),
                      o3d.core.Tensor(np.asarray(init, dtype=np.float64)),
                      reg.TransformationEstimationPointToPlane(), crit)
        return AlignResult(res.transformation.numpy().astype(np.float64),
                           int(res.num_iterations), bool(res.converged), float(res.fitness))


def make_backend(name: str, num_threads: int = 1) -> Backend:
    """Backend by name; ``auto`` is :data:`DEFAULT_BACKEND` (chosen by measurement)."""
    if name == "auto":
        name = DEFAULT_BACKEND
    if name == "small_gicp":
        return SmallGicpBackend(num_threads)
    if name == "open3d":
        return Open3dBackend(num_threads)
    raise ConfigError(f"unknown LiDAR backend {name!r}; choose one of {', '.join(BACKENDS)}")
