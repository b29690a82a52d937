"""The simulated world: textured planar rectangles, shared by the camera and the LiDAR.

World frame: x forward along the main aisle, y to the left, z up, metres. Every visible thing is
a :class:`Surface` — a rectangle ``origin + s*eu + q*ev`` for ``0 <= s <= width`` and
``0 <= q <= height`` — carrying a ``uint8`` reflectance texture sampled at ``ppm`` texels per
metre (texture row index grows along ``ev``, column index along ``eu``). Boxes are five such
faces. The renderer splits large surfaces into tiles of at most :data:`TILE_M` metres so each
tile can use one mip level without aliasing; the LiDAR ray-casts the untiled surfaces.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import cv2
import numpy as np

TILE_M = 2.0


@dataclass(eq=False)
class Surface:
    """One textured rectangle in the world.

    ``radiance`` scales the texture (1.0: lit by the warehouse lights); ``emissive`` surfaces
    (daylight through a door) keep their radiance when the lights go out. ``kind`` names what
    the surface is (``floor``, ``label``, ``blank`` ...) for scenario bookkeeping.
    """

    origin: np.ndarray
    eu: np.ndarray
    ev: np.ndarray
    width: float
    height: float
    tex: np.ndarray
    ppm: float
    radiance: float = 1.0
    emissive: bool = False
    kind: str = "surface"
    facing: np.ndarray | None = None  # outward normal of a one-sided face (box faces)

    def __post_init__(self) -> None:
        self.origin = np.asarray(self.origin, np.float64)
        self.eu = np.asarray(self.eu, np.float64)
        self.ev = np.asarray(self.ev, np.float64)
        self.eu /= np.linalg.norm(self.eu)
        self.ev /= np.linalg.norm(self.ev)

    @cached_property
    def normal(self) -> np.ndarray:
        n = np.cross(self.eu, self.ev)
        return n / np.linalg.norm(n)

    @cached_property
    def reflectivity(self) -> float:
        return float(self.tex.mean()) / 255.0

    def corners(self) -> np.ndarray:
        o, u, v = self.origin, self.eu * self.width, self.ev * self.height
        return np.stack([o, o + u, o + u + v, o + v])


@dataclass(eq=False)
class Tile:
    """A piece of a surface small enough for one mip level; holds its texture pyramid."""

    surface: Surface
    origin: np.ndarray
    width: float
    height: float
    tex: np.ndarray
    index: int = 0
    _pyr: list[np.ndarray] = field(default_factory=list)

    def level(self, k: int) -> np.ndarray:
        if not self._pyr:
            self._pyr.append(np.ascontiguousarray(self.tex))
        while len(self._pyr) <= k:
            prev = self._pyr[-1]
            if min(prev.shape) < 4:
                break
            self._pyr.append(cv2.pyrDown(prev))
        return self._pyr[min(k, len(self._pyr) - 1)]


class World:
    """A list of surfaces plus the tiles the renderer draws."""

    def __init__(self, background: float = 0.25) -> None:
        self.surfaces: list[Surface] = []
        self.background = background
        self._tiles: list[Tile] | None = None
        self._arrays: dict[str, np.ndarray] | None = None
        self._sarrays: dict[str, np.ndarray] | None = None

    # -- building ------------------------------------------------------------------------
    def add(self, surface: Surface) -> Surface:
        self.surfaces.append(surface)
        self._tiles = None
        return surface

    def quad(self, origin: np.ndarray | list[float], eu: np.ndarray | list[float],
             ev: np.ndarray | list[float], width: float, height: float, tex: np.ndarray,
             *, radiance: float = 1.0, emissive: bool = False, kind: str = "surface",
             facing: list[float] | None = None) -> Surface:
        """Add a rectangle whose texture covers it exactly (``ppm`` from the texture width).

        ``facing`` makes it one-sided: only drawn when seen from that side.
        """
        ppm = tex.shape[1] / width
        return self.add(Surface(np.asarray(origin, float), np.asarray(eu, float),
                                np.asarray(ev, float), width, height, tex, ppm,
                                radiance=radiance, emissive=emissive, kind=kind,
                                facing=None if facing is None else np.asarray(facing, float)))

    def box(self, lo: list[float], hi: list[float], texfn, *, ppm: float,
            faces: str = "xXyYz", kind: str = "box", radiance: float = 1.0) -> None:
        """Add an axis-aligned box's faces; ``texfn(h, w)`` makes each face's texture.

        ``faces`` picks faces: x/X the -x/+x faces, y/Y the -y/+y faces, z the top.
        Vertical faces have their texture rows pointing down so printing reads upright.
        """
        x0, y0, z0 = lo
        x1, y1, z1 = hi
        down = [0.0, 0.0, -1.0]

        def add(o, eu, ev, w, h, out):
            tw, th = max(2, round(w * ppm)), max(2, round(h * ppm))
            self.quad(o, eu, ev, w, h, texfn(th, tw), kind=kind, radiance=radiance, facing=out)

        if "x" in faces:
            add([x0, y1, z1], [0, -1, 0], down, y1 - y0, z1 - z0, [-1, 0, 0])
        if "X" in faces:
            add([x1, y0, z1], [0, 1, 0], down, y1 - y0, z1 - z0, [1, 0, 0])
        if "y" in faces:
            add([x0, y0, z1], [1, 0, 0], down, x1 - x0, z1 - z0, [0, -1, 0])
        if "Y" in faces:
            add([x1, y1, z1], [-1, 0, 0], down, x1 - x0, z1 - z0, [0, 1, 0])
        if "z" in faces:
            add([x0, y0, z1], [1, 0, 0], [0, 1, 0], x1 - x0, y1 - y0, [0, 0, 1])

    # -- tiles ---------------------------------------------------------------------------
    @property
    def tiles(self) -> list[Tile]:
        if self._tiles is None:
            tiles: list[Tile] = []
            for surf in self.surfaces:
                th, tw = surf.tex.shape
                nu = max(1, min(int(np.ceil(surf.width / TILE_M)), tw // 2))
                nv = max(1, min(int(np.ceil(surf.height / TILE_M)), th // 2))
                for i in range(nu):
                    for j in range(nv):
                        c0, c1 = tw * i // nu, tw * (i + 1) // nu
                        r0, r1 = th * j // nv, th * (j + 1) // nv
                        if c1 - c0 < 2 or r1 - r0 < 2:
                            continue
                        s0, q0 = c0 / surf.ppm, r0 / surf.ppm
                        origin = surf.origin + surf.eu * s0 + surf.ev * q0
                        tiles.append(Tile(surf, origin, (c1 - c0) / surf.ppm,
                                          (r1 - r0) / surf.ppm, surf.tex[r0:r1, c0:c1],
                                          index=len(tiles)))
            self._tiles = tiles
            self._arrays = None
        return self._tiles

    def tile_arrays(self) -> dict[str, np.ndarray]:
        """Stacked tile geometry for vectorised culling: corners (N,4,3), facing (N,3)."""
        tiles = self.tiles
        if self._arrays is None:
            corners = np.stack([np.stack([t.origin, t.origin + t.surface.eu * t.width,
                                          t.origin + t.surface.eu * t.width
                                          + t.surface.ev * t.height,
                                          t.origin + t.surface.ev * t.height]) for t in tiles])
            facing = np.stack([t.surface.facing if t.surface.facing is not None
                               else np.zeros(3) for t in tiles])
            self._arrays = {"corners": corners, "facing": facing,
                            "centre": corners.mean(axis=1)}
        return self._arrays

    def surface_arrays(self) -> dict[str, np.ndarray]:
        """Stacked surface geometry for the LiDAR."""
        arrays = self._sarrays
        if arrays is None or len(arrays["origin"]) != len(self.surfaces):
            S = self.surfaces
            arrays = self._sarrays = {
                "origin": np.stack([s.origin for s in S]),
                "eu": np.stack([s.eu for s in S]), "ev": np.stack([s.ev for s in S]),
                "normal": np.stack([s.normal for s in S]),
                "size": np.array([[s.width, s.height] for s in S]),
                "refl": np.array([s.reflectivity for s in S]),
                "corners": np.stack([s.corners() for s in S]),
                "facing": np.stack([s.facing if s.facing is not None else np.zeros(3)
                                    for s in S]),
            }
        return arrays
