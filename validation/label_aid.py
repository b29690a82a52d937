"""Measured aid to the exposure labels: the brightness ratio of the same surfaces between
consecutive frames of a built validation recording.

    python validation/label_aid.py [--unclipped] /work/valdata/dev/churchill_print [more...]

Per consecutive pair: OpenCV's own ORB (2000 features, not frontdiag's extractor), brute-force
Hamming matches with Lowe's ratio test (0.8), verified by a fundamental matrix (USAC MAGSAC,
1.5 px); over the verified matches, the median of the ratio of 9x9 patch means (current over
previous). The README's exposure criterion reads this number: at least 10 % brighter or darker
is a step, 6-10 % is left unlabelled. The ratio is independent of every rule of frontdiag; it
is printed with the number of verified matches it rests on (under 30 it is not used).

`--unclipped` leaves out the patches holding a pixel at 0 or 255 in either frame (a clipped
pixel does not follow a gain change). The labels were measured without it; it measures how
much they depend on clipped patches (README: on sunny KITTI frames 79-90 % of the matched
patches hold a saturated pixel).
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

from frontdiag.io.readers import open_recording
from frontdiag.io.topics import choose_topics
from frontdiag.runner import iter_camera_frames

HALF = 4  # 9x9 patches


def patch_means(gray: np.ndarray, xy: np.ndarray) -> np.ndarray:
    integral = cv2.integral(gray.astype(np.float64))
    x = np.clip(np.rint(xy[:, 0]).astype(int), HALF, gray.shape[1] - HALF - 1)
    y = np.clip(np.rint(xy[:, 1]).astype(int), HALF, gray.shape[0] - HALF - 1)
    x0, x1, y0, y1 = x - HALF, x + HALF + 1, y - HALF, y + HALF + 1
    s = integral[y1, x1] - integral[y0, x1] - integral[y1, x0] + integral[y0, x0]
    return s / (2 * HALF + 1) ** 2


def clipped(gray: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Whether each 9x9 patch holds a pixel at 0 or 255."""
    bad = ((gray == 0) | (gray == 255)).astype(np.float64)
    return patch_means(bad, xy) > 0


def pair_ratio(a: np.ndarray, b: np.ndarray, unclipped: bool = False) -> tuple[float, int]:
    orb = cv2.ORB.create(2000)
    ka, da = orb.detectAndCompute(a, None)
    kb, db = orb.detectAndCompute(b, None)
    if da is None or db is None or len(ka) < 8 or len(kb) < 8:
        return float("nan"), 0
    knn = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(da, db, k=2)
    good = [m[0] for m in knn if len(m) == 2 and m[0].distance < 0.8 * m[1].distance]
    if len(good) < 8:
        return float("nan"), len(good)
    pa = np.float32([ka[m.queryIdx].pt for m in good])
    pb = np.float32([kb[m.trainIdx].pt for m in good])
    cv2.setRNGSeed(0)
    _, mask = cv2.findFundamentalMat(pa, pb, cv2.USAC_MAGSAC, 1.5, 0.999, 10000)
    if mask is None:
        return float("nan"), 0
    ok = mask.ravel().astype(bool)
    ma, mb = patch_means(a, pa[ok]), patch_means(b, pb[ok])
    keep = (ma > 5) & (mb > 5)
    if unclipped:
        keep &= ~clipped(a, pa[ok]) & ~clipped(b, pb[ok])
    if not keep.any():
        return float("nan"), int(ok.sum())
    return float(np.median(mb[keep] / ma[keep])), int(ok.sum())


def main(argv: list[str]) -> int:
    unclipped = "--unclipped" in argv
    paths = [a for a in argv if a != "--unclipped"]
    for p in paths:
        with open_recording(Path(p)) as rec:
            ch = choose_topics(rec.topics, use_lidar=False)
            if ch.camera is None:
                print(f"{p}: no camera topic")
                continue
            prev = None
            for f in iter_camera_frames(rec, ch.camera, ch.camera_type):
                if prev is not None:
                    r, n = pair_ratio(prev, f.gray, unclipped)
                    print(f"{Path(p).name}  frame {f.index:3d}  ratio {r:6.3f}  "
                          f"({n} verified matches)  frame mean {prev.mean():6.1f} -> "
                          f"{f.gray.mean():6.1f}")
                prev = f.gray
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
