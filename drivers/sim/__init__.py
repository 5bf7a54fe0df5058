"""Simulated hardware for tests and the demo (register-level MPU6050, STM32 chassis firmware)."""
