"""16-bit thermal pictures through frontdiag's 8-bit mapping: keypoints with the bit shift
against the fixed window that pictures on a pedestal get (docs/camera.md, "16-bit pictures").

Reads every 16-bit single-channel image (TIFF or PNG) in a folder, and prints:

1. each picture mapped as if it were a recording's first frame (its own mapping): keypoints
   per picture with the shift and with the window, and how many would read as a detection
   failure (keypoint_fill under FD-DET-001's 0.3);
2. the window of one picture (``--first``, repeatable) applied to every picture: the mapping is
   fixed for a run, so this is what pictures far from the first one get.

The measurement in docs/camera.md used 60 frames of FLIR's ADAS dataset (a FLIR Tau2 on a car,
640x512, raw 14-bit counts), as published in github.com/ubiratantavares/LWIR-FPGA-Lossless-
Compression at commit 491655ade7161544e912fe978ece23fea2518f91, ``data/thermal_16_bit/
FLIR_00149.tiff`` to ``FLIR_00208.tiff`` (the repository has no licence file; the dataset
carries FLIR's own agreement, so the frames are not copied here). Consecutive files there are
not consecutive video frames (the set samples many clips), so nothing is matched: the figures
are of detection alone. From a snapshot of that repository (a bare git directory)::

    git --git-dir SNAPSHOT archive 491655ade7161544e912fe978ece23fea2518f91 \
        data/thermal_16_bit | tar -x
    python benchmarks/thermal_frames.py data/thermal_16_bit [--first 0 --first 10]

(the docs' figures are of FLIR_00149 to FLIR_00208, moved to a folder of their own).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from frontdiag.camera.features import OrbExtractor
from frontdiag.io.images import GrayConverter, mono16_mapping
from frontdiag.metrics import DEFAULT_FEATURE_BUDGET

FILL_FLOOR = 0.3  # FD-DET-001


def load(folder: Path) -> list[tuple[str, np.ndarray]]:
    out = []
    for f in sorted(folder.iterdir()):
        if f.suffix.lower() not in (".tif", ".tiff", ".png"):
            continue
        img = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
        if img is not None and img.dtype == np.uint16 and img.ndim == 2:
            out.append((f.name, img))
    return out


def fixed(first: np.ndarray) -> GrayConverter:
    conv = GrayConverter("/thermal")
    conv._mono16_to_8(first)  # fixes the mapping, as a run's first frame does
    return conv


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--first", type=int, action="append", default=None,
                    help="index of a picture whose mapping is applied to all (repeatable)")
    args = ap.parse_args()
    pics = load(args.folder) if args.folder.is_dir() else []
    if not pics:
        print(f"error: {args.folder}: no 16-bit single-channel TIFF or PNG", file=sys.stderr)
        return 2
    ex = OrbExtractor()
    h, w = pics[0][1].shape
    budget = DEFAULT_FEATURE_BUDGET * min(1.0, w * h / (1280 * 720))
    floor = FILL_FLOOR * budget

    def stats(n: np.ndarray) -> str:
        return (f"keypoints median {np.median(n):.0f} [p10 {np.percentile(n, 10):.0f}, p90 "
                f"{np.percentile(n, 90):.0f}]; detection failure (under {floor:.0f}) "
                f"{int((n < floor).sum())} of {len(n)}")

    shifted, windowed, spreads, pedestal = [], [], [], 0
    for _, img in pics:
        shift, window, _ = mono16_mapping(img)
        pedestal += window is not None
        p1, p99 = np.percentile(img, [1, 99])
        spreads.append(p99 - p1)
        shifted.append(len(ex.detect_and_compute((img >> shift).clip(0, 255).astype(np.uint8))))
        windowed.append(len(ex.detect_and_compute(fixed(img)._mono16_to_8(img))))
    print(f"{len(pics)} pictures {w}x{h} in {args.folder}; on a pedestal: {pedestal}; "
          f"1st-99th percentile spread {np.median(spreads):.0f} counts (median; "
          f"{min(spreads):.0f}-{max(spreads):.0f})")
    print("1. each picture with its own mapping")
    print("   shift:  " + stats(np.array(shifted)))
    print("   window: " + stats(np.array(windowed)))
    print("2. one picture's mapping for all")
    for k in args.first or [0]:
        conv = fixed(pics[k][1])
        n = np.array([len(ex.detect_and_compute(conv._mono16_to_8(img))) for _, img in pics])
        m = conv.mono16_map
        how = "?" if m is None else f"window {m.window}" if m.window else f"shift {m.shift}"
        print(f"   {pics[k][0]} ({how}): " + stats(n))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
