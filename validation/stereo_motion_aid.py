"""Measured aids to the labels of `zed_lab`: how far the camera moves, how far away the scene
is, and how much of the view holds texture, from the source's stereo pair and tracking.

    python -m validation.stereo_motion_aid [--src /work/.mirror] > zed_aid.txt

Per frame of the left camera:

* motion: the camera's centre over the last 0.2 s and its rotation, from the ZED's own
  positional tracking (`SVO/data/groundtruth.tum`, TUM format, stamps equal to the image
  names); frames without a pose there print NaN;
* depth: the median depth of the valid disparities of OpenCV's semi-global block matcher on
  the rectified pair (baseline and focal length from `SVO/data/calib_stereo.txt`), over the
  pixels with texture enough to match;
* texture: how many cells of an 8 x 6 grid hold at least 5 corners of OpenCV's FAST
  (threshold 20, non-maximum suppression) on the full-resolution grey image, a stock detector,
  not frontdiag's.

The README's criteria read these numbers: healthy needs the centre to move at least 1 % of
the scene depth over 0.2 s and texture over most of the view (at least 24 of the 48 cells);
no rule of frontdiag is involved.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from validation.build import aid_source, checked, decode

NAME = "zed_lab"
WINDOW_S = 0.2
GRID = (8, 6)
CELL_CORNERS = 5


def textured_cells(gray: np.ndarray, fast: cv2.FastFeatureDetector) -> int:
    pts = np.array([k.pt for k in fast.detect(gray)]).reshape(-1, 2)
    h, w = gray.shape
    cx = np.minimum((pts[:, 0] * GRID[0] / w).astype(int), GRID[0] - 1)
    cy = np.minimum((pts[:, 1] * GRID[1] / h).astype(int), GRID[1] - 1)
    counts = np.bincount(cy * GRID[0] + cx, minlength=GRID[0] * GRID[1])
    return int((counts >= CELL_CORNERS).sum())


def quat_angle_deg(q1: np.ndarray, q2: np.ndarray) -> float:
    d = abs(float(np.dot(q1 / np.linalg.norm(q1), q2 / np.linalg.norm(q2))))
    return float(np.degrees(2.0 * np.arccos(min(d, 1.0))))


def main() -> int:
    rec, src = aid_source(NAME, __doc__ or "")
    calib = src.read("SVO/data/calib_stereo.txt").decode().split()
    focal, baseline = float(calib[1]), float(calib[-1])
    gt = {}
    for line in src.read("SVO/data/groundtruth.tum").decode().splitlines():
        v = line.split()
        if len(v) == 8:
            gt[int(v[0])] = (np.array(v[1:4], float), np.array(v[4:8], float))
    sgbm = cv2.StereoSGBM.create(minDisparity=0, numDisparities=128, blockSize=7,
                                 P1=8 * 49, P2=32 * 49, uniquenessRatio=10,
                                 speckleWindowSize=100, speckleRange=2)
    fast = cv2.FastFeatureDetector.create(20, True)
    stamps = [int(Path(e["path"]).stem) for e in rec["frames"]["files"]]
    for k, entry in enumerate(rec["frames"]["files"]):
        left = cv2.cvtColor(decode(checked(src, entry), entry["path"]), cv2.COLOR_BGR2GRAY)
        rpath = entry["path"].replace("image_0", "image_1")
        right = cv2.cvtColor(decode(src.read(rpath), rpath), cv2.COLOR_BGR2GRAY)
        disp = sgbm.compute(left, right).astype(np.float32) / 16.0
        valid = disp > 1.0
        depth = float(np.median(focal * baseline / disp[valid])) if valid.any() else np.nan
        cells = textured_cells(left, fast)
        t_us = stamps[k]
        back = [j for j in range(k, -1, -1) if (t_us - stamps[j]) >= WINDOW_S * 1e6]
        move = rot = np.nan
        if back and t_us in gt and stamps[back[0]] in gt:
            (p1, q1), (p0, q0) = gt[t_us], gt[stamps[back[0]]]
            move, rot = float(np.linalg.norm(p1 - p0)), quat_angle_deg(q0, q1)
        print(f"frame {k:3d}  baseline_0.2s {move * 100:6.2f} cm  rot_0.2s {rot:5.1f} deg  "
              f"depth_med {depth:.2f} m  ratio {move / depth:.4f}  textured_cells {cells:2d}/48")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
