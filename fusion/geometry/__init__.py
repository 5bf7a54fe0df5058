"""Geometry with no state: quaternions (scalar first, body -> world), angles, and the
differential-drive kinematics (twist <-> wheel speeds <-> encoder ticks).

Pure math: nothing here imports the rest of the project but :mod:`fusion.types`, so drivers
may use it.
"""
