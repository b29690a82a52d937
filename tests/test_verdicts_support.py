"""Hand-made per-frame tables for the verdict tests (healthy values from the reference figures)."""

from __future__ import annotations

from typing import Any

import pandas as pd

HEALTHY_CAMERA: dict[str, Any] = dict(  # keypoint_fill is derived: budget 1000 at 1280x720
    width=1280, height=720, n_keypoints=1000, entropy_norm=0.85, entropy_inliers_norm=0.85, n_putative=900, ratio_reject_rate=0.30, n_matches=420,
    inliers_e=300, inliers_h=126, h_over_e=0.42, inlier_ratio=0.85, ransac_iters_required=12,
    ransac_iters_run=40, parallax_med_deg=2.1, rot_deg=1.0, pose_info_cond=50.0,
    mean_intensity=120.0, d_mean_intensity=0.5, photo_residual_med=4.0, affine_gain=1.0,
    in_frame_twin_rate=0.02, status="ok")
HEALTHY_LIDAR: dict[str, Any] = dict(
    n_points=20000, icp_fitness=0.95, icp_rmse_m=0.03, lidar_eig_min=2400.0, lidar_cond=35.0,
    lidar_weak_dir="none", status="ok")


def frames(n: int, changes: dict[int | range, dict[str, Any]] | None = None, *,
           sensor: str = "camera", topic: str | None = None, rate_hz: float = 30.0,
           t0_ns: int = 1_700_000_000_000_000_000) -> pd.DataFrame:
    """n healthy rows of one topic; `changes` maps a frame (or range) to overridden columns."""
    base = HEALTHY_CAMERA if sensor == "camera" else HEALTHY_LIDAR
    topic = topic or ("/camera/image_raw" if sensor == "camera" else "/lidar/points")
    rows = []
    for i in range(n):
        r = dict(base)
        r.update(frame=i, t_ns=t0_ns + int(i * 1e9 / rate_hz), t_rel_s=i / rate_hz,
                 sensor=sensor, topic=topic)
        if sensor == "camera":
            r["ref_frame"] = i - 1      # every frame its own reference unless a test says so
        for key, upd in (changes or {}).items():
            if (i in key) if isinstance(key, range) else i == key:
                r.update(upd)
        if sensor == "camera" and "keypoint_fill" not in r:  # 1280x720, budget 1000
            r["keypoint_fill"] = r["n_keypoints"] / 1000
        rows.append(r)
    return pd.DataFrame(rows)


def test_builder_makes_healthy_rows() -> None:
    t = frames(5, {2: {"n_keypoints": 120}})
    assert list(t["n_keypoints"]) == [1000, 1000, 120, 1000, 1000]
    assert t["t_ns"].is_monotonic_increasing
