"""Warehouse building blocks: floors, walls, shelving runs, the dock door, the dock corridor.

Every builder takes a ``detail`` factor that scales texel density with the image size (a
160x120 test render does not need 200 texels per metre), and a seeded generator. What a scene
contains decides its label, so each builder documents what a camera and a LiDAR can see in it:

- ``unique`` shelving: cartons of random size, depth and print in every bay — textured, 3D,
  unambiguous. Healthy for both sensors.
- ``repetitive`` shelving: every bay holds the same crates carrying literally the same texture
  array and the same barcode beam label, on identical uprights every 1.2 m (light paint, dark
  punched holes). These periodic patterns take the feature budget, so the feature count stays
  normal while their descriptors stop telling one copy, or one moment, from the next.
- ``labels`` shelving: blank shelf backs and plain uprights, plus one bank of printed labels at
  eye height on bins at staggered depths: all texture in one narrow band of the image.
- ``blank`` shelving: blank backs, plain uprights, no stock. Geometry for the LiDAR, nothing for
  a detector.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable

import numpy as np

from frontdiag.sim import textures as T
from frontdiag.sim.world import World

UPRIGHT_PITCH = 1.2
SHELF_DEPTH = 0.9
SHELF_HEIGHT = 3.2
LEVELS = (0.12, 1.0, 1.85, 2.7)
DOWN = [0.0, 0.0, -1.0]


class Builder:
    """Adds warehouse parts to a :class:`World` at a texel density scaled by ``detail``."""

    def __init__(self, world: World, rng: np.random.Generator, detail: float = 1.0) -> None:
        self.w = world
        self.rng = rng
        self.detail = float(np.clip(detail, 0.2, 2.0))
        # grey level of blank paint; every blank part stays within 4 levels of it, so no
        # corner between two blank parts reaches even the low FAST threshold (7) that a
        # frontend uses to refill empty cells
        self.plain = 150.0

    def ppm(self, base: float) -> float:
        return base * self.detail

    def _size(self, width_m: float, height_m: float, base_ppm: float) -> tuple[int, int]:
        p = self.ppm(base_ppm)
        return max(4, round(height_m * p)), max(4, round(width_m * p))

    # -- surfaces ------------------------------------------------------------------------
    def floor(self, x0: float, x1: float, y0: float, y1: float, *, textured: bool = True,
              z: float = 0.0) -> None:
        h, w = self._size(x1 - x0, y1 - y0, 60)
        tex = (T.concrete(h, w, self.rng, level=115, contrast=22) if textured
               else T.blank(h, w, self.rng, level=self.plain - 3, contrast=1.0))
        self.w.quad([x0, y0, z], [1, 0, 0], [0, 1, 0], x1 - x0, y1 - y0, tex,
                    kind="floor" if textured else "blank")

    def ceiling(self, x0: float, x1: float, y0: float, y1: float, z: float = 6.0) -> None:
        h, w = self._size(x1 - x0, y1 - y0, 6)
        self.w.quad([x0, y0, z], [1, 0, 0], [0, 1, 0], x1 - x0, y1 - y0,
                    T.blank(h, w, self.rng, level=self.plain - 4, contrast=1.0), kind="blank")

    def wall_x(self, x0: float, x1: float, y: float, height: float = 6.0, *,
               style: str = "poster", facing: int = -1) -> None:
        """A wall along x at ``y``; ``style`` poster (signage, textured), concrete or blank."""
        h, w = self._size(x1 - x0, height, 80 if style != "blank" else 8)
        tex = self._wall_tex(h, w, style)
        if facing < 0:  # seen from -y side
            self.w.quad([x0, y, height], [1, 0, 0], DOWN, x1 - x0, height, tex, kind=style)
        else:
            self.w.quad([x1, y, height], [-1, 0, 0], DOWN, x1 - x0, height, tex, kind=style)

    def wall_y(self, y0: float, y1: float, x: float, height: float = 6.0, *,
               style: str = "poster", facing: int = -1) -> None:
        """A wall along y at ``x``; ``facing`` -1 is seen from the -x side."""
        h, w = self._size(y1 - y0, height, 80 if style != "blank" else 8)
        tex = self._wall_tex(h, w, style)
        if facing < 0:
            self.w.quad([x, y1, height], [0, -1, 0], DOWN, y1 - y0, height, tex, kind=style)
        else:
            self.w.quad([x, y0, height], [0, 1, 0], DOWN, y1 - y0, height, tex, kind=style)

    def _wall_tex(self, h: int, w: int, style: str) -> np.ndarray:
        if style == "poster":
            return T.poster(h, w, self.rng)
        if style == "concrete":
            return T.concrete(h, w, self.rng, level=140, contrast=10)
        return T.blank(h, w, self.rng, level=self.plain + 2, contrast=1.0)

    # -- shelving ------------------------------------------------------------------------
    def shelving(self, x0: float, x1: float, y_front: float, side: int, content: str, *,
                 bank: list[tuple[float, float]] | None = None) -> None:
        """A run of pallet racking along x, its front face at ``y_front``.

        ``side`` +1 puts the rack at y >= y_front (left of a robot driving +x along y=0),
        -1 at y <= y_front. ``content``: unique, repetitive, labels, blank (module docstring).
        ``bank`` lists the x ranges holding label banks.
        """
        s = float(side)
        yb = y_front + s * SHELF_DEPTH
        plain = content in ("labels", "blank")
        # back panel (blank shelf backs)
        h, w = self._size(x1 - x0, SHELF_HEIGHT, 8)
        back = T.blank(h, w, self.rng, level=self.plain, contrast=1.0)
        if s > 0:
            self.w.quad([x0, yb, SHELF_HEIGHT], [1, 0, 0], DOWN, x1 - x0, SHELF_HEIGHT, back,
                        kind="blank")
        else:
            self.w.quad([x1, yb, SHELF_HEIGHT], [-1, 0, 0], DOWN, x1 - x0, SHELF_HEIGHT, back,
                        kind="blank")
        ppm_u = self.ppm(200)
        rep = content == "repetitive"
        up_size = (max(8, int(SHELF_HEIGHT * ppm_u)), max(4, int(0.08 * ppm_u)))
        if plain:
            up_tex = T.blank(max(4, int(SHELF_HEIGHT * 20)), 4, self.rng, level=self.plain - 2,
                             contrast=1.0)
        elif rep:
            # light paint, dark punched holes: the holes are the upright's corners
            up_tex = T.upright(*up_size, holes=130.0, paint=150.0)
        else:
            up_tex = T.upright(*up_size, holes=12.0)
        beam_h = 0.1
        rep_cartons: list[np.ndarray] = []
        beam_tex_rep = np.zeros((1, 1), np.uint8)
        if rep:
            # the one beam label and the one crate (0.22 m x 0.2 m with its gaps) every bay
            # repeats
            beam_tex_rep = T.beam_label(*self._size(0.12, 0.06, 400), self.rng)
            ch, cw = self._size(0.22, 0.2, 300)
            tote = np.full((ch, cw), 60, np.uint8)
            gh, gw = max(1, ch // 10), max(1, cw // 11)
            tote[: ch - gh, : cw - gw] = T.bin_front(ch - gh, cw - gw, self.rng)
            rep_cartons = [tote]
        xs = np.arange(x0, x1 + 1e-6, UPRIGHT_PITCH)
        for xk in xs:
            lo = [xk - 0.04, min(y_front, y_front + s * 0.08), 0.0]
            hi = [xk + 0.04, max(y_front, y_front + s * 0.08), SHELF_HEIGHT]
            self.w.box(lo, hi, lambda hh, ww, t=up_tex: t, ppm=ppm_u,
                       faces="xX" + ("y" if s > 0 else "Y"), kind="blank" if plain else "upright")
        for zl in LEVELS:
            # beam across the whole run, just below the level
            bh, bw = self._size(x1 - x0, beam_h, 40)
            beam = T.blank(bh, bw, self.rng, level=self.plain - 1 if plain else 95,
                           contrast=1.0)
            zt = zl
            if s > 0:
                self.w.quad([x0, y_front, zt], [1, 0, 0], DOWN, x1 - x0, beam_h, beam, kind="blank")
            else:
                self.w.quad([x1, y_front, zt], [-1, 0, 0], DOWN, x1 - x0, beam_h, beam,
                            kind="blank")
            for xa, xb in itertools.pairwise(xs):
                self._bay(xa + 0.05, xb - 0.05, y_front, s, zl, content, bank,
                          rep_cartons, beam_tex_rep)

    def _bay(self, xa: float, xb: float, y_front: float, s: float, zl: float, content: str,
             bank: list[tuple[float, float]] | None, rep_cartons: list[np.ndarray],
             beam_label: np.ndarray) -> None:
        rng = self.rng
        faces = "xX" + ("y" if s > 0 else "Y") + "z"
        if content == "unique":
            x = xa + rng.uniform(0.0, 0.1)
            while x < xb - 0.2:
                wd = min(rng.uniform(0.25, 0.55), xb - x)
                ht = rng.uniform(0.25, 0.7)
                dp = rng.uniform(0.05, 0.45)
                d0 = y_front + s * dp
                d1 = y_front + s * min(SHELF_DEPTH - 0.05, dp + rng.uniform(0.3, 0.6))
                self.w.box([x, min(d0, d1), zl], [x + wd, max(d0, d1), zl + ht],
                           lambda hh, ww: T.cardboard(hh, ww, rng), ppm=self.ppm(160),
                           faces=faces, kind="carton")
                x += wd + rng.uniform(0.02, 0.2)
            lab = T.label(*self._size(0.12, 0.06, 400), rng)
            self._beam_label(xa + 0.1, y_front, s, zl, lab)
        elif content == "repetitive":
            # identical crates side by side and stacked four high: one quad per bay and level
            # whose texture is the same crate tile repeated, so the nearest copy of any corner
            # sits at the same depth a crate away and looks exactly the same
            n = int((xb - xa - 0.02) // 0.22)
            if n < 1:
                return
            tile = rep_cartons[0]
            reps = np.tile(tile, (4, n))
            y = y_front - s * 0.02 + s * 0.04
            width, height = n * 0.22, 4 * 0.2
            x0 = xa + 0.02
            if s > 0:
                self.w.quad([x0, y, zl + height], [1, 0, 0], DOWN, width, height, reps,
                            kind="repetitive")
            else:
                self.w.quad([x0 + width, y, zl + height], [-1, 0, 0], DOWN, width, height, reps,
                            kind="repetitive")
            self._beam_label(xa + 0.1, y_front, s, zl, beam_label)
        elif content == "labels":
            if not bank or not any(b0 <= xa < b1 for b0, b1 in bank) or zl != LEVELS[1]:
                return
            # rows of small bins with printed fronts, at staggered depths, from 0.72 m to
            # 1.6 m (eye height for the camera at 1.1 m); sizes, gaps and paper shades vary
            # so the bank is a cluster of distinct labels, not a grid of identical corners
            zr = 0.72
            while zr < 1.6:
                bh = float(rng.uniform(0.08, 0.13))
                x = xa + float(rng.uniform(0.0, 0.05))
                while x < xb - 0.12:
                    bw = float(rng.uniform(0.12, 0.24))
                    dp = float(rng.uniform(0.0, 0.7))
                    d0 = y_front + s * dp
                    d1 = y_front + s * (dp + 0.15)
                    paper = float(rng.uniform(190.0, 245.0))
                    self.w.box([x, min(d0, d1), zr], [x + bw, max(d0, d1), zr + bh],
                               lambda hh, ww, p=paper: T.label(hh, ww, rng, paper=p),
                               ppm=self.ppm(500), faces=("y" if s > 0 else "Y"), kind="label")
                    x += bw + float(rng.uniform(0.01, 0.06))
                zr += bh + float(rng.uniform(0.015, 0.04))

    def _beam_label(self, x: float, y_front: float, s: float, zl: float, tex: np.ndarray) -> None:
        y = y_front - s * 0.002
        if s > 0:
            self.w.quad([x, y, zl], [1, 0, 0], DOWN, 0.12, 0.06, tex, kind="label")
        else:
            self.w.quad([x + 0.12, y, zl], [-1, 0, 0], DOWN, 0.12, 0.06, tex, kind="label")

    def pallets(self, x: float, y: float, n: int) -> None:
        """A few stacks of cartons on the floor (3D texture for open areas)."""
        rng = self.rng
        for _ in range(n):
            cx, cy = x + rng.uniform(-1.5, 1.5), y + rng.uniform(-1.5, 1.5)
            sx, sy, sz = rng.uniform(0.6, 1.2), rng.uniform(0.6, 1.2), rng.uniform(0.5, 1.6)
            self.w.box([cx, cy, 0.0], [cx + sx, cy + sy, sz], lambda hh, ww: T.cardboard(hh, ww, rng),
                       ppm=self.ppm(120), kind="carton")


BuildFn = Callable[[Builder], None]
