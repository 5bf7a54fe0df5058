"""Planar estimation of a differential-drive robot: wheel dead reckoning, the robot
description and the EKF that fuses the gyro's vertical rate with the wheels.
"""
