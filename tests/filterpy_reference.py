"""Reference for the planar EKF: a plain filterpy ``ExtendedKalmanFilter`` driven by the model.

filterpy does the Kalman algebra of the prediction (``P = F P F^T + Q``) and of the absolute
yaw (``update``: ``inv(S)``, Joseph form, ``residual``); the rate measurements' update (a gain
with zero position rows and a yaw row limited by the yaw budget, Joseph form) is written here in
numpy with ``inv(S)``; :mod:`fusion.planar.model` gives f, F, Q and each sensor's h, H and R;
the filter's logic (time bookkeeping, late inputs, ZUPTs with the IMU motion codes, encoder
faults, slip gating, motion onset, saturated gyro, the yaw budget, implausible inputs, the gap
policy) is written here again from :mod:`fusion.planar.ekf`'s description, with numpy,
independently of :mod:`fusion.planar._ekf_core`. Used by tests/test_ekf.py and
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

GYRO, WHEELS, YAW, TWIST, WHEELS_SLIP, ACCEL = 0, 1, 2, 3, 4, 5
ACCEL_HOLD = 0.1  # s: an older forward specific force drives v no more
STILL, UNSURE, MOVING = 1, 2, 3  # fusion.planar.imu_motion



def _linear_slope(sums):
    """The slope of y against x from ``sums`` = (n, sum x, sum y, sum x^2, sum x*y, sum y^2),
    or None unless x spreads by 0.05 rad/s and the two correlate by 0.9
    (_ekf_core._linear_fit, PROOF_SPREAD, LINEAR_SOURCE_CORRELATION)."""
    n, sx, sy, sxx, sxy, syy = sums
    if n < 2:
        return None
    var_x = sxx / n - (sx / n) ** 2
    var_y = syy / n - (sy / n) ** 2
    cov = sxy / n - sx * sy / n ** 2
    if var_x >= 0.05 ** 2 and var_y > 0 and cov > 0 and cov * cov >= 0.81 * var_x * var_y:
        return cov / var_x
    return None

class FilterpyReference:
    """The planar EKF on ``filterpy.kalman.ExtendedKalmanFilter`` (not a subclass of it).

    ``step(kind, t, a, b)`` takes the events of :func:`fusion.planar.ekf.merge_events` and
    returns the same status codes as :meth:`fusion.planar.ekf.PlanarEKF.process_batch`;
    ``stats`` counts like :attr:`fusion.planar.ekf.PlanarEKF.stats`. ``default_prior``:
    as :class:`fusion.planar.ekf.PlanarEKF` with its default ``P0`` (w unknown until the
    first gyro sample, v until the first fused wheel frame or twist); False for a ``P0``
    given by hand.
    """

    def __init__(self, robot: DiffDriveParams, noise: EkfNoise, x0, P0, *,
                 default_prior: bool = True) -> None:
        self.robot = robot
        self.noise = noise
        self.kf = ExtendedKalmanFilter(dim_x=model.NX, dim_z=2)
        self.kf.x = np.array(x0, dtype=float)
        self.kf.P = np.array(P0, dtype=float)
        self.t: float | None = None
        self.zero_count = 0
        # w at the first of a stop's ZUPTs with the same unexplained offset, and its time
        self.steady_w: float | None = None
        self.steady_t = 0.0
        self.imu_motion = 0
        self.in_fault = False
        self.fault_run = 0  # encoder-fault frames since the last frame that was not one
        self.after_slip = False  # the last wheel frame or twist was a slip
        self.wheel_t: float | None = None
        # the last wheel frame with ticks (twist above zero): effective time, measured yaw rate
        self.moved_t: float | None = None
        self.moved_w = math.nan
        self.yaw_budget = noise.yaw_fix_burst
        self.yaw_owed = 0.0  # heading correction beyond the budget, rad
        # position error (m) driven into the pose along the heading held while owed
        self.held_xy = np.zeros(2)
        self.stats = dict.fromkeys(("slips", "wheel_rate_distrusted", "zupts",
                                    "late_dropped", "late_applied", "invalid",
                                    "gyro_saturated", "encoder_faults", "updates",
                                    "speed_resets", "predictions", "accel_slips",
                                    "straight_frames", "wheel_scale_refits",
                                    "bias_relearnt", "gyro_spikes", "catch_ups"), 0)
        self.stats["fault_turn"] = 0.0  # rad: w over the encoder faults' intervals
        # the wheels' yaw rates are fused only while few turning frames fail the slip gate
        self.slip_share = 0.0
        self.distrust = False  # disproven: most turns disagree
        self.agreed = 0.0  # s of turning frames that agreed (proven at wheel_rate_proof_time)
        self.fit: list[tuple[float, float]] = []  # (gyro rate with bias, wheels' rate), turns
        self.lin = np.zeros(6)  # n, sums of x, y, x^2, x*y, y^2 of the same over moving frames
        self.ticks_fit = np.zeros(6)  # the same over moving tick frames since k's restart
        self.ticks_turning = 0.0  # s of turning frames among those
        self.clipped_at = -math.inf  # filter time of the last saturated gyro sample
        self.gyro_t = None  # time of the last gyro sample fused (the spike test)
        self.spike_run = 0  # gyro samples rejected as spikes since then
        # gap policy: filter time of the last measurement of v and of w (None: forgotten)
        self.measured: dict[int, float | None] = {3: None, 4: None}
        self.forgotten: dict[int, tuple[float, float]] = {}  # i -> (time, second moment)
        # the accelerometer's forward specific force: last value and time, learnt offset
        self.fx: float | None = None
        self.fx_t: float | None = None
        self.offset: float | None = None
        self.rest_n = 0  # samples of the current stop averaged into the offset
        # after the previous wheel twist (not an encoder fault): (time, wheel_h of the
        # posterior), for the stamp noise
        self.last_twist: tuple[float, np.ndarray] | None = None
        # the persistent-disagreement test: (time, yaw-rate innovation, its variance without
        # the stamp's share, the stamp's signed standard deviation) of every wheel twist
        # since the test last started afresh, and when the current disagreement began
        self.window: list[tuple[float, float, float, float]] = []
        self.disagreeing_since: float | None = None
        self.ramp = 0.0  # m/s^2: the speed's rate of change between the last two twists
        # the default prior: w is unknown until the first gyro sample, which sets it alone,
        # and v until the first fused wheel frame or twist
        self.first_gyro = default_prior
        self.first_speed = default_prior

    def _accel(self, now: float) -> float | None:
        """The forward acceleration driving v from ``now`` on (None: v is a random walk)."""
        n = self.noise
        if (n.accel_speed_psd <= 0 or self.measured[3] is None or self.offset is None
                or self.zero_count >= n.zupt_frames or self.fx_t is None
                or now - self.fx_t > ACCEL_HOLD):
            return None
        return self.fx - self.offset

    # -- time ------------------------------------------------------------------------------------
    def reported_P(self) -> np.ndarray:
        """P with the pose block about the held pose: the held pose is off the estimate by
        d = (held_xy, -yaw_owed), so its mean square error is P + d d^T."""
        d = np.array([*self.held_xy, -self.yaw_owed])
        P = self.kf.P.copy()
        P[:3, :3] += np.outer(d, d)
        return P

    def _predict(self, dt: float, still: bool, now: float) -> None:
        n, kf = self.noise, self.kf
        f = n.still_scale if still else 1.0
        accel = self._accel(now)
        q_v = n.accel_psd * f
        if not still:  # the speed may go on changing as fast as it last did
            q_v = max(q_v, self.ramp ** 2 * n.speed_ramp_time)
        if accel is not None:
            q_v = n.accel_speed_psd
        if self.after_slip:  # after a slipping frame the speed changes with nothing to hold it
            q_v = max(q_v, n.slip_accel_psd)
        # P and the odometry noise are the estimate's, whose heading is yaw_owed further
        # than the one held in kf.x
        kf.x[2] += self.yaw_owed
        kf.F = model.transition_jacobian(kf.x, dt)
        before = kf.x[:2].copy()
        kf.Q = model.process_noise(dt, q_v, n.angular_accel_psd * f, n.bias_psd,
                                   n.calib_k_psd, n.calib_c_psd, n.gyro_scale_psd,
                                   n.distance_scale_psd)
        q_xx, q_xy, q_yy = model.odometry_noise(kf.x, dt, n.odometry_along_var,
                                                n.odometry_cross_var)
        kf.Q[:2, :2] += np.array([[q_xx, q_xy], [q_xy, q_yy]])
        kf.predict_x = lambda u=0: setattr(kf, "x", model.transition(kf.x, dt))
        kf.predict()
        kf.x[2] -= self.yaw_owed
        # the held pose steps along the held heading: the estimate's step turned back
        step = kf.x[:2] - before
        c, s = math.cos(self.yaw_owed), math.sin(self.yaw_owed)
        held_step = np.array([[c, s], [-s, c]]) @ step
        kf.x[:2] = before + held_step
        self.held_xy += held_step - step
        if accel is not None:  # the accelerometer drives the speed: v += a dt
            kf.x[3] += accel * dt

    def _forget(self, i: int, now: float) -> None:
        """Speed state i unknown: mean 0, variance max(x_i^2 + P_ii, prior), uncorrelated."""
        kf = self.kf
        var = max(kf.x[i] ** 2 + kf.P[i, i], self.noise.initial_speed_std ** 2)
        kf.P[i, :] = 0.0
        kf.P[:, i] = 0.0
        kf.P[i, i] = var
        kf.x[i] = 0.0
        self.zero_count = 0
        self.measured[i] = None
        self.forgotten[i] = (now, var)
        self.stats["speed_resets"] += 1

    def _predict_span(self, start: float, span: float, one_step: bool) -> None:
        steps = [span] if one_step else []
        while not one_step and span > 0:
            steps.append(min(span, self.noise.max_dt))
            span -= steps[-1]
        now = start
        for h in steps:
            lost = [i for i in (3, 4) if self.measured[i] is None]
            P = self.kf.P
            kept = {i: P[i, i] for i in lost}
            for i in lost:  # a forgotten speed takes no part in the propagation
                P[i, i] = 0.0
            self._predict(h, self.zero_count >= self.noise.zupt_frames, now)
            P = self.kf.P
            for i in lost:  # ... the pose gets the envelope r * s^2 of an unknown motion
                P[i, i] += kept[i]
                t_forgot, r = self.forgotten[i]
                grow = r * ((now + h - t_forgot) ** 2 - (now - t_forgot) ** 2)
                for j in ((0, 1) if i == 3 else (2,)):
                    P[j, j] += grow
            self.stats["predictions"] += 1
            now += h

    def _advance(self, t: float) -> bool:
        n = self.noise
        if self.t is None:
            self.t = t
            self.measured = {3: t, 4: t}
            return True
        dt = t - self.t
        if dt < 0:
            if -dt <= n.late_tolerance:
                self.stats["late_applied"] += 1
                return True
            self.stats["late_dropped"] += 1
            return False
        if dt > 0:
            self.yaw_budget = min(self.yaw_budget + n.yaw_fix_rate * dt, n.yaw_fix_burst)
            pay = min(abs(self.yaw_owed), self.yaw_budget)  # the owed correction, paid
            self.kf.x[2] += math.copysign(pay, self.yaw_owed)
            self.yaw_owed -= math.copysign(pay, self.yaw_owed)
            self.yaw_budget -= pay
        now = self.t
        while dt > 0:
            # deadlines (time from now) of the speeds still extrapolated, within this interval
            due = {i: m + n.max_extrapolation - now for i, m in self.measured.items()
                   if m is not None}
            span = min([dt] + [max(d, 0.0) for d in due.values()])
            both_forgotten = not due
            if span > 0:
                self._predict_span(now, span, one_step=both_forgotten)
            dt -= span
            now += span
            for i in (3, 4):
                if i in due and due[i] <= span:
                    self._forget(i, now)
        self.t = t
        return True

    def _rate_update(self, y, H, R) -> None:
        """Rate measurement: no position correction, the yaw correction within the budget."""
        kf = self.kf
        S = H @ kf.P @ H.T + R
        K = kf.P @ H.T @ np.linalg.inv(S)
        K[0:2] = 0.0
        dyaw = float(K[2] @ y)
        kf.x = kf.x + K @ y
        if abs(dyaw) > self.yaw_budget:  # beyond the budget: owed, paid later
            applied = math.copysign(self.yaw_budget, dyaw)
            self.yaw_owed += dyaw - applied
            kf.x[2] -= dyaw - applied
            dyaw = applied
        IKH = np.eye(model.NX) - K @ H
        kf.P = IKH @ kf.P @ IKH.T + K @ R @ K.T
        self.yaw_budget = max(self.yaw_budget - abs(dyaw), 0.0)

    def _learn_offset(self, driven: bool, v_prior: float, interval: float) -> None:
        """The wheels' correction of an accelerometer-driven v, per second, is the offset's
        error: learnt with time constant accel_offset_time."""
        if driven:
            gain = min(1.0, interval / self.noise.accel_offset_time)
            self.offset -= gain * (self.kf.x[3] - v_prior) / interval

    def _persistent(self, y_w: float, s_w: float, stamp_w: float) -> bool:
        """The persistent-disagreement test, written as explicit sums over the frames kept
        in ``self.window``: weights ``exp(-(t_now - t_j)/slip_window)`` on the innovations,
        their squares on the variances (without the stamp's share), and the stamp's shares
        summed with the weights before squaring (one latency for all)."""
        tau = self.noise.slip_window
        if tau <= 0:
            return False
        t_now = self.t
        # frames older than 50 time constants weigh less than 2e-22: dropped
        self.window = [f for f in self.window if t_now - f[0] < 50.0 * tau]
        # a frame above the per-frame gate counts as one standard deviation its way
        if y_w ** 2 > self.noise.slip_gate * s_w:
            y_w = math.copysign(math.sqrt(s_w), y_w)
        self.window.append((t_now, y_w, max(s_w - stamp_w ** 2, 0.0), stamp_w))
        t_j, y_j, s_j, d_j = (np.array(c) for c in zip(*self.window))
        weight = np.exp(-(t_now - t_j) / tau)
        total = float(np.sum(weight * y_j))
        variance = float(np.sum(weight ** 2 * s_j)) + float(np.sum(weight * d_j)) ** 2
        if not total ** 2 > self.noise.slip_gate * variance:
            self.disagreeing_since = None
            return False
        if self.disagreeing_since is None:
            self.disagreeing_since = t_now
        elif t_now - self.disagreeing_since > 3.0:  # _ekf_core.PERSISTENT_SLIP_MAX
            # so long a disagreement is the wheel model's: the test starts afresh
            self.window.clear()
            self.disagreeing_since = None
            return False
        return True

    def _remember_twist(self, t: float) -> None:
        """After a wheel twist's update at ``t``: the twist the wheels should now read, and
        the rate of change of its speed since the last one."""
        h = model.wheel_h(self.kf.x, self.robot.wheel_distance, self.kf.x[3])
        if self.last_twist is not None and t > self.last_twist[0]:
            # over at least one wheel period (frames a millisecond apart: one serial read)
            span = max(t - self.last_twist[0], self.robot.encode_sampling_time)
            self.ramp = (h[0] - self.last_twist[1][0]) / span
        self.last_twist = (t, h)

    def _track_wheel_rate(self, rate: float, interval: float) -> None:
        # the wheels' recent yaw rate (rad/s): frames not taken for faults, 0.2 s average
        if math.isnan(self.moved_w):
            self.moved_w = rate
        else:
            self.moved_w += min(1.0, interval / 0.2) * (rate - self.moved_w)

    def _measured(self, *states: int) -> None:
        for i in states:
            self.measured[i] = self.t

    # -- one event -------------------------------------------------------------------------------
    def step(self, kind: int, t: float, a: float, b: float) -> int:
        n, kf, r = self.noise, self.kf, self.robot
        if not (math.isfinite(t) and math.isfinite(a) and math.isfinite(b)):
            self.stats["invalid"] += 1
            return 6
        wheel_speed = max(abs(a), abs(b)) * r.speed_ratio / r.encode_sampling_time
        if ((kind == GYRO and abs(a) > n.max_rate)
                or (kind in (WHEELS, WHEELS_SLIP) and wheel_speed > n.max_speed)
                or (kind == TWIST and (abs(a) > n.max_speed or abs(b) > n.max_rate))):
            self.stats["invalid"] += 1  # implausible: a corrupt value
            return 6
        if not self._advance(t):
            return 5
        # a wheel frame the accelerometer flagged: a slip whatever the gyro says
        accel_slip = kind == WHEELS_SLIP
        if accel_slip:
            kind = WHEELS
        status = 0
        if kind == GYRO:
            self.imu_motion = int(b) if b in (STILL, UNSURE, MOVING) else 0
            if abs(a) >= n.gyro_limit:
                self.stats["gyro_saturated"] += 1
                self.clipped_at = self.t
                return 2
            if self.first_gyro:
                self.first_gyro = False
                kf.P[4, 4] += 100.0 ** 2  # w forgotten: 100 rad/s, beyond any gyro's range
            H = model.gyro_jacobian(kf.x)
            R = model.gyro_noise(n.gyro_std ** 2)
            if self.gyro_t is not None:
                # a spike: further from the predicted rate than any robot turns
                # (200 rad/s^2 since the last fused sample) plus 6 sigma; the third in a row
                # is the rate, fused with w forgotten
                s = (H @ kf.P @ H.T + R)[0, 0]
                step = 200.0 * (self.t - self.gyro_t) + 6.0 * math.sqrt(s)
                if abs(a - model.gyro_h(kf.x)[0]) > step:
                    if self.spike_run < 2:
                        self.spike_run += 1
                        self.stats["gyro_spikes"] += 1
                        return 2
                    kf.P[4, 4] += 100.0 ** 2
            self.spike_run = 0
            self.gyro_t = self.t
            if self.zero_count >= n.zupt_frames:
                s = (H @ kf.P @ H.T + R)[0, 0]
                if ((a - model.gyro_h(kf.x)[0]) ** 2 / s > n.slip_gate
                        or self.imu_motion == MOVING):
                    self.zero_count = 0
                    kf.P[4, 4] += n.angular_accel_psd * r.encode_sampling_time
            self._rate_update(np.array([a]) - model.gyro_h(kf.x), H, R)
            self._measured(4)
        elif kind == ACCEL:
            self.fx, self.fx_t = a, self.t
            if self.zero_count >= n.zupt_frames and self.imu_motion in (0, STILL):
                # standing still: the offset is the mean over this stop
                self.rest_n += 1
                self.offset = a if self.rest_n == 1 else (
                    self.offset + (a - self.offset) / self.rest_n)
            else:
                self.rest_n = 0
            return 0
        elif kind in (WHEELS, TWIST):
            # the accelerometer drove v till now, driving straight: the offset is learnt
            driven = self._accel(self.t) is not None and abs(kf.x[4]) <= 0.1
            v_prior = kf.x[3]
            in_fault, self.in_fault = self.in_fault, False
            self.after_slip = False
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
                if self.measured[3] is not None:  # or since v was last measured
                    since = max(since, t - self.measured[3])
                hard = abs(kf.x[3]) > n.stop_decel * since + 3 * math.sqrt(kf.P[3, 3])
                self.wheel_t = t
                creep = (2 * r.speed_ratio / r.encode_sampling_time if kind == WHEELS
                         else 2 * n.twist_zero_v)
                turning = abs(kf.x[3]) + 0.5 * r.wheel_distance * abs(kf.x[4]) > creep
                # a steady turn on a smooth floor: the IMU reads still, the gyro's rate (less
                # sqrt(gate) std of the bias and a sample) says a turn of >= 0.1 rad/s, within
                # half of itself of the wheels' recent rate (0.2 s average over the frames not
                # taken for faults), that would have turned
                # the wheels by 2 ticks since they last did (a twist: faster than twice its
                # zero speed)
                w = kf.x[4]
                heard = self.gyro_t is not None and self.t - self.gyro_t <= 0.5
                low = abs(w) - math.sqrt(n.slip_gate * (kf.P[5, 5] + n.gyro_std ** 2))
                rim = 0.5 * r.wheel_distance * low
                if self.moved_t is None:
                    spinning = False
                elif kind == WHEELS:
                    turned = max(r.encode_sampling_time, t - self.moved_t)
                    spinning = rim * turned > 2 * r.speed_ratio
                else:
                    spinning = rim > 2 * n.twist_zero_v
                spinning = (spinning and heard and low > 0.1
                            and abs(w - self.moved_w) <= 0.5 * abs(w))
                if ((self.imu_motion == MOVING and turning) or spinning
                        or (in_fault and self.imu_motion in (UNSURE, MOVING))
                        or (self.imu_motion != STILL and hard)):
                    self.zero_count = 0
                    self.steady_w = None
                    self.stats["encoder_faults"] += 1
                    self.stats["fault_turn"] += kf.x[4] * interval
                    self.in_fault = True
                    self.fault_run += 1
                    if self.imu_motion in (UNSURE, MOVING) or spinning:  # no gap: v stays
                        self._measured(3)
                    return 7
                self._track_wheel_rate(0.0, interval)
                self.fault_run = 0
            else:
                self.wheel_t = t
                if self.zero_count >= n.zupt_frames:  # motion onset: v's freedom back
                    kf.P[3, 3] += n.accel_psd * r.encode_sampling_time
                self.steady_w = None
                # the first frame after 1-3 encoder faults at about (faults + 1) times the
                # coasted speed (within 25 %, nearer than the coasted speed itself, which is
                # above 0.25 m/s: _ekf_core.CATCH_UP_MIN_SPEED) carries
                # the faulted frames' counts, whose motion was coasted: divided by that
                # (_ekf_core._catch_up)
                periods = self.fault_run + 1
                self.fault_run = 0
                if kind == WHEELS:
                    v_m = 0.5 * (a + b) * r.speed_ratio / r.encode_sampling_time
                    slow = 4 * r.speed_ratio / r.encode_sampling_time
                else:
                    v_m, slow = a, 10 * n.twist_zero_v
                v = kf.x[3]
                if (2 <= periods <= 4 and abs(v) > max(slow, 0.25)
                        and abs(v_m - periods * v) <= 0.25 * periods * abs(v)
                        and abs(v_m - periods * v) < abs(v_m - v)):
                    a, b = a / periods, b / periods
                    self.stats["catch_ups"] += 1
            self.zero_count = self.zero_count + 1 if still else 0
            if self.zero_count >= n.zupt_frames and self.imu_motion in (0, STILL):
                # a bias off by more than it admits: the stop's gyro samples fail the still
                # gate and w carries the offset; the same w (within 4 sigma of two gyro
                # samples' difference) at the ZUPTs of 0.5 s, the IMU still, opens the bias's
                # variance by w^2
                w = kf.x[4]
                if (self.imu_motion == STILL
                        and w ** 2 > n.slip_gate * (kf.P[5, 5] + n.gyro_std ** 2)):
                    if (self.steady_w is None
                            or abs(w - self.steady_w) > 4.0 * math.sqrt(2.0) * n.gyro_std):
                        self.steady_w, self.steady_t = w, self.t
                    elif self.t - self.steady_t >= 0.5:
                        kf.P[5, 5] += w * w
                        self.steady_w = None
                        self.stats["bias_relearnt"] += 1
                else:
                    self.steady_w = None
                H = model.zupt_jacobian(kf.x)
                self._rate_update(-model.zupt_h(kf.x), H,
                                  model.zupt_noise(n.zupt_v_std, n.zupt_w_std))
                self._remember_twist(t)
                status = 4
                self.stats["zupts"] += 1
                self.first_speed = False  # standing still: v is known
                self._measured(3, 4)
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
                if not still:  # the wheels turned: when, and at what yaw rate
                    self.moved_t = t
                    self._track_wheel_rate(z[1], interval)
                R = R.copy()
                R[1, 1] += (n.turn_w_std * kf.x[4]) ** 2  # turns: relative to the state's rate
                inflate = n.wheel_w_corr_time / interval  # correlated yaw-rate error
                if inflate > 1:
                    R[1, 1] *= inflate
                    R[0, 1] = R[1, 0] = R[0, 1] * math.sqrt(inflate)
                stamp_w = 0.0
                if self.last_twist is not None and t > self.last_twist[0]:
                    # the stamp's error, with the filter's own rates of change of the twist
                    # the wheels should read, from the last twist's posterior to this prior
                    t0, h0 = self.last_twist
                    span = max(t - t0, r.encode_sampling_time)
                    rate = (model.wheel_h(kf.x, L, kf.x[3]) - h0) / span
                    model.stamp_noise(R, rate[0], rate[1], n.stamp_std)
                    if n.stamp_std > 0:
                        stamp_w = rate[1] * n.stamp_std
                first = self.first_speed
                if first:
                    self.first_speed = False
                    kf.P[3, 3] += 100.0 ** 2  # v forgotten: 100 m/s, beyond any robot's speed
                    driven = False  # v's jump teaches the accelerometer's offset nothing
                # does the source's yaw rate follow the gyro's, whatever its scale? Over every
                # moving frame: correlation >= 0.9 once the gyro rates spread by 0.05 rad/s
                # (_ekf_core.LINEAR_SOURCE_CORRELATION, PROOF_SPREAD)
                moving = abs(z[0]) > n.twist_zero_v
                turning = abs(z[1]) > 0.1 or abs(kf.x[4]) > 0.1  # a turn tests the wheels
                gr = kf.x[4] + kf.x[5]
                # no gyro fused for 0.5 s (none in the log, a gap): the wheels' yaw rate is
                # all there is, fused without the slip gate (_ekf_core.GYRO_SILENT)
                silent = self.gyro_t is None or not self.t - self.gyro_t <= 0.5
                if moving and not silent:  # without a gyro w is the wheels' own
                    self.lin += (1.0, gr, z[1], gr * gr, gr * z[1], z[1] * z[1])
                linear = _linear_slope(self.lin) is not None
                # a gap in a gyro that had spoken: a source it had not proven, or had
                # disproven, is fused in the gyro's scale (its slope against the gyro over
                # the moving frames), or only its speed (_ekf_core._silent_rate_scale)
                scale = 1.0
                if silent and self.gyro_t is not None and (
                        self.distrust or (kind == TWIST
                                          and self.agreed < n.wheel_rate_proof_time)):
                    slope = _linear_slope(self.lin)
                    scale = 0.0 if slope is None else slope
                if scale > 0.0 and scale != 1.0:
                    z = np.array([z[0], z[1] / scale])
                    R = R.copy()
                    R[0, 1] /= scale
                    R[1, 0] /= scale
                    R[1, 1] /= scale * scale
                if (kind == WHEELS and moving and not accel_slip and n.calib_k_std > 0
                        and n.wheel_scale_refit > 0 and not silent):
                    # the ticks' own fit since the last restart of k; k restarts at its slope
                    # once it holds wheel_rate_proof_time s of turns, correlates by 0.9 and is
                    # that many prior sigmas off, c at its prior mean, both at their prior
                    # variances, and the fit starts afresh (_ekf_core._refit_wheel_scale)
                    self.ticks_fit += (1.0, gr, z[1], gr * gr, gr * z[1], z[1] * z[1])
                    self.ticks_turning += interval if turning else 0.0
                    slope = _linear_slope(self.ticks_fit)
                    if (self.ticks_turning >= n.wheel_rate_proof_time and slope is not None
                            and abs(slope - 1.0 - kf.x[6])
                            > n.wheel_scale_refit * n.calib_k_std):
                        kf.x[6], kf.x[7] = slope - 1.0, n.wheel_rate_per_speed
                        kf.P[6:8, :] = 0.0
                        kf.P[:, 6:8] = 0.0
                        kf.P[6, 6] = n.calib_k_std ** 2
                        kf.P[7, 7] = n.calib_c_std ** 2
                        self.stats["wheel_scale_refits"] += 1
                        self.ticks_fit[:] = 0.0
                        self.ticks_turning = 0.0
                H = model.wheel_jacobian(kf.x, L, z[0])
                if silent:  # k and c are not measured without a gyro
                    H[0, 7] = H[1, 6] = H[1, 7] = 0.0
                S = H @ kf.P @ H.T + R
                y = z - model.wheel_h(kf.x, L, z[0])
                gated = y[1] ** 2 / S[1, 1] > n.slip_gate  # the yaw rate disagrees
                slip = gated
                # with the gyro saturated or silent the wheels are all there is
                fuse_rate, disproven = True, False
                if silent:
                    slip = gated = False
                    fuse_rate, disproven = scale > 0.0, self.distrust
                elif self.t - self.clipped_at >= n.wheel_rate_proof_time:
                    if turning:
                        w = min(1.0, interval / n.wheel_rate_trust_time)
                        self.slip_share += w * (float(slip) - self.slip_share)
                        # agreeing: below the gate, and the slope of the wheels' yaw rate
                        # against the gyro's (bias included) over every turn so far within
                        # 10 % of 1, once those gyro rates spread by 0.05 rad/s
                        # (_ekf_core.PROOF_TOLERANCE, PROOF_SPREAD)
                        self.fit.append((kf.x[4] + kf.x[5], z[1]))
                        gx, wy = np.array(self.fit).T
                        close = False
                        if len(self.fit) >= 2 and np.var(gx) >= 0.05 ** 2:
                            slope = np.polyfit(gx, wy, 1)[0]
                            close = abs(slope - 1.0) <= 0.1
                        self.agreed += interval if not slip and close else 0.0
                    if self.slip_share > n.max_slip_share:
                        self.distrust = True
                    elif self.slip_share < 0.5 * n.max_slip_share:
                        self.distrust = False
                    disproven = self.distrust
                    fuse_rate = not disproven and (kind == WHEELS
                                                   or self.agreed >= n.wheel_rate_proof_time)
                    # the persistent test sees only yaw rates that would be fused
                    if fuse_rate and self._persistent(y[1], S[1, 1], stamp_w):
                        slip = True
                if slip or not fuse_rate or accel_slip:
                    # disproven wheels, or an external odometry not yet proven in turns: a
                    # disagreement is no sign of slip
                    unproven = kind == TWIST and self.agreed < n.wheel_rate_proof_time
                    slip_gated = slip
                    slip = slip and not disproven and not unproven
                    if (disproven or (unproven and slip_gated)) and turning:
                        self.stats["wheel_rate_distrusted"] += 1
                    if accel_slip:  # the accelerometer says so: a slip whatever the gyro says
                        self.stats["accel_slips"] += 1
                        slip = True
                    if slip:
                        self.stats["slips"] += 1
                        self.after_slip = True
                    # a frame only the persistent test flags keeps its speed's own noise
                    inflation = n.slip_inflation if slip and (gated or accel_slip) else 1.0
                    if inflation <= 0:
                        if first:  # nothing fused: v stays unknown for the next frame
                            kf.P[3, 3] -= 100.0 ** 2
                            self.first_speed = True
                        self._remember_twist(t)  # the prior: nothing fused
                        self.stats["updates"] += 1
                        return 2
                    # the speed alone (down-weighted if slipping); never the yaw rate
                    H_v = np.zeros((1, model.NX))
                    H_v[0, 3] = H[0, 3]
                    self._rate_update(y[:1], H_v, R[:1, :1] * inflation)
                    if (not slip and not accel_slip and not fuse_rate and moving and linear
                            and abs(z[1]) < n.straight_rate):
                        # an untrusted yaw rate near zero: driving straight, its noise
                        # widened by the rate (scale unknown) and by 2 s of correlation
                        # (_ekf_core.STRAIGHT_SCALE_STD, STRAIGHT_CORR_TIME)
                        H_w = model.wheel_jacobian(kf.x, L, z[0])[1:2]
                        y_w = z[1:2] - model.wheel_h(kf.x, L, z[0])[1:2]
                        R_w = np.array([[(R[1, 1] + z[1] ** 2)
                                         * max(1.0, 2.0 / max(interval,
                                                              r.encode_sampling_time))]])
                        if y_w[0] ** 2 <= n.slip_gate * (H_w @ kf.P @ H_w.T + R_w)[0, 0]:
                            self.stats["straight_frames"] += 1
                            self._rate_update(y_w, H_w, R_w)
                    self._remember_twist(t)
                    self._learn_offset(driven, v_prior, interval)
                    self._measured(3, 4)
                    self.stats["updates"] += 1
                    return 1 if slip else 0
                self._rate_update(y, H, R)
                self._remember_twist(t)
                self._learn_offset(driven, v_prior, interval)
                self._measured(3, 4)
        elif kind == YAW:
            kf.x[2] += self.yaw_owed  # an absolute yaw: what is owed is paid at once
            self.yaw_owed = 0.0
            kf.update(np.array([a]), model.yaw_jacobian, model.yaw_h, R=model.yaw_noise(b),
                      residual=model.yaw_residual)
        else:
            self.stats["invalid"] += 1
            return 6
        self.stats["updates"] += 1
        return status
