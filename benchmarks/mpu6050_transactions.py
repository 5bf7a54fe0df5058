"""I2C transactions per MPU6050 sample: this driver vs the access patterns of two popular drivers.

Run: ``python benchmarks/mpu6050_transactions.py``

For each driver the script issues, against the register-level simulated chip
(``drivers.sim.mpu6050``), the bus operations that one sample (accelerometer, gyroscope and
temperature) costs, and reports:

- transactions per sample and bytes on the wire per sample (address, register and data bytes);
- the wire time per sample at 400 kHz (9 bits a byte plus start/stop), hence the most samples
  per second the bus could carry;
- samples per second through the simulated bus on this machine (Python overhead of the driver
  and the simulator, no real bus: a relative figure).

The peers are not installed or run: their per-sample access pattern is replayed from their
published code (cited in the output):

- m-rtijn/mpu6050 (PyPI mpu6050-raspberrypi), ``mpu6050/mpu6050.py``: ``get_all_data()`` calls
  ``get_temp()``, ``get_accel_data()``, ``get_gyro_data()``; each value comes from
  ``read_i2c_word()`` = two ``read_byte_data`` calls (high then low byte), and
  ``get_accel_data``/``get_gyro_data`` also read ACCEL_CONFIG/GYRO_CONFIG through
  ``read_accel_range``/``read_gyro_range``: 2 + (6 + 1) + (6 + 1) = 16 transactions.
- adafruit/Adafruit_CircuitPython_MPU6050, ``adafruit_mpu6050.py``: the ``acceleration`` and
  ``gyro`` properties index ``StructArray(reg, ">h", 3)`` three times, and in
  adafruit/Adafruit_CircuitPython_Register ``adafruit_register/i2c_struct_array.py``
  ``_BoundStructArray.__getitem__`` does one ``write_then_readinto`` per element; each property
  then reads its range through ``RWBits`` (``i2c_bits.py``, one ``write_then_readinto``);
  ``temperature`` is one ``ROUnaryStruct`` read: (3 + 1) + (3 + 1) + 1 = 9 transactions.

Both read the axes in separate transactions, so one "sample" can mix two sampling instants
(a torn sample); this driver's burst and FIFO reads cannot.
"""

from __future__ import annotations

import math
import time

from smbus2 import i2c_msg

from drivers.mpu6050 import MPU6050
from drivers.sim.mpu6050 import SimClock, SimulatedMPU6050

ADDR = 0x68
I2C_HZ = 400_000.0


def new_sim():
    sim = SimulatedMPU6050(clock=SimClock(), i2c_hz=I2C_HZ, gyro_noise_dps=0.05,
                           accel_noise_g=0.002)
    imu = MPU6050(sim, clock=sim.clock, dlpf=1, sample_rate_hz=1000, stuck_samples=0)
    return sim, imu


def m_rtijn_sample(sim):
    """m-rtijn get_all_data(): 16 single-byte reads."""
    for reg in (0x41, 0x42):  # get_temp -> read_i2c_word(TEMP_OUT0)
        sim.read_byte_data(ADDR, reg)
    for base, cfg in ((0x3B, 0x1C), (0x43, 0x1B)):  # get_accel_data, get_gyro_data
        for reg in range(base, base + 6):  # read_i2c_word per axis: high, low
            sim.read_byte_data(ADDR, reg)
        sim.read_byte_data(ADDR, cfg)  # read_accel_range / read_gyro_range(True)


def adafruit_sample(sim):
    """Adafruit acceleration + gyro + temperature: 9 write-then-read transactions."""

    def write_then_read(reg, n):
        sim.i2c_rdwr(i2c_msg.write(ADDR, [reg]), i2c_msg.read(ADDR, n))

    for base, cfg in ((0x3B, 0x1C), (0x43, 0x1B)):
        for i in range(3):  # StructArray[i]: one element of ">h"
            write_then_read(base + 2 * i, 2)
        write_then_read(cfg, 1)  # RWBits range read
    write_then_read(0x41, 2)  # ROUnaryStruct temperature


def measure(name, fn, sim, calls, idle_s):
    """Run ``fn`` (returns the samples it obtained) ``calls`` times, ``idle_s`` of simulated
    time passing before each call; per-sample transactions, wire time and wall rate."""
    tr0, wire0 = sim.transactions, sim.wire_time_s
    wall, n = 0.0, 0
    for _ in range(calls):
        sim.clock.sleep(idle_s)
        w0 = time.perf_counter()
        n += fn()
        wall += time.perf_counter() - w0
    return name, (sim.transactions - tr0) / n, (sim.wire_time_s - wire0) / n, n / wall


def main() -> None:
    rows = []
    sim, imu = new_sim()
    rows.append(measure("this driver: read() (one 14-byte burst)", lambda: imu.read() and 1,
                        sim, 2000,
                        idle_s=0.001))
    # Batches stay below the 85-frame FIFO: at 1 kHz and 400 kHz a 12-byte frame takes
    # 0.27 ms to read, so the idle time between reads is shortened by that much per frame to
    # keep the batch size steady (80-frame batches would overflow: 22 ms of transfer).
    for frames, rdwr in ((10, True), (40, True), (64, True), (64, False)):
        sim, imu = new_sim()
        imu.use_i2c_rdwr = rdwr
        imu.enable_fifo()
        how = "i2c_rdwr" if rdwr else "SMBus-only bus"
        rows.append(measure(f"this driver: read_fifo(), {frames} frames ({how})",
                            lambda imu=imu: len(imu.read_fifo().samples), sim, 200,
                            idle_s=frames * (1.0 - 12 * 9 / I2C_HZ * 1000) / 1000.0))
    sim, _ = new_sim()
    rows.append(measure("m-rtijn mpu6050: get_all_data()", lambda: m_rtijn_sample(sim) or 1, sim,
                        2000, idle_s=0.001))
    sim, _ = new_sim()
    rows.append(measure("Adafruit MPU6050: acceleration, gyro, temperature",
                        lambda: adafruit_sample(sim) or 1, sim, 2000, idle_s=0.001))

    ours = rows[0][1]
    print(f"{'driver / call':52s} {'trans/sample':>12s} {'x read()':>8s} {'wire us':>8s} "
          f"{'max S/s @400k':>13s} {'sim S/s':>9s}")
    for name, tr, wire, rate in rows:
        print(f"{name:52s} {tr:12.3f} {tr / ours:8.2f} {wire * 1e6:8.1f} {1 / wire:13.0f} "
              f"{rate:9.0f}")
    print()
    print("read() = 1 transaction per sample; read_fifo() = 3 per call whatever N (3/N per "
          "sample); on a bus without i2c_rdwr the FIFO data costs ceil(12 N / 32) block reads "
          f"({2 + math.ceil(12 * 64 / 32)} transactions for N = 64).")
    print("'sim S/s' is Python time through the simulated bus on this machine (driver + "
          "simulator), a relative figure; 'max S/s @400k' is the bus limit from wire time.")
    print("sources: m-rtijn/mpu6050 mpu6050/mpu6050.py: get_all_data, get_temp, get_accel_data,"
          " get_gyro_data, read_i2c_word, read_accel_range, read_gyro_range")
    print("         adafruit/Adafruit_CircuitPython_MPU6050 adafruit_mpu6050.py: "
          "MPU6050.acceleration, .gyro, .temperature; adafruit/Adafruit_CircuitPython_Register")
    print("         adafruit_register/i2c_struct_array.py _BoundStructArray.__getitem__ (one "
          "write_then_readinto per element), i2c_bits.py RWBits.__get__, i2c_struct.py "
          "ROUnaryStruct.__get__")


if __name__ == "__main__":
    main()
