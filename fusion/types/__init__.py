"""Leaf data types passed between drivers, estimators and sinks (SI units, body frame).

Nothing here imports anything else of the project: drivers may import these and nothing more
of ``fusion``.
"""
