"""Reference for the planar EKF: a plain filterpy ``ExtendedKalmanFilter`` driven by the model.

filterpy does the Kalman algebra of the prediction (``P = F P F^T + Q``) and of the absolute
yaw (``update``: ``inv(S)``, Joseph form, ``residual``); the rate measurements' update (a gain
with zero position rows and a yaw row limited by the yaw budget, Joseph form) is written here in
numpy with ``inv(S)``; :mod:`fusion.planar.model` gives f, F, Q and each sensor's h, H and R;
the filter's logic (time bookkeeping, late inputs, ZUPTs with the IMU motion codes, encoder
faults, slip gating, motion onset, saturated gyro, the yaw budget) is written here again from
:mod:`fusion.planar.ekf`'s description, with numpy, independently of
:mod:`fusion.planar._ekf_core`. Used by tests/test_ekf.py and
benchmarks/ekf_speed.py.
"""

from __future__ import annotations

import math

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter

from fusion.geometry.kinematics import DiffDriveParams
from fusion.planar import model
from fusion.planar.ekf import EkfNoise

__all__ = ["FilterpyReference"]

GYRO, WHEELS, YAW, TWIST = 0, 1, 2, 3
STILL, UNSURE, MOVING = 1, 2, 3  # fusion.planar.imu_motion


class FilterpyReference:
    """The planar EKF on ``filterpy.kalman.ExtendedKalmanFilter`` (not a subclass of it).

    ``step(kind, t, a, b)`` takes the events of :func:`fusion.planar.ekf.merge_events` and
    returns the same status codes as :meth:`fusion.planar.ekf.PlanarEKF.process_batch`;
    ``stats`` counts like :attr:`fusion.planar.ekf.PlanarEKF.stats`.
    """

    def __init__(self, robot: DiffDriveParams, noise: EkfNoise, x0, P0) -> None:
        self.robot = robot
        self.noise = noise
        self.kf = ExtendedKalmanFilter(dim_x=8, dim_z=2)
        self.kf.x = np.array(x0, dtype=float)
        self.kf.P = np.array(P0, dtype=float)
        self.t: float | None = None
        self.zero_count = 0
        self.imu_motion = 0
        self.in_fault = False
        self.wheel_t: float | None = None
        self.yaw_budget = noise.yaw_fix_burst
        self.stats = dict.fromkeys(("slips", "zupts", "late_dropped", "late_applied",
                                    "invalid", "gyro_saturated", "encoder_faults", "updates"),
                                   0)

    # -- time ------------------------------------------------------------------------------------
    def _predict(self, dt: float, still: bool) -> None:
        n, kf = self.noise, self.kf
        f = n.still_scale if still else 1.0
        kf.F = model.transition_jacobian(kf.x, dt)
        kf.Q = model.process_noise(dt, n.accel_psd * f, n.angular_accel_psd * f, n.bias_psd,
                                   n.calib_k_psd, n.calib_c_psd)
        kf.predict_x = lambda u=0: setattr(kf, "x", model.transition(kf.x, dt))
        kf.predict()

    def _advance(self, t: float) -> bool:
        n = self.noise
        if self.t is None:
            self.t = t
            return True
        dt = t - self.t
        if dt < 0:
            if -dt <= n.late_tolerance:
                self.stats["late_applied"] += 1
                return True
            self.stats["late_dropped"] += 1
            return False
        still = self.zero_count >= n.zupt_frames
        if dt > 0:
            self.yaw_budget = min(self.yaw_budget + n.yaw_fix_rate * dt, n.yaw_fix_burst)
        while dt > 0:
            h = min(dt, n.max_dt)
            self._predict(h, still)
            dt -= h
        self.t = t
        return True

    def _rate_update(self, y, H, R) -> None:
        """Rate measurement: no position correction, the yaw correction within the budget."""
        kf = self.kf
        S = H @ kf.P @ H.T + R
        K = kf.P @ H.T @ np.linalg.inv(S)
        K[0:2] = 0.0
        dyaw = float(K[2] @ y)
        if abs(dyaw) > self.yaw_budget:
            K[2] *= self.yaw_budget / abs(dyaw)
        yaw = kf.x[2]
        kf.x = kf.x + K @ y
        IKH = np.eye(8) - K @ H
        kf.P = IKH @ kf.P @ IKH.T + K @ R @ K.T
        self.yaw_budget = max(self.yaw_budget - abs(kf.x[2] - yaw), 0.0)

    # -- one event -------------------------------------------------------------------------------
    def step(self, kind: int, t: float, a: float, b: float) -> int:
        n, kf, r = self.noise, self.kf, self.robot
        if not (math.isfinite(t) and math.isfinite(a) and math.isfinite(b)):
            self.stats["invalid"] += 1
            return 6
        if not self._advance(t):
            return 5
        status = 0
        if kind == GYRO:
            self.imu_motion = int(b) if b in (STILL, UNSURE, MOVING) else 0
            if abs(a) >= n.gyro_limit:
                self.stats["gyro_saturated"] += 1
                return 2
            H = model.gyro_jacobian(kf.x)
            R = model.gyro_noise(n.gyro_std ** 2)
            if self.zero_count >= n.zupt_frames:
                s = (H @ kf.P @ H.T + R)[0, 0]
                if ((a - model.gyro_h(kf.x)[0]) ** 2 / s > n.slip_gate
                        or self.imu_motion == MOVING):
                    self.zero_count = 0
                    kf.P[4, 4] += n.angular_accel_psd * r.encode_sampling_time
            self._rate_update(np.array([a]) - model.gyro_h(kf.x), H, R)
        elif kind in (WHEELS, TWIST):
            in_fault, self.in_fault = self.in_fault, False
            interval = r.encode_sampling_time
            if self.wheel_t is not None and t - self.wheel_t > 0:
                interval = t - self.wheel_t
            if kind == WHEELS:
                still = a == 0 and b == 0
            else:
                still = abs(a) <= n.twist_zero_v and abs(b) <= n.twist_zero_w
            if still:
                # zero speed: an encoder fault when the IMU moves, or (unless the IMU is still)
                # when stopping since the last frame would need more than stop_decel
                since = r.encode_sampling_time
                if self.wheel_t is not None:
                    since = max(since, t - self.wheel_t)
                hard = abs(kf.x[3]) > n.stop_decel * since + 3 * math.sqrt(kf.P[3, 3])
                self.wheel_t = t
                creep = (2 * r.speed_ratio / r.encode_sampling_time if kind == WHEELS
                         else 2 * n.twist_zero_v)
                turning = abs(kf.x[3]) + 0.5 * r.wheel_distance * abs(kf.x[4]) > creep
                if ((self.imu_motion == MOVING and turning)
                        or (in_fault and self.imu_motion in (UNSURE, MOVING))
                        or (self.imu_motion != STILL and hard)):
                    self.zero_count = 0
                    self.stats["encoder_faults"] += 1
                    self.in_fault = True
                    return 7
            else:
                self.wheel_t = t
                if self.zero_count >= n.zupt_frames:  # motion onset: v's freedom back
                    kf.P[3, 3] += n.accel_psd * r.encode_sampling_time
            self.zero_count = self.zero_count + 1 if still else 0
            if self.zero_count >= n.zupt_frames and self.imu_motion in (0, STILL):
                H = model.zupt_jacobian(kf.x)
                self._rate_update(-model.zupt_h(kf.x), H,
                                  model.zupt_noise(n.zupt_v_std, n.zupt_w_std))
                status = 4
                self.stats["zupts"] += 1
            else:
                L = r.wheel_distance
                if kind == WHEELS:
                    z, R = model.ticks_measurement(a, b, r.speed_ratio, r.encode_sampling_time,
                                                   L, n.tick_std, n.scale_std,
                                                   n.separation_std, n.wheel_w_std)
                else:
                    z, R = model.twist_measurement(a, b, n.twist_v_std, n.twist_w_std,
                                                   n.scale_std, n.separation_std,
                                                   n.wheel_w_std)
                R = R.copy()
                R[1, 1] += (n.turn_w_std * kf.x[4]) ** 2  # turns: relative to the state's rate
                inflate = n.wheel_w_corr_time / interval  # correlated yaw-rate error
                if inflate > 1:
                    R[1, 1] *= inflate
                    R[0, 1] = R[1, 0] = R[0, 1] * math.sqrt(inflate)
                H = model.wheel_jacobian(kf.x, L)
                S = H @ kf.P @ H.T + R
                y = z - model.wheel_h(kf.x, L)
                if y[1] ** 2 / S[1, 1] > n.slip_gate:  # the yaw rate disagrees: a slip
                    self.stats["slips"] += 1
                    if n.slip_inflation <= 0:
                        self.stats["updates"] += 1
                        return 2
                    # the speed alone, down-weighted; never the yaw rate
                    self._rate_update(y[:1], H[:1], R[:1, :1] * n.slip_inflation)
                    self.stats["updates"] += 1
                    return 1
                self._rate_update(y, H, R)
        elif kind == YAW:
            kf.update(np.array([a]), model.yaw_jacobian, model.yaw_h, R=model.yaw_noise(b),
                      residual=model.yaw_residual)
        else:
            self.stats["invalid"] += 1
            return 6
        self.stats["updates"] += 1
        return status
