"""Haptic SLAM mapper: log-odds occupancy grids at a known pose, and FastSLAM over finger joints."""
