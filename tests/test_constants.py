"""The shared constants have one definition, and their values follow their definitions."""

from __future__ import annotations

import subprocess
import sys

import pytest

import drivers.chassis
import drivers.mpu6050
import drivers.sim.mpu6050
import fusion.attitude.mahony
import fusion.calibration.imu
import fusion.evaluation.synthetic
import fusion.geometry.kinematics
import fusion.io.mpu6050_csv
import fusion.types.fused
from fusion.types import constants


def test_values_follow_their_definitions():
    assert constants.STANDARD_GRAVITY == 9.80665  # g_n, m/s^2 (3rd CGPM, 1901)
    assert constants.UNOBSERVED_VARIANCE == 99999.0  # seed 000's nav_msgs/Odometry filler
    assert constants.TICKS_MAX == 2**24 - 1  # a 24-bit magnitude behind a sign byte


def test_ticks_max_is_the_wire_limit():
    # DATA-uart2 field: sign byte (1 = +, 0 = -) then the 24-bit magnitude, big-endian
    frame = drivers.chassis.encode_wheel_frame(constants.TICKS_MAX, -constants.TICKS_MAX)
    assert frame[2:10] == bytes([0x01, 0xFF, 0xFF, 0xFF, 0x00, 0xFF, 0xFF, 0xFF])
    with pytest.raises(ValueError, match="24-bit"):
        drivers.chassis.encode_wheel_frame(constants.TICKS_MAX + 1, 0)


@pytest.mark.parametrize(("module", "name", "canonical"), [
    (drivers.chassis, "TICKS_MAX", "TICKS_MAX"),
    (fusion.geometry.kinematics, "TICKS_MAX", "TICKS_MAX"),
    (drivers.mpu6050, "STANDARD_GRAVITY", "STANDARD_GRAVITY"),
    (drivers.sim.mpu6050, "STANDARD_GRAVITY", "STANDARD_GRAVITY"),
    (fusion.attitude.mahony, "STANDARD_GRAVITY", "STANDARD_GRAVITY"),
    (fusion.calibration.imu, "STANDARD_GRAVITY", "STANDARD_GRAVITY"),
    (fusion.io.mpu6050_csv, "STANDARD_GRAVITY", "STANDARD_GRAVITY"),
    (fusion.evaluation.synthetic, "GRAVITY", "STANDARD_GRAVITY"),
    (fusion.types.fused, "UNOBSERVED_VARIANCE", "UNOBSERVED_VARIANCE"),
])
def test_public_names_are_the_canonical_constants(module, name, canonical):
    assert getattr(module, name) is getattr(constants, canonical)


def test_drivers_import_only_the_leaf_packages_of_fusion():
    code = (
        "import importlib, sys\n"
        "for m in ('drivers.chassis', 'drivers.mpu6050', 'drivers.serial_link',\n"
        "          'drivers.slamware', 'drivers.sim.mpu6050', 'drivers.sim.stm32',\n"
        "          'drivers.sim.robot'):\n"
        "    importlib.import_module(m)\n"
        "print(' '.join(sorted(k for k in sys.modules if k.startswith('fusion.'))))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out and all(m.startswith(("fusion.types", "fusion.geometry", "fusion._jit"))
                       for m in out), out
