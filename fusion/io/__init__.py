"""Files in and out: robot.toml and the run configuration, log directories, IMU and MPU6050 CSV,
BROAD trials, ROS bags and MCAP files, DATA-uart2 captures.
"""
