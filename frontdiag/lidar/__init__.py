"""LiDAR frontend: PointCloud2/LaserScan decoding, deskew, scan-to-map registration and the
degeneracy spectrum of the registration (see docs/lidar.md)."""

from frontdiag.lidar.decode import decode_laserscan, decode_pointcloud2
from frontdiag.lidar.frontend import EXTRA_COLUMNS, LidarFrontend, LidarParams

__all__ = ["EXTRA_COLUMNS", "LidarFrontend", "LidarParams", "decode_laserscan",
           "decode_pointcloud2"]
