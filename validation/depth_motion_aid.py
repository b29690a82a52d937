"""Measured aid to the motion labels of `realsense_office`: how far the camera's centre moves,
from the source's aligned depth images (not part of the built recording).

    python validation/depth_motion_aid.py [--src /work/.mirror] > rs_motion.txt

Per consecutive pair: OpenCV's own ORB (2000 features, not frontdiag's extractor), Lowe's ratio
test (0.8), 3D points from the previous frame's depth (millimetres: the depth reads 0.65 m on
the desk and 10 m across the office, a D435's range; an L515's quarter-millimetre unit would put
the desk at 16 cm), EPnP in RANSAC (2 px) refined by Levenberg-Marquardt, with the manifest's
approximate intrinsics. The relative poses are chained, and per frame the script prints the
camera centre's displacement over the last 0.2 s (6 frames at 30 Hz) and the median depth of
the matched points. The README's motion criterion reads these two numbers; no rule of frontdiag
is involved.
"""

from __future__ import annotations

import cv2
import numpy as np

from frontdiag.errors import ConfigError
from validation.build import aid_source, checked, decode

NAME = "realsense_office"
WINDOW_S = 0.2


def main() -> int:
    rec, src = aid_source(NAME, __doc__ or "")
    cam = rec["camera"]
    fx, fy, cx, cy = (float(cam[k]) for k in ("fx", "fy", "cx", "cy"))
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    win = round(WINDOW_S * float(rec["stamps"]["hz"]))
    cv2.setRNGSeed(0)
    orb = cv2.ORB.create(2000)
    bf = cv2.BFMatcher(cv2.NORM_HAMMING)
    poses = [np.eye(4)]  # frame-0 coordinates -> camera k
    depth_med = [float("nan")]
    prev = None
    for k, entry in enumerate(rec["frames"]["files"]):
        gray = cv2.cvtColor(decode(checked(src, entry), entry["path"]), cv2.COLOR_BGR2GRAY)
        dpath = entry["path"].replace("rgb/rgb", "depths/depth")
        try:  # the last colour frame has no depth image in the source
            depth = decode(src.read(dpath), dpath)
        except ConfigError:
            depth = None
        kp, des = orb.detectAndCompute(gray, None)
        rel, zmed = np.eye(4), float("nan")
        if prev is not None and des is not None and prev[1] is not None and prev[2] is not None:
            kp0, des0, d0 = prev[0], prev[1], prev[2]
            good = [p[0] for p in bf.knnMatch(des0, des, k=2)
                    if len(p) == 2 and p[0].distance < 0.8 * p[1].distance]
            p0 = np.array([kp0[g.queryIdx].pt for g in good]).reshape(-1, 2)
            p1 = np.array([kp[g.trainIdx].pt for g in good]).reshape(-1, 2)
            z = d0[p0[:, 1].astype(int), p0[:, 0].astype(int)] / 1000.0
            ok = (z > 0.2) & (z < 8.0)
            if ok.sum() >= 12:
                X = np.c_[(p0[ok, 0] - cx) * z[ok] / fx, (p0[ok, 1] - cy) * z[ok] / fy, z[ok]]
                found, rv, tv, inl = cv2.solvePnPRansac(X, p1[ok], K, None, iterationsCount=2000,
                                                        reprojectionError=2.0,
                                                        flags=cv2.SOLVEPNP_EPNP)
                if found and inl is not None and len(inl) >= 12:
                    i = inl[:, 0]
                    rv, tv = cv2.solvePnPRefineLM(X[i], p1[ok][i], K, None, rv, tv)
                    rel[:3, :3], rel[:3, 3] = cv2.Rodrigues(rv)[0], tv.ravel()
                    zmed = float(np.median(z[ok]))
            if np.isnan(zmed):
                print(f"frame {k:3d}  no pose (too few matches with depth)")
        if k:
            poses.append(rel @ poses[-1])
            depth_med.append(zmed)
        prev = (kp, des, depth)
    centres = np.array([-(T[:3, :3].T @ T[:3, 3]) for T in poses])
    for k in range(win, len(centres)):  # the first 0.2 s has no full window: unlabelled
        b = float(np.linalg.norm(centres[k] - centres[k - win]))
        print(f"frame {k:3d}  baseline_0.2s {b * 100:6.2f} cm  depth_med {depth_med[k]:.2f} m  "
              f"ratio {b / depth_med[k]:.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
