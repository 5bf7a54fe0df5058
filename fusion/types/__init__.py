"""Leaf types and constants passed between drivers, estimators and sinks (SI units, body
frame): samples, the fused odometry record, and :mod:`~fusion.types.constants` (standard
gravity, the unobserved variance, the wheel-tick wire range).

Nothing here imports anything else of the project: drivers may import these and nothing more
of ``fusion``.
"""
