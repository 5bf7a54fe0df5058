"""Hardware drivers and wire protocols: MPU6050 over I2C, the miiboo STM32 chassis link.

Nothing here runs at import time; import the submodule you need, e.g.
``from drivers.mpu6050 import MPU6050``.
"""
