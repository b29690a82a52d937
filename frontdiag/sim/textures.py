"""Procedural surface textures with the statistics of real warehouse surfaces.

Every texture is a ``uint8`` reflectance map (0 = black, 255 = white) generated from a seeded
``numpy.random.Generator``, so a scene is reproducible byte for byte. Natural surfaces have a
roughly 1/f amplitude spectrum; :func:`pink_noise` builds one by summing octaves of upsampled
white noise (cheap, and close enough to an FFT synthesis for feature detectors). Printed labels
carry glyphs drawn with OpenCV's Hershey fonts, which give FAST/ORB the sharp corners real print
gives them.

A texture's contrast decides whether a detector fires on it: ORB's default FAST threshold is 20
grey levels, so "blank" paint keeps its variation to a few levels (it stays blank under sensor
noise), while cardboard, print and scuffs span tens of levels.
"""

from __future__ import annotations

import string

import cv2
import numpy as np

_GLYPHS = string.ascii_uppercase + string.digits + "-/#"


def pink_noise(h: int, w: int, rng: np.random.Generator, *, finest: int = 2,
               slope: float = 1.0) -> np.ndarray:
    """Zero-mean noise with an amplitude spectrum ~ 1/f**slope, unit standard deviation.

    Octave ``k`` is white noise at 1/2**k of the resolution, upsampled bicubically, with
    amplitude 2**(k*slope); ``finest`` is the first octave (in texels, as a power of two) so the
    texture has no energy finer than the renderer can show without aliasing.
    """
    out = np.zeros((h, w), np.float32)
    k = max(0, int(np.log2(max(finest, 1))))
    while (h >> k) >= 2 and (w >> k) >= 2:
        sh, sw = (h >> k) + 2, (w >> k) + 2
        small = rng.standard_normal((sh, sw)).astype(np.float32)
        big = cv2.resize(small, (sw << k, sh << k), interpolation=cv2.INTER_CUBIC)
        out += big[:h, :w] * float(2.0 ** (k * slope))
        k += 1
    out -= out.mean()
    sd = float(out.std())
    return out / sd if sd > 0 else out


def _to_u8(x: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(x), 0, 255).astype(np.uint8)


def blank(h: int, w: int, rng: np.random.Generator, level: float = 150.0,
          contrast: float = 1.5) -> np.ndarray:
    """Fresh paint or polished concrete: smooth, a couple of grey levels of variation."""
    return _to_u8(level + contrast * pink_noise(h, w, rng, finest=16))


def scuffs(img: np.ndarray, rng: np.random.Generator, n: int, dark: float = 60.0,
           max_len: int = 60) -> None:
    """Draw ``n`` scuff marks (short dark strokes and blotches) into ``img`` in place."""
    h, w = img.shape
    for _ in range(n):
        x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
        if rng.random() < 0.6:
            ang = rng.uniform(0, np.pi)
            ln = rng.uniform(0.3, 1.0) * max_len
            p2 = (int(x + ln * np.cos(ang)), int(y + ln * np.sin(ang)))
            val = int(max(0, img[y, x] - rng.uniform(0.5, 1.0) * dark))
            cv2.line(img, (x, y), p2, val, int(rng.integers(1, 4)), cv2.LINE_AA)
        else:
            ax = (int(rng.integers(2, max(3, max_len // 4))), int(rng.integers(2, max(3, max_len // 6))))
            val = int(max(0, img[y, x] - rng.uniform(0.3, 0.8) * dark))
            cv2.ellipse(img, (x, y), ax, float(rng.uniform(0, 180)), 0, 360, val, -1, cv2.LINE_AA)


def concrete(h: int, w: int, rng: np.random.Generator, level: float = 120.0,
             contrast: float = 22.0, n_scuffs: int | None = None) -> np.ndarray:
    """Worn floor or wall: 1/f mottling plus scuffs; textured enough for FAST."""
    img = level + contrast * pink_noise(h, w, rng, finest=2)
    out = _to_u8(img)
    scuffs(out, rng, n_scuffs if n_scuffs is not None else max(4, h * w // 2500),
           dark=2.5 * contrast, max_len=max(8, min(h, w, 240) // 6))
    return out


def random_text(rng: np.random.Generator, n: int) -> str:
    return "".join(_GLYPHS[int(i)] for i in rng.integers(0, len(_GLYPHS), n))


_FONTS = (cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_COMPLEX,
          cv2.FONT_HERSHEY_TRIPLEX, cv2.FONT_HERSHEY_PLAIN)


def label(h: int, w: int, rng: np.random.Generator, *, paper: float = 235.0,
          ink: float = 25.0, barcode: bool = True) -> np.ndarray:
    """A printed bin label: paper, one or two lines of glyphs, and (optionally) a barcode.

    Layout, font and glyphs are drawn from ``rng``, so two labels share a look but not their
    corners — unless the caller reuses one label array, which is how repetition is built.
    """
    img = np.full((h, w), paper, np.float32) + 3.0 * pink_noise(h, w, rng, finest=4)
    out = _to_u8(img)
    lines = 1 if h < 30 or rng.random() < 0.5 else 2
    bar_top = 0.6 if barcode else 1.0
    for k in range(lines):
        font = _FONTS[int(rng.integers(0, len(_FONTS)))]
        scale = h / 70.0 * rng.uniform(0.6, 1.1) / (1.3 if lines == 2 else 1.0)
        n = max(2, int(w / (22 * scale + 1e-9)) - int(rng.integers(1, 4)))
        y = int((0.4 + 0.3 * k) * h * bar_top / 0.6) if lines == 2 else int(0.45 * h)
        cv2.putText(out, random_text(rng, n), (int(rng.uniform(0.03, 0.15) * w), y), font,
                    0.9 * scale, int(ink), max(1, round(2 * scale)), cv2.LINE_AA)
    if barcode:
        x = int(rng.uniform(0.04, 0.3) * w)
        x_end = int(rng.uniform(0.7, 0.96) * w)
        y0, y1 = int(0.62 * h), int(0.92 * h)
        unit = max(1, round(h / 70.0))
        while x < x_end:
            bw = int(rng.integers(1, 4)) * unit
            if rng.random() < 0.55:
                out[y0:y1, x:x + bw] = int(ink)
            x += bw
    cv2.rectangle(out, (0, 0), (w - 1, h - 1), int(paper - 60), max(1, int(h / 70.0)))
    return out


def logo(img: np.ndarray, rng: np.random.Generator, x: int, y: int, size: int,
         value: int) -> None:
    """A printed mark: a random filled polygon, circle or arrow, in place."""
    kind = rng.random()
    if kind < 0.45:
        n = int(rng.integers(3, 8))
        ang = np.sort(rng.uniform(0, 2 * np.pi, n))
        rad = size * rng.uniform(0.4, 1.0, n)
        pts = np.stack([x + rad * np.cos(ang), y + rad * np.sin(ang)], 1).astype(np.int32)
        cv2.fillPoly(img, [pts], value, cv2.LINE_AA)
    elif kind < 0.7:
        cv2.circle(img, (x, y), max(2, size // 2), value, max(1, size // 6), cv2.LINE_AA)
    else:
        cv2.arrowedLine(img, (x - size, y), (x + size, y + int(rng.integers(-size, size + 1))),
                        value, max(1, size // 5), cv2.LINE_AA, tipLength=0.4)


def cardboard(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """A carton face: brown-grey mottling, tape, printed glyphs and a shipping label."""
    base = float(rng.uniform(90, 150))
    img = _to_u8(base + 22.0 * pink_noise(h, w, rng, finest=2))
    tape = int(rng.integers(0, 2))
    if tape and h > 8:
        y = h // 2 + int(rng.integers(-h // 8 - 1, h // 8 + 1))
        cv2.rectangle(img, (0, y - max(1, h // 14)), (w - 1, y + max(1, h // 14)),
                      int(min(255, base + 40)), -1)
    scale = h / 120.0
    cv2.putText(img, random_text(rng, int(rng.integers(2, 6))),
                (int(rng.uniform(0.05, 0.4) * w), int(rng.uniform(0.25, 0.95) * h)),
                cv2.FONT_HERSHEY_DUPLEX, max(0.3, 1.1 * scale), int(base - 80),
                max(1, round(2 * scale)), cv2.LINE_AA)
    if rng.random() < 0.7 and w > 20 and h > 20:
        lh, lw = max(8, h // 4), max(12, w // 3)
        lab = label(lh, lw, rng)
        y, x = int(rng.integers(0, h - lh + 1)), int(rng.integers(0, w - lw + 1))
        img[y:y + lh, x:x + lw] = lab
    scuffs(img, rng, max(1, h * w // 4000), dark=40, max_len=max(6, min(h, w) // 4))
    return img


def poster(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """Safety signage and stencilled markings on a wall: big glyphs and stripes."""
    img = concrete(h, w, rng, level=150, contrast=14)
    n = max(1, (h * w) // 40000)
    for _ in range(n):
        ph, pw = int(rng.integers(h // 6 + 2, h // 2 + 3)), int(rng.integers(h // 6 + 2, h // 2 + 3))
        y, x = int(rng.integers(0, max(1, h - ph))), int(rng.integers(0, max(1, w - pw)))
        kind = rng.random()
        if kind < 0.4:
            sub = label(ph, pw, rng, barcode=False)
            img[y:y + ph, x:x + pw] = sub
        elif kind < 0.7:
            step = max(4, pw // 8)
            for k in range(-ph, pw, 2 * step):
                cv2.line(img, (x + k, y + ph), (x + k + ph, y), 30, step // 2 + 1, cv2.LINE_AA)
        else:
            cv2.putText(img, random_text(rng, 2), (x, y + ph), cv2.FONT_HERSHEY_DUPLEX,
                        ph / 30.0, 20, max(1, ph // 15), cv2.LINE_AA)
    return img


def upright(h: int, w: int, holes: float = 55.0, paint: float = 70.0) -> np.ndarray:
    """A steel upright: painted, punched holes every few centimetres (identical always).

    ``holes`` is how much darker the holes are than the ``paint``.
    """
    img = np.full((h, w), int(paint), np.uint8)
    step = max(4, w)
    for y in range(step // 2, h, step):
        cv2.rectangle(img, (w // 3, y), (2 * w // 3, y + max(1, step // 3)), int(paint - holes),
                      -1)
    img[:, :max(1, w // 8)] = min(255, int(paint + holes // 2))
    return img


def beam_label(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """A rack beam's location label: a barcode filling the paper, bars of 1-3 units.

    Bars repeat at a handful of widths, so most of a barcode's corners look like the next bar's.
    """
    img = np.full((h, w), 235, np.uint8)
    x, unit = int(0.06 * w), max(1, round(h / 70.0))
    while x < int(0.94 * w):
        bw = int(rng.integers(1, 4)) * unit
        if rng.random() < 0.55:
            img[int(0.15 * h):int(0.85 * h), x:x + bw] = 25
        x += bw
    return img


def bin_front(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """The front of a ventilated plastic crate: a regular grid of vent slots.

    The slots repeat every few centimetres, so the neighbourhood of one slot corner is the
    neighbourhood of the next: the pattern that makes nearest-neighbour matching ambiguous.
    """
    img = _to_u8(170 + 3.0 * pink_noise(h, w, rng, finest=4))  # light grey plastic
    rim = max(1, h // 10)
    img[:rim] = 70
    pitch = max(3, w // 4)
    hole_w, hole_h = max(1, pitch // 2), max(2, (2 * pitch) // 3)
    for y in range(rim + pitch // 3, h - hole_h, pitch):
        for x in range(pitch // 3, w - hole_w, pitch):
            img[y:y + hole_h, x:x + hole_w] = 35
    return img
