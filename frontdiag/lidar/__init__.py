"""frontdiag.lidar"""
