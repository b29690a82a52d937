"""Measured aid to the exposure labels: the brightness ratio of the same surfaces between
consecutive frames of a built validation recording.

    python validation/label_aid.py [--with-clipped] /work/valdata/dev/churchill_print [more...]
    python validation/label_aid.py --check                       # labels against the aid
    python validation/label_aid.py --stride 2 /work/valdata/dev/kitti02_road.mcap
    python validation/label_aid.py --stride 2 --write-manifest   # every built recording

With ``--stride N`` each frame is compared with the frame N before it, the pair that
``frontdiag analyze --stride N`` compares. A gain that ramps 3-5 % a frame is under the step
line between neighbours and over it across two frames, so the labels of a gap cannot be derived
from those of its frames alone; ``--write-manifest`` stores, per recording, the gaps that
measure at least 6 % brighter or darker, or give no reading (``gap_brightness`` in
validation/manifest.json), and ``validation/score.py --stride N`` applies the exposure
criterion of the README to those pairs.

Per consecutive pair: OpenCV's own ORB (2000 features, not frontdiag's extractor), brute-force
Hamming matches with Lowe's ratio test (0.8), verified by a fundamental matrix (USAC MAGSAC,
1.5 px); over the verified matches, the median of the ratio of 9x9 patch means (current over
previous). The README's exposure criterion reads this number: at least 10 % brighter or darker
is a step, 6-10 % is left unlabelled. The ratio is independent of every rule of frontdiag; it
is printed with the number of verified matches it rests on (under 30 it is not used).

Patches holding a pixel at 0 or 255 in either frame are left out where at least 30 others
remain: a clipped pixel does not follow a gain change, so on sunny KITTI frames, where 79-90 %
of the matched patches hold a saturated pixel, the median of every patch read a +11 % step as
+6 % and a -15 % one as -9 % (README, "Labels", revision of 2026-11-29). `--with-clipped`
reads every patch, the aid's reading before that revision.

`--check` lists, per built recording labelled from this aid (all but the chequerboards, which
have their own), the frames whose labels
disagree with the exposure criterion as the aid reads it: a step not labelled, a step label
under the line, a healthy label at 6 % or more.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE.parent) not in sys.path:
    sys.path.insert(0, str(HERE.parent))

from frontdiag.io.readers import open_recording  # noqa: E402
from frontdiag.io.topics import choose_topics  # noqa: E402
from frontdiag.runner import iter_camera_frames  # noqa: E402
from validation.score import EXPOSURE_UNLABELLED_CHANGE  # noqa: E402

HALF = 4  # 9x9 patches
MIN_VERIFIED = 30  # a ratio resting on fewer verified matches is not used


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


MIN_UNCLIPPED = MIN_VERIFIED  # unclipped patches the ratio needs before it leaves out clipped ones


def pair_ratio(a: np.ndarray, b: np.ndarray, unclipped: bool = True) -> tuple[float, int]:
    """Median ratio of 9x9 patch means of frame b over frame a at verified matches, and the
    number of verified matches; with ``unclipped``, over the patches holding no clipped pixel
    where at least MIN_UNCLIPPED of them remain."""
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
        lit = keep & ~clipped(a, pa[ok]) & ~clipped(b, pb[ok])
        if lit.sum() >= MIN_UNCLIPPED:
            keep = lit
    if not keep.any():
        return float("nan"), int(ok.sum())
    return float(np.median(mb[keep] / ma[keep])), int(ok.sum())


GAP_LISTED = EXPOSURE_UNLABELLED_CHANGE
"""Gaps stored in the manifest: at least this much brighter or darker (the README's lower
exposure line, which validation/score.py reads them against; under it a gap of healthy frames
is healthy)."""


def gap_ratios(path: Path, n: int, unclipped: bool = True) -> list[tuple[int, float, int]]:
    """(frame k, brightness ratio of frame k over frame k - n, verified matches) for every k."""
    out = []
    with open_recording(Path(path)) as rec:
        ch = choose_topics(rec.topics, use_lidar=False)
        if ch.camera is None:
            return out
        back: list[np.ndarray] = []
        for f in iter_camera_frames(rec, ch.camera, ch.camera_type):
            if len(back) == n:
                r, m = pair_ratio(back[0], f.gray, unclipped)
                out.append((f.index, r, m))
                back.pop(0)
            back.append(f.gray)
    return out


def listed_gaps(ratios: list[tuple[int, float, int]]) -> list[list[Any]]:
    """The manifest's entries: [k, ratio] for the gaps at least GAP_LISTED brighter or darker,
    [k, null] for those with no reading (too few verified matches)."""
    out: list[list[Any]] = []
    for k, r, m in ratios:
        if not np.isfinite(r) or m < MIN_VERIFIED:
            out.append([k, None])
        elif abs(r - 1.0) >= GAP_LISTED:
            out.append([k, round(r, 4)])
    return out


def write_manifest(n: int, data: Path, manifest: Path) -> None:
    from validation.build import load_manifest, output_path

    m = load_manifest(manifest)
    for rec in m["recordings"]:
        path = output_path(data, rec)
        gaps = listed_gaps(gap_ratios(path, n))
        rec.setdefault("gap_brightness", {})[str(n)] = gaps
        print(f"{rec['name']}: {len(gaps)} gaps listed", flush=True)
    manifest.write_text(json.dumps(m, indent=1) + "\n")


OWN_AID = ("chessboard",)
"""Recordings whose exposure labels come from another aid (README, "Measured aids"): the
chequerboards' white squares."""


def label_disagreements(rec: dict[str, Any], ratios: list[tuple[int, float, int]]
                        ) -> list[str]:
    """Frames whose labels disagree with the exposure criterion read from ``ratios`` (stride
    1): a step (|r - 1| >= 10 %) not labelled ``exposure_step``, an ``exposure_step`` under
    10 %, a ``healthy`` frame at 6 % or more. Frames without a reading are not judged."""
    from validation.score import EXPOSURE_STEP_CHANGE, frame_labels

    labels = frame_labels(rec)
    out = []
    for k, r, m in ratios:
        if not np.isfinite(r) or m < MIN_VERIFIED:
            continue
        change, mine = abs(r - 1.0), labels[k] if k < len(labels) else set()
        if change >= EXPOSURE_STEP_CHANGE and "exposure_step" not in mine:
            out.append(f"frame {k}: {r - 1:+.1%}, a step, labelled {sorted(mine) or 'nothing'}")
        elif change < EXPOSURE_STEP_CHANGE and "exposure_step" in mine:
            out.append(f"frame {k}: {r - 1:+.1%}, under the step line, labelled exposure_step")
        elif change >= GAP_LISTED and "healthy" in mine:
            out.append(f"frame {k}: {r - 1:+.1%}, labelled healthy")
    return out


def check_labels(data: Path, manifest: Path, unclipped: bool) -> int:
    """Print the disagreements of every recording's labels with the aid; 1 if any."""
    from validation.build import load_manifest, output_path

    found = 0
    for rec in load_manifest(manifest)["recordings"]:
        if any(a in rec["name"] for a in OWN_AID):
            continue
        bad = label_disagreements(rec, gap_ratios(output_path(data, rec), 1, unclipped))
        found += len(bad)
        print(f"{rec['name']}: {len(bad)} disagreement(s)", flush=True)
        for line in bad:
            print(f"  {line}")
    return 1 if found else 0


def main(argv: list[str]) -> int:
    unclipped = "--with-clipped" not in argv
    n = 1
    if "--stride" in argv:
        i = argv.index("--stride")
        n = int(argv[i + 1])
        argv = argv[:i] + argv[i + 2:]
    if "--write-manifest" in argv:
        from validation.build import DEFAULT_OUT, MANIFEST

        write_manifest(n, DEFAULT_OUT, MANIFEST)
        return 0
    if "--check" in argv:
        from validation.build import DEFAULT_OUT, MANIFEST

        return check_labels(DEFAULT_OUT, MANIFEST, unclipped)
    paths = [a for a in argv if a not in ("--with-clipped", "--check")]
    if n > 1:
        for p in paths:
            for k, r, m in gap_ratios(Path(p), n, unclipped):
                print(f"{Path(p).name}  frame {k - n:3d} -> {k:3d}  ratio {r:6.3f}  ({m} "
                      "verified matches)")
        return 0
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
