"""Geometry with no state: quaternions (scalar first, body -> world), angle wrapping
(:mod:`~fusion.geometry.angles`), the IMU mount rotation and vertical rate
(:mod:`~fusion.geometry.mount`), the differential-drive kinematics (twist <-> wheel speeds <->
encoder ticks) and the dead-reckoning step (:mod:`~fusion.geometry.dead_reckoning`).

Pure math: nothing here imports the rest of the project but :mod:`fusion.types` (and the
optional numba wrapper :mod:`fusion._jit`), so drivers may use it.
"""
