"""The local map: a sliding window of recent keyframe scans in the map frame.

A scan becomes a keyframe when the sensor has moved or turned enough since the last one; the map
is then rebuilt once (voxel grid, normals, KD-tree) and reused by every scan until the next
keyframe, so its cost is paid per keyframe, not per scan.

Two clouds are kept. The *registration* cloud holds every keyframe point; the backends align
against it. The *scoring* cloud, from which fitness, RMSE and the degeneracy spectrum are read,
holds only points whose surface is measured: seen by more than one beam of their keyframe, and
lying on a compact, flat patch of the merged map. The reason is a property of spinning LiDARs:
one beam ring sweeping a floor and two walls traces a flat "U" across a corridor, which normal
estimation reads as a wall facing the sensor. Such a pseudo-surface has no registration cost to
speak of, but in J^T J it invents information along the corridor axis, exactly the direction
the spectrum exists to expose.
"""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np
import small_gicp

PLANAR_SPREAD = 0.1
"""A patch is two-dimensional when its middle covariance eigenvalue is at least this share of the
largest (a line has ~0)."""
PLANAR_FLAT = 0.05
"""A patch is flat when its smallest covariance eigenvalue is at most this share of the middle one:
an RMS plane-fit residual under ~22 % of the patch's smaller extent (1 cm noise on a 0.5 m patch
gives ~0.1 %)."""
PLANAR_RADIUS = 2.5
"""A patch is compact when its neighbours lie within this many voxels (on a dense surface they lie
within ~1.8)."""
RING_SPREAD_RAD = np.deg2rad(0.1)
"""A keyframe point is seen by more than one beam when the elevation angles of its neighbours, from
the keyframe's sensor, span at least this much: one ring spans ~0 (noise), two adjacent rings at
least the beam spacing (0.35 deg on a 128-beam sensor, 2 deg on a 16-beam one)."""


def _neighbours(points: np.ndarray, tree: Any, k: int, threads: int) -> tuple[np.ndarray,
                                                                               np.ndarray]:
    idx_l, sq_l = tree.batch_knn_search(points, k, threads)
    return np.asarray(idx_l, dtype=np.int64), np.asarray(sq_l, dtype=np.float64)


class LocalMap:
    def __init__(self, voxel_m: float, max_keyframes: int, normal_neighbors: int = 10,
                 num_threads: int = 1) -> None:
        self.voxel_m = voxel_m
        self.num_threads = num_threads
        self.normal_neighbors = normal_neighbors
        self._frames: deque[np.ndarray] = deque(maxlen=max_keyframes)
        self._measured: deque[np.ndarray] = deque(maxlen=max_keyframes)
        # registration cloud (what the backends read)
        self.points = np.zeros((0, 3))
        self.normals = np.zeros((0, 3))
        self.version = 0
        self._cloud: Any = None
        self._tree: Any = None
        # scoring cloud
        self.score_points = np.zeros((0, 3))
        self.score_normals = np.zeros((0, 3))
        self.score_planar = np.zeros(0, dtype=bool)
        self._score_tree: Any = None

    def __len__(self) -> int:
        return len(self._frames)

    def insert(self, points_map: np.ndarray, points_sensor: np.ndarray | None = None) -> None:
        """Add one keyframe and rebuild. ``points_sensor`` (the same points in the keyframe's
        sensor frame) enables the single-beam test; without it (2D scans) every point counts as
        measured."""
        pts = np.asarray(points_map, dtype=np.float64)
        self._frames.append(pts)
        measured = self._multi_beam(points_sensor) if points_sensor is not None \
            else np.ones(len(pts), dtype=bool)
        self._measured.append(pts[measured])
        self._cloud, self._tree = self._build(np.concatenate(list(self._frames), axis=0))
        self.points = np.asarray(self._cloud.points())[:, :3].copy()
        self.normals = np.asarray(self._cloud.normals())[:, :3].copy()
        merged = np.concatenate(list(self._measured), axis=0)
        if len(merged) >= self.normal_neighbors:
            cloud = small_gicp.voxelgrid_sampling(merged, self.voxel_m, self.num_threads)
            self._score_tree = small_gicp.KdTree(cloud, self.num_threads)
            self.score_points = np.asarray(cloud.points())[:, :3].copy()
            self.score_normals, self.score_planar = self._planarity(self.score_points,
                                                                    self._score_tree)
        else:
            self._score_tree = None
            self.score_points = np.zeros((0, 3))
            self.score_normals = np.zeros((0, 3))
            self.score_planar = np.zeros(0, dtype=bool)
        self.version += 1

    def _build(self, merged: np.ndarray) -> tuple[Any, Any]:
        """Voxel grid, KD-tree and normals of the registration cloud."""
        cloud = small_gicp.voxelgrid_sampling(merged, self.voxel_m, self.num_threads)
        tree = small_gicp.KdTree(cloud, self.num_threads)
        small_gicp.estimate_normals(cloud, tree, self.normal_neighbors, self.num_threads)
        return cloud, tree

    def _multi_beam(self, pts: np.ndarray) -> np.ndarray:
        """Points whose neighbourhood in their own keyframe spans more than one beam."""
        pts = np.ascontiguousarray(pts, dtype=np.float64)
        k = min(self.normal_neighbors, len(pts))
        if k < 3:
            return np.ones(len(pts), dtype=bool)
        idx, _ = _neighbours(pts, small_gicp.KdTree(pts, self.num_threads), k, self.num_threads)
        elev = np.arctan2(pts[:, 2], np.hypot(pts[:, 0], pts[:, 1]))[idx]
        return (elev.max(axis=1) - elev.min(axis=1)) >= RING_SPREAD_RAD

    def _planarity(self, points: np.ndarray, tree: Any) -> tuple[np.ndarray, np.ndarray]:
        """Normals (smallest principal direction of the k nearest neighbours) and which points
        sit on a compact, two-dimensional, flat patch (covariance eigenvalues e0 <= e1 <= e2:
        e1 >= PLANAR_SPREAD e2, e0 <= PLANAR_FLAT e1, k-th neighbour within PLANAR_RADIUS
        voxels)."""
        n = len(points)
        k = min(self.normal_neighbors, n)
        if k < 5:
            return np.zeros((n, 3)), np.zeros(n, dtype=bool)
        idx, sq = _neighbours(points, tree, k, self.num_threads)
        nb = points[idx]
        nb = nb - nb.mean(axis=1, keepdims=True)
        e, vec = np.linalg.eigh(np.einsum("nki,nkj->nij", nb, nb) / k)
        compact = sq[:, -1] <= (PLANAR_RADIUS * self.voxel_m) ** 2
        planar = compact & (e[:, 1] >= PLANAR_SPREAD * e[:, 2]) & (e[:, 0] <= PLANAR_FLAT * e[:, 1])
        return np.ascontiguousarray(vec[:, :, 0]), planar

    def sg_cloud(self) -> Any:
        return self._cloud

    def sg_tree(self) -> Any:
        return self._tree

    def nearest(self, query: np.ndarray, scoring: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Index of the nearest point of the scoring (or registration) cloud, and the distance
        (inf when that cloud is empty)."""
        tree, size = (self._score_tree, len(self.score_points)) if scoring \
            else (self._tree, len(self.points))
        if tree is None:
            return np.zeros(len(query), dtype=np.int64), np.full(len(query), np.inf)
        idx_l, sq_l = tree.batch_nearest_neighbor_search(
            np.ascontiguousarray(query, dtype=np.float64), self.num_threads)
        idx = np.asarray(idx_l, dtype=np.uint64)
        found = idx < size
        d = np.where(found, np.sqrt(np.asarray(sq_l, dtype=np.float64)), np.inf)
        return np.where(found, idx, 0).astype(np.int64), d
