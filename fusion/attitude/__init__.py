"""Attitude estimation from a gyro, an accelerometer and optionally a magnetometer."""
