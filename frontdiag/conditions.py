"""The fixed condition vocabulary shared by the simulator's labels, the rules and the scorer."""

from __future__ import annotations

CONDITIONS: tuple[str, ...] = (
    "feature_clustering",
    "repetitive_structure",
    "planar_degeneracy",
    "exposure_step",
    "pure_rotation",
    "detection_failure",
    "registration_degeneracy",
    "ransac_starved",
)
HEALTHY = "healthy"
LABELS: tuple[str, ...] = (*CONDITIONS, HEALTHY)

DESCRIPTIONS: dict[str, str] = {
    "feature_clustering": "keypoints crowd into a few image cells; yaw and sideslip become confusable",
    "repetitive_structure": "features are fine but appearance is ambiguous (identical uprights, labels)",
    "planar_degeneracy": "correspondences lie on one plane; E is not identifiable, H explains them",
    "exposure_step": "auto-exposure stepped the gain; brightness constancy broke for a frame or two",
    "pure_rotation": "translation unobservable: rotation only, or a stationary camera",
    "detection_failure": "too few features: dark, blurred or blank view",
    "registration_degeneracy": "LiDAR registration cost is flat along some direction (corridor)",
    "ransac_starved": "RANSAC ran fewer iterations than the measured inlier ratio requires",
    "healthy": "none of the failures above",
}

# Which sensor's rows can show a condition. The scorer evaluates a condition on those rows only,
# so a LiDAR corridor label is not counted against camera frames recorded in the same interval.
CONDITION_SENSORS: dict[str, tuple[str, ...]] = {
    "feature_clustering": ("camera",),
    "repetitive_structure": ("camera",),
    "planar_degeneracy": ("camera",),
    "exposure_step": ("camera",),
    "pure_rotation": ("camera",),
    "detection_failure": ("camera",),
    "ransac_starved": ("camera",),
    "registration_degeneracy": ("lidar",),
    "healthy": ("camera", "lidar"),
}
