"""The local map: a sliding window of recent keyframe scans in the map frame.

A scan becomes a keyframe when the sensor has moved or turned enough since the last one; the map
is then rebuilt once (voxel grid, normals, KD-tree) and reused by every scan until the next
keyframe, so its cost is paid per keyframe, not per scan.
"""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np
import small_gicp

PLANAR_SPREAD = 0.1
PLANAR_FLAT = 0.05
PLANAR_RADIUS = 2.5


class LocalMap:
    def __init__(self, voxel_m: float, max_keyframes: int, normal_neighbors: int = 10,
                 num_threads: int = 1) -> None:
        self.voxel_m = voxel_m
        self.num_threads = num_threads
        self.normal_neighbors = normal_neighbors
        self._frames: deque[np.ndarray] = deque(maxlen=max_keyframes)
        self.points = np.zeros((0, 3))
        self.normals = np.zeros((0, 3))
        self.planar = np.zeros(0, dtype=bool)
        self.version = 0
        self._cloud: Any = None
        self._tree: Any = None

    def __len__(self) -> int:
        return len(self._frames)

    def insert(self, points_map: np.ndarray) -> None:
        """Add one keyframe (points already in the map frame) and rebuild."""
        self._frames.append(np.asarray(points_map, dtype=np.float64))
        merged = np.concatenate(list(self._frames), axis=0)
        cloud = small_gicp.voxelgrid_sampling(merged, self.voxel_m, self.num_threads)
        tree = small_gicp.KdTree(cloud, self.num_threads)
        small_gicp.estimate_normals(cloud, tree, self.normal_neighbors, self.num_threads)
        self._cloud, self._tree = cloud, tree
        self.points = np.asarray(cloud.points())[:, :3].copy()
        self.normals = np.asarray(cloud.normals())[:, :3].copy()
        self.planar = self._planarity()
        self.version += 1

    def _planarity(self) -> np.ndarray:
        """Which map points sit on a well-defined plane.

        A LiDAR ring seen at grazing incidence, or a single beam line on a far wall, gives a
        neighbourhood that is a line, not a patch: its "normal" is any direction perpendicular
        to the line and invents information along the line (in a corridor, along the very axis
        that is unconstrained). With covariance eigenvalues e0 <= e1 <= e2 of the neighbourhood,
        a point is planar when the patch is two-dimensional (e1 >= PLANAR_SPREAD * e2) and flat
        (e0 <= PLANAR_FLAT * e1), and compact: its neighbours lie within PLANAR_RADIUS voxels
        (on a dense surface they lie within ~1.8; farther neighbours mean sparse beam rings,
        and a ring climbing from a floor onto two walls looks like a tilted plane).
        """
        n = len(self.points)
        k = min(self.normal_neighbors, n)
        if k < 5:
            return np.zeros(n, dtype=bool)
        idx_l, sq_l = self._tree.batch_knn_search(self.points, k, self.num_threads)
        nb = self.points[np.asarray(idx_l, dtype=np.int64)]  # (n, k, 3)
        nb = nb - nb.mean(axis=1, keepdims=True)
        cov = np.einsum("nki,nkj->nij", nb, nb) / k
        e = np.linalg.eigvalsh(cov)
        compact = np.asarray(sq_l, dtype=np.float64)[:, -1] <= (PLANAR_RADIUS * self.voxel_m) ** 2
        return compact & (e[:, 1] >= PLANAR_SPREAD * e[:, 2]) & (e[:, 0] <= PLANAR_FLAT * e[:, 1])

    def sg_cloud(self) -> Any:
        return self._cloud

    def sg_tree(self) -> Any:
        return self._tree

    def nearest(self, query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Index of the nearest map point and the distance, for each query point."""
        idx_l, sq_l = self._tree.batch_nearest_neighbor_search(
            np.ascontiguousarray(query, dtype=np.float64), self.num_threads)
        idx = np.asarray(idx_l, dtype=np.uint64)
        found = idx < len(self.points)
        d = np.where(found, np.sqrt(np.asarray(sq_l, dtype=np.float64)), np.inf)
        return np.where(found, idx, 0).astype(np.int64), d
