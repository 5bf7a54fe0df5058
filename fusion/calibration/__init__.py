"""Calibration from recordings: IMU biases and scales, odometry geometry (UMBmark)."""
