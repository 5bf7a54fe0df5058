"""Planar EKF fusing wheel odometry with the gyro's yaw rate, with a gyro-bias state.

Frames and units (REP-103/105): the pose is ``base_footprint`` in ``odom``; x, y in m, yaw in
rad (CCW from the odom x axis; kept continuous inside, wrapped to (-pi, pi] on output),
v forward speed m/s, w yaw rate rad/s (in the gyro's scale, see g), b the gyro's bias about
the vertical axis, rad/s.

State ``x = [x, y, yaw, v, w, b, k, c, g, s]``, covariance ``P`` (10x10). ``k`` (dimensionless) and
``c`` (rad/m) describe how the wheels' yaw rate departs from the gyro's:
``w_wheels = (1 + k)*w + c*v`` (``v`` the frame's measured speed). A wheel-separation error
shows up as ``k`` (``k ~ L_true/L_nominal - 1``), a left/right radius mismatch as ``c``
(``c ~ (e_right - e_left)/L`` with ``e`` each wheel's relative distance error). The gyro makes
both observable (turning reveals ``k``, driving straight reveals ``c``) once its bias is pinned
by zero-velocity updates; a common distance scale (``speed_ratio`` wrong on both wheels alike)
is not observable from a gyro and stays as it is configured. ``g`` (dimensionless) is the
gyro's scale error, ``z_gyro = (1 + g)*w_true + b``: its prior comes from the datasheet
(MPU6050: sensitivity tolerance +-3 %), not from any data. The heading error it causes grows
with the angle turned, not with time, so no white process noise can stand for it; as a state
it makes the pose covariance grow with the angle turned. Gyro and wheels reveal only the ratio
of their scales (``k``), never the common one, so the state ``w`` is the rate in the gyro's
scale and the heading integrates ``w/(1 + g)`` (:mod:`fusion.planar.model`): no rate
measurement depends on g, only an absolute yaw corrects it. The state is there for an honest
covariance, not for accuracy: without absolute yaws g stays 0 and the estimate is that of
the filter without it. ``s`` (dimensionless) is the common distance scale error of the wheels
(``speed_ratio`` wrong on both alike), unobservable too: ``v`` is the speed in the wheels'
scale and the position integrates ``v/(1 + s)``; its prior makes the position covariance grow
with the distance driven, along the track. The class is a
:class:`filterpy.kalman.ExtendedKalmanFilter`: ``x``, ``P``, ``y``, ``S``, ``K`` keep filterpy's
meaning and filterpy's own ``update(z, HJacobian, Hx, R, residual=...)`` can fuse any extra
measurement (a beacon, a scan match) into the same state (``P`` is the estimate's: while a
heading correction is owed, ``yaw_fix_rate``, the pose held in ``x`` lags it by a known offset
and :meth:`PlanarEKF.reported_covariance` is the held pose's; an extra position measurement
fused then does not clear that offset). The model below is written once, in
:mod:`fusion.planar.model` (f, F, Q and each sensor's h, H, R); the built-in sensors run
through the core :mod:`fusion.planar._ekf_core`, which computes filterpy's update equations
(Joseph form) with a Cholesky solve instead of ``inv(S)``. numba compiles the core when it is
installed (the ``fast`` extra); without it the same functions run as plain Python with the
same results, more slowly. The tests drive a plain filterpy ``ExtendedKalmanFilter`` with the
model's functions as the reference.

Model:

- Prediction over ``dt`` (constant twist): ``yaw += u*dt`` with ``u = w/(1 + g)`` the true
  yaw rate, ``x += d*cos(yaw + u*dt/2)``, ``y += d*sin(yaw + u*dt/2)`` with ``d = v*dt/(1 + s)``;
  v, w, b, k, c, g and s are random walks (``q_v``, ``q_w``, ``q_b``, ...), in steps of at most
  ``max_dt``; while driving v's walk is at least its last rate of change squared times
  ``speed_ramp_time`` (a ramp goes on); the position gets a white noise per metre driven
  along and across the heading (``odometry_along_var``, ``odometry_cross_var``): wheel
  distance errors that accumulate along the path and that no constant scale represents.
- Gap policy (bounded cost and bounded extrapolation for any interval without inputs): v and
  w are extrapolated at most ``max_extrapolation`` s (default 3) past their last
  measurement (v: a wheel frame, twist or ZUPT, or an encoder-fault frame while the IMU shows
  motion: a dead encoder feed on a moving robot is no gap, the pose coasts; w: those or a gyro
  sample). Then each is
  *forgotten* until it is measured again: its mean becomes 0 and its variance its second
  moment ``r = x_i^2 + P_ii`` (at least ``initial_speed_std^2``), it stays uncorrelated with
  the rest, and the ZUPT's standing-still state ends. While forgotten it does not move the
  pose; the pose's covariance grows instead by the envelope of an unknown motion at that
  speed, ``r * s^2`` on the variances of x and y (v) or of yaw (w), ``s`` the time since it
  was forgotten, whatever the steps. So after a gap of any length the pose has moved at most
  ``|v| * max_extrapolation`` (the yaw ``|w| * max_extrapolation``), its standard deviation
  covers the distance the last speed would have carried the robot, and a speed measured after
  the gap does not move the pose by the gap's distance (nothing correlates them). Once both
  are forgotten nothing moves and the growth is in closed form: the rest of the interval is a
  single step. One input therefore costs at most about ``2 * max_extrapolation / max_dt + 1``
  steps (a 1e5 s gap: 61, not 2 million); forgetting is counted in
  ``stats["speed_resets"]``, steps in ``stats["predictions"]``. The speeds of ``x0`` count
  as measured at the first input.
- Implausible inputs (a rate above ``max_rate``, a speed above ``max_speed``: a corrupt
  value, not a measurement) and non-finite ones are counted in ``stats["invalid"]`` and
  never fused.
- Gyro update: ``z = w + b`` where z is the heading rate (the rate of the ZYX yaw that the
  pose integrates). On a level robot that is ``gyro[2]``; on a tilted one the rate about the
  world vertical, :func:`vertical_rate` (the body rates projected with the attitude
  quaternion), is the same on a level floor or at a constant tilt but not while roll and
  pitch change together (hills: it misses ``roll_dot * sin(pitch)``).
  :func:`heading_rate` is exact on an exact attitude but turns a tilt error into a scale
  error of every turn; the pipeline (:class:`fusion.pipeline.core.FusionPipeline`) feeds
  the vertical rate plus the roll term taken from its attitude's roll change.
- Wheel update: one DATA-uart2 frame's ticks give the period's mean speed ``v = (dl+dr)/(2T)``
  and yaw rate ``w = (dr-dl)/(L T)`` (seed 000's names: ``speed_ratio`` m/tick,
  ``wheel_distance`` L, ``encode_sampling_time`` T), modelled as ``v + c*w*L^2/4`` and
  ``(1 + k)*w + c*v_m``, ``v_m`` the frame's own measured speed (the radius mismatch scales
  the wheels' own travel; with the speed state there, its quantisation ripple walked b and c
  on long straight drives without a stop: :mod:`fusion.planar.model`). The noise comes from
  tick quantisation and a per-frame wheel scale
  noise, plus white noise on w, plus the stamp's uncertainty times the filter's own rate of
  change of the twist (``stamp_std``). The yaw-rate innovation is
  chi-square gated (1 dof): above the gate the frame is a slip and its noise is inflated
  (down-weighted) so the gyro carries the heading; until the next frame the speed's random
  walk is ``slip_accel_psd`` (a robot whose wheels slip accelerates harder than the floor
  allows, and no frame holds its speed). A slip too small for one frame's noise (a wheel
  spinning a few per cent faster than the floor on a coarse encoder) is caught by the sum of
  the innovations over about ``slip_window`` s: those frames are slips as well, their speed
  fused with its own noise. The gyro cannot see wheels that spin or skid alike
  or a body sliding sideways; a frame the accelerometer flags
  (:mod:`fusion.planar.accel_slip`: forward specific force against the wheels' dv/dt,
  lateral against v*w; event kind 4, ``wheel_slip=`` of :func:`fuse`,
  ``update_wheels(slip=True)``) is a slip too, whatever the gate says: its yaw rate is not
  fused, its speed down-weighted alike, and its flag and status are a slip's.
- Zero-velocity update (ZUPT): after ``zupt_frames`` consecutive frames with zero ticks on both
  wheels, ``v = 0`` and ``w = 0`` are fused with a tight noise; the gyro then reads its own bias,
  which is how ``b`` becomes observable. While standing still the v and w random walks shrink
  by ``still_scale`` so every gyro sample informs the bias; a gyro reading that the still model
  cannot explain (chi-square above ``slip_gate``) ends the stationary phase at once, so the
  start of a turn does not leak into the bias before the first moving wheel frame arrives.
  Where the bias itself is what the still model cannot explain (it went wrong before, e.g. a
  late twist's zeros over a turn's start), the stop's ZUPTs keep finding the same offset in
  ``w``: after 0.5 s of that with the IMU still, the bias's variance is opened for it
  (``stats["bias_relearnt"]``, :func:`fusion.planar._ekf_core._relearn_bias_at_stop`).
- External twist (kind 3, e.g. a nav_msgs/Odometry from a ROS bag): forward speed and yaw
  rate through the same wheel model, gate and ZUPT logic, noise ``twist_v_std``/``twist_w_std``;
  its yaw rate is fused only once proven in turns (``wheel_rate_proof_time``), and until then
  a twist that fails the gate is no slip (its speed is fused as measured). An unproven or
  disproven twist (or wheel frame) whose rates have followed the gyro's in proportion still
  tells "driving straight" when it reads below ``straight_rate``: what teaches the bias of a
  skid-steer base that starts moving before its first stop.
- Optional absolute yaw (a compass, a map match), residual wrapped to (-pi, pi].
- Optional, off by default (``EkfNoise.accel_speed_psd`` > 0): the forward specific force of
  each IMU sample (kind 5, base frame x, ``accel_x=`` of :func:`fuse`,
  :meth:`PlanarEKF.update_accel`) drives the speed's prediction, ``v += (f_x - offset) dt``,
  instead of the random walk; the offset is learnt at stops and from the wheels driving
  straight (see :class:`EkfNoise`). It removes the speed's lag in ramps and carries the
  speed through a dead encoder feed. Not the default: on benchmarks/ekf_accuracy.py
  (``--accel-speed 0.002 --accel-offset-time 2``, chosen by benchmarks/tune_ekf.py's
  cross-validation) it cuts the position error of the calibrated physics runs (0.16 -> 0.10 %
  "all", 0.72 -> 0.29 % "all+dead") and puts the worst raw-gyro NEES run from 64-68 % to
  81-87 % (raw "all+dead": every run at 85 % or more), but the pose NEES of "plain" (already
  underconfident: 32 -> 25 % inside) and of the calibrated runs (all 83 -> 79 %, all+dead
  83 -> 77 %, its worst run 62 -> 49 %) fall
  further below the lower bound, and the worst raw "all+dead" run ends 2.79 % off instead of
  2.51 % (figures with ``stamp_std`` 0.02 s and ``speed_ramp_time`` 0.1 s; the latter does
  nothing while the accelerometer drives v); it needs a stop to learn the offset (the Jackal
  bag has none: unchanged).

Tuning (:class:`EkfNoise`): the defaults describe an MPU6050 at 100 Hz and a miiboo-like
chassis with 40 ms frames. ``bias_psd`` should come from the gyro's Allan variance (the rate
random walk squared); ``accel_psd`` is how much the speed may change between wheel frames
(small, since every frame measures it precisely). How honest the pose covariance is
(benchmarks/ekf_accuracy.py, pose NEES inside its 95 % bounds): on the physics simulator's
"all" runs 91 % of the rows on average (83 % with a calibrated gyro), 59-68 % in the worst
run, where speed ramps the constant-speed model lags and an unmodelled 15 ms wheel latency
make it overconfident in spite of ``speed_ramp_time`` and ``stamp_std``; runs whose common
wheel scale error is well below the 1 % prior are underconfident; on the kinematic
simulator, whose gyro and wheel scales are exact, the g and s states make it underconfident
(tests/test_ekf_acceptance.py, tests/test_ekf_nees_physics.py).

Why the wheels are a measurement and not the prediction input: a prediction driven by wheel
increments makes the heading follow the wheels (3 % separation error, slip) and leaves no place
to reject a slipping frame. Here the heading integrates the gyro-corrected rate state and each
wheel frame can be weighed, gated or replaced by a ZUPT.

Time policy (multi-rate, out of order), stated once:

- Every input carries a host time stamp. The filter predicts from its current time to the
  input's *effective* time, then updates. A wheel frame's effective time is
  ``stamp - encode_sampling_time/2 - wheel_latency``: the frame reports the mean over the period
  ending at its stamp, which equals the speed at the period's midpoint.
- An input older than the filter's time by at most ``late_tolerance`` s is fused at the current
  time (no re-prediction); an older one is dropped and counted in :attr:`PlanarEKF.stats`.
- Offline, :func:`merge_events` sorts all inputs by effective time first (at equal times gyro,
  the same sample's forward specific force, then wheels, then yaw, then twists), so replay
  never sees late inputs;
  :meth:`PlanarEKF.process_batch` takes such a list.
  Live, feed inputs through a :class:`ReorderBuffer` whose window is at least the largest
  transport delay plus half a period.
"""

from __future__ import annotations

import heapq
import math
import warnings
from dataclasses import asdict, dataclass, field

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from numpy.typing import ArrayLike, NDArray

from fusion.geometry.angles import wrap_angle_scalar
from fusion.geometry.kinematics import DiffDriveParams
from fusion.geometry.mount import heading_rate, vertical_rate
from fusion.planar import _ekf_core as core
from fusion.planar.model import NX
from fusion.types.constants import UNOBSERVED_VARIANCE

__all__ = [
    "MAX_STEPS_PER_INPUT",
    "STATE_NAMES",
    "EkfNoise",
    "FusedTrack",
    "PlanarEKF",
    "ReorderBuffer",
    "fuse",
    "heading_rate",
    "merge_events",
    "odometry_covariances",
    "pose_covariances",
    "vertical_rate",
]

STATE_NAMES = ("x", "y", "yaw", "v", "w", "gyro_bias_z", "wheel_rate_scale", "wheel_rate_per_speed",
               "gyro_scale", "distance_scale")


@dataclass(frozen=True)
class EkfNoise:
    """Noise and tuning of :class:`PlanarEKF` (SI units).

    Attributes:
        gyro_std: white noise of one gyro sample, rad/s (MPU6050: 0.005 deg/s/sqrt(Hz) at
            100 Hz gives 8.7e-4).
        accel_psd: forward-speed random walk, (m/s)^2/s (how fast v may change).
        slip_accel_psd: forward-speed random walk from a slipping wheel frame (its speed
            down-weighted, see ``slip_inflation``) to the next frame, (m/s)^2/s, at least
            ``accel_psd``: wheels slip when the robot accelerates harder than the floor
            allows, and its speed then changes with no frame to hold it. Chosen with
            ``slip_inflation`` by benchmarks/tune_ekf.py (see its docstring).
        accel_speed_psd: 0 (default): v is a random walk (``accel_psd``). > 0: the forward
            specific force (base frame x) of each IMU sample drives v,
            ``v += (f_x - offset) * dt``, and this is v's process noise, (m/s)^2/s: the
            accelerometer's error (white noise and vibration while driving, ~1 m/s^2 RMS at
            100-200 Hz: about 1 (m/s^2)^2 x 0.005 s; the offset's residual error between
            wheel frames). The offset (accelerometer bias + gravity through the tilt) is
            the mean of f_x over each stop (a ZUPT's conditions) and, while driving, follows
            the wheels' corrections of v with time constant ``accel_offset_time`` (a slope:
            gravity leaks ~0.17 m/s^2 per degree). Until the first stop v stays a random
            walk. Needs the IMU's f_x fed (``accel_x`` of :func:`fuse`,
            :meth:`PlanarEKF.update_accel`; the pipeline feeds it when this is > 0, e.g.
            ``accel_speed_psd = 0.002`` under ``[ekf]`` in robot.toml: the value
            benchmarks/tune_ekf.py's cross-validation chose, with ``accel_offset_time`` 2 s).
        accel_offset_time: time constant of the accelerometer offset learnt from the wheels
            while driving, s.
        speed_ramp_time: s. While driving (not standing still, v not driven by the
            accelerometer) the speed's random walk is at least ``a^2 * speed_ramp_time``
            ((m/s)^2/s), with ``a`` (m/s^2) the filter's own rate of change of the speed
            between the last two wheel twists (their posteriors): in a ramp the speed may
            go on changing as fast as it just did, about ``a * speed_ramp_time`` over that
            time, which the constant-speed model does not predict (a random walk of
            ``accel_psd`` lets v change by 9 mm/s per 40 ms frame; a 1 m/s^2 ramp changes it
            by 40). 0: off. Default 0.1 s (2.5 frames), chosen by benchmarks/tune_ekf.py
            run (7) (five of six folds in both modes). Held out (benchmarks/ekf_accuracy.py,
            seeds 0-7, with ``stamp_std`` 0.02 s): pose NEES of "all" inside its bounds on
            90.8 % of the rows on average, 68.5 % in the worst run (85.2 / 53.2 % with 0),
            84.0 / 59.6 % with the calibrated gyro (79.8 / 47.8 %); "plain" falls further
            below (32.8 -> 32.1 %); errors unchanged within noise
            (tests/test_ekf_timing.py: the speed's error inside its bound in ramps). The
            estimates barely change (a wheel frame's speed is trusted almost fully either
            way); the covariance follows the ramps.
        angular_accel_psd: yaw-rate random walk, (rad/s)^2/s.
        bias_psd: gyro-bias random walk, (rad/s)^2/s (square of the bias walk in rad/s/sqrt(s)).
        tick_std: encoder quantisation noise per period, ticks.
        scale_std: relative white noise of each wheel's travel in one frame (floor texture,
            tyre deformation).
        separation_std: relative white noise of the wheel yaw rate (per frame).
        wheel_w_std: extra white noise on the wheel yaw rate, rad/s.
        calib_k_std, calib_c_std: prior standard deviations of the wheel calibration states
            ``k`` (1) and ``c`` (rad/m).
        wheel_rate_scale, wheel_rate_per_speed: prior means of ``k`` (1; the wheels' yaw rate
            is ``1 + k`` times the gyro's) and ``c`` (rad/m): 0 (unknown), or what a whole
            run taught (``fusion replay``'s "wheel yaw-rate calibration seen by the gyro";
            its moving start's second pass starts from the first pass's end,
            :mod:`fusion.jobs.moving_start`).
        calib_k_psd, calib_c_psd: their random walks, 1/s and (rad/m)^2/s.
        zupt_v_std, zupt_w_std: noise of the zero-velocity pseudo-measurement, m/s and rad/s.
        zupt_frames: consecutive all-zero wheel frames before a ZUPT; from then on the robot is
            taken as standing still until a wheel moves or the gyro sees a rotation.
        still_scale: factor on the v and w random walks while standing still (small: the
            gyro samples between ZUPTs then all inform the bias).
        slip_gate: chi-square threshold (1 dof) of the wheel/gyro yaw-rate disagreement
            (10.83 = 0.1 % false alarms).
        slip_inflation: factor on the speed noise of a gated (slipping) frame, whose yaw
            rate is never fused (0: drop the frame). Chosen with ``slip_accel_psd`` by
            benchmarks/tune_ekf.py.
        slip_window: time constant (s) of the persistent-disagreement test: the wheels'
            yaw-rate innovations, exponentially weighted over about this long, are tested
            against their own variance with ``slip_gate``; while the sum fails it, frames are
            slips too (flagged, yaw rate not fused; their speed keeps its own noise), for at
            most ``_ekf_core.PERSISTENT_SLIP_MAX`` s at a stretch. It catches a wheel that
            spins a few per cent faster than the floor, which one frame's quantisation noise
            hides from the per-frame gate and which, frame by frame, pulled the bias by
            degrees per second before the first stop
            (:func:`fusion.planar._ekf_core._persistent_disagreement`). A frame the
            per-frame gate catches counts as one standard deviation, so the flags end within
            about ``slip_window`` s of a slip's end (none after tests/test_ekf.py's 30 %
            slip at 0.2 s; 0.1-0.2 s at 0.5 s). Needs ``stamp_std``: with exact stamps an
            unmodelled 15 ms latency looks like a persistent disagreement in every spin-up
            (tests/test_ekf_timing.py). 0: off. Default 0.2 s, set from that trade
            (detection within a few frames, a short tail): on benchmarks/blackbox's tuning
            runs (seeds 301-308, four scenarios) 0.1, 0.2 and 0.3 s give the same means
            within 0.01 deg, so no run chose it; tests/test_ekf_slip.py's coarse encoder
            needs 0.2 s or more to hold a 3 % slip (0.1 s: the bias pulled by 0.2 deg/s).
        stop_decel: hardest braking the robot can do, m/s^2: zero wheel speed that would
            need more (with three standard deviations of v on top), while the IMU is not
            still, is an encoder fault, not a stop.
        turn_w_std: relative noise of the wheels' yaw rate in a turn, on the filter's own
            yaw-rate state (1): turns teach little about the gyro bias, straight driving does.
        wheel_w_corr_time: correlation time of the wheels' yaw-rate error, s (skid-steer
            scrub, slip, tyre creep are not white): the yaw-rate noise of wheel frames or
            twists closer together than this is multiplied by ``wheel_w_corr_time/interval``
            so that they do not average it down (0: white).
        yaw_fix_rate, yaw_fix_burst: rate measurements (gyro, wheels, twists, ZUPTs) never
            correct the position (it follows from the motion model), and the heading by at
            most ``yaw_fix_burst + yaw_fix_rate*T`` (rad; rad/s) over any ``T`` s: a heading
            error that a better bias or wheel scale reveals is corrected at that pace, never
            in a jump; what exceeds the allowance is owed and paid as it refills, never
            dropped. ``P`` is that of the full correction; the covariance reported (state
            rows, records, :meth:`PlanarEKF.reported_covariance`) is that of the pose held,
            ``P`` plus the outer product of its known offset (the owed heading and the
            position driven along the held one).
        late_tolerance: inputs at most this much older than the filter time are fused at the
            filter time, s; older ones are dropped.
        max_dt: longest single prediction step, s.
        max_extrapolation: how long v and w are extrapolated past their last measurement, s
            (the gap policy in the module docstring). Set by hand, not tuned: a driven robot
            keeps its speed for a few seconds (a chassis cable pulled for 2 s while the
            firmware holds its target: tests/test_pipeline_live.py), while 100 s at
            0.25 m/s would be 25 m; 3 s bounds that to 0.75 m.
        wheel_latency: transport delay from the end of a period to its host stamp, s.
        stamp_std: standard deviation of a wheel frame's or twist's stamp, s: transport
            latency not in ``wheel_latency`` and its jitter, and in a ramp a period's mean
            that is not quite the speed at its midpoint. While the speed changes at ``a``
            (m/s^2) and the yaw rate at ``alpha`` (rad/s^2) the measurement then errs by
            ``a*stamp_std`` and ``alpha*stamp_std``, whose variances are added to its R
            (:func:`fusion.planar.model.stamp_noise`). ``a`` and ``alpha`` are the filter's
            own: the change, per second, of the twist the wheels should read from the
            previous wheel twist's posterior to this one's prior, i.e. the gyro's change of
            the yaw rate and, when the accelerometer drives v (``accel_speed_psd``), its
            change of the speed (with v a random walk nothing changes v between frames: no
            speed share). Not the measured twists' difference: a wheel that starts to slip
            would hide behind it. A wheel frame that lags the gyro in a spin-up is then no
            slip (tests/test_ekf_timing.py). 0: stamps exact. Default 0.02 s, chosen by
            benchmarks/tune_ekf.py run (6): its cross-validation prefers 0.08 s, which
            breaks the bundled Jackal bag (a skid-steer's disagreeing turns hidden from the
            slip gate: yaw RMSE 21.5 deg instead of 1.07) and a turn carried by the wheels
            while the gyro saturates; 0.02 s is the largest value of its grid that keeps
            both, and beats 0 in both of its modes (so the Jackal bag's figures are
            in-sample for this value). The margin is narrow on a noisy gyro: the Jackal's
            (0.05 rad/s per sample) makes the filter's own dw/dt between twists mostly
            sample noise, and 0.05 s already gives 18.5 deg there; keep it at or below
            0.04 s unless the gyro is quiet. Held out (benchmarks/ekf_accuracy.py,
            seeds 0-7, with ``speed_ramp_time`` 0): final error and yaw RMSE unchanged
            within noise or better, pose NEES of "all" inside its bounds 85.2 % on average
            (84.4 % with 0), 79.8 % with the calibrated gyro (77.9 %); no false slips where
            late frames lag the gyro in spin-ups (tests/test_ekf_timing.py).
        twist_v_std, twist_w_std: noise of an external odometry twist (nav_msgs/Odometry
            from a ROS bag), m/s and rad/s.
        twist_zero_v, twist_zero_w: below both (m/s, rad/s) a twist counts as standing still.
        gyro_limit: gyro samples with ``|rate| >= gyro_limit`` (rad/s) are saturated and
            skipped (set it a little below the full scale: 4.3 for the MPU6050's +-250 deg/s).
        max_rate: a gyro sample or twist with a rate above this (rad/s) is corrupt: counted
            as invalid, never fused. The default is above every MEMS gyro's full scale
            (+-4000 deg/s = 70 rad/s).
        max_speed: inputs with a speed above this (m/s: either wheel of a frame, a twist)
            are corrupt: counted as invalid, never fused.
        initial_bias: prior mean of the gyro bias about the vertical, rad/s (0: unknown; a
            bias measured before the log, or the one ``fusion replay`` takes back from a
            moving start's first stop, :mod:`fusion.jobs.moving_start`).
        initial_bias_std: prior standard deviation of the gyro bias, rad/s.
        gyro_scale: prior mean of the gyro's scale error ``g`` (1; the gyro reads
            ``(1 + g)`` times the true rate): 0 for an uncalibrated gyro, or the result of
            :func:`fusion.calibration.gyro_scale.calibrate_gyro_scale` (turns in place back to
            a mark; ``fusion calibrate gyro-scale`` writes it into robot.toml's ``[ekf]``).
        gyro_scale_std: prior standard deviation of ``g`` (1): the MPU6050 datasheet's
            sensitivity tolerance, +-3 %, for an uncalibrated gyro (set from the datasheet,
            not tuned); the calibration's own standard deviation after a calibration.
        gyro_scale_psd: random walk of ``g``, 1/s (sensitivity drifts with temperature;
            small).
        distance_scale_std: prior standard deviation of the wheels' common distance scale
            error ``s`` (1): 1 % (tyre wear, pressure and load change the rolling radius;
            a value set by hand from that, not tuned on any run).
        distance_scale_psd: random walk of ``s``, 1/s.
        odometry_along_var, odometry_cross_var: white noise of the position per metre
            driven, along and across the heading, m^2/m (a standard deviation of
            ``sqrt(var * d)`` m after ``d`` m): wheel distance errors that accumulate along
            the path (slip on a low-friction floor, a rolling radius that changes with speed,
            floor texture; across: tyre creep in turns) and that the constant scale ``s``
            cannot stand for, since its error cancels when the robot drives back. They only
            widen the pose covariance (rate measurements never correct the position), so
            they change no estimate. Default 0, chosen by benchmarks/tune_ekf.py: with
            ``odometry_along_var`` 1e-4 the pose NEES on the physics simulator's "all"
            scenario lies inside its 95 % bounds on 90.4 % of the rows instead of 88.0 %
            (seeds 100-105, calibrated gyro; worst run 80.1 % against 81.6 %), while the runs
            without such errors become more underconfident ("plain" 49.7 -> 37.6 %, the
            kinematic simulator 56.1 -> 49.1 %); the cross-validated objective prefers 0.
        initial_speed_std: prior standard deviation of v (m/s) and w (rad/s); also the least
            variance of a speed forgotten by the gap policy. Under the default prior v is
            forgotten just before the first fused wheel frame or twist (its variance widened
            by (100 m/s)^2, ``_ekf_core.UNKNOWN_SPEED_VAR``), which then sets v alone: the
            robot may be driving when the filter starts (issue 11's outdoor bag); under a
            prior at rest, first frames whose yaw rate fails the slip gate would have their
            speed fused 1e5 times down-weighted, and v would stay near 0 for as long as they
            do.
        initial_rate_std: prior standard deviation of w from the first input until the first
            gyro sample, rad/s. That sample then sets w alone (w's variance is widened by
            (100 rad/s)^2 first, ``_ekf_core.UNKNOWN_RATE_VAR``): the robot may be turning at
            any rate when the filter starts, and under a prior the reading would be split
            between w and the bias by their variances, which nothing but a stop or trusted
            wheels undoes (the bundled Jackal bag, which never stops: a prior of 0.05 rad/s
            left a bias of 0.8 deg/s and a yaw RMSE of 27 deg; 1 rad/s still 0.03 deg/s when
            the same drive is cut to start turning at 0.45 rad/s; now below 1e-5 deg/s on
            both: nothing else tells this bag's bias, so it stays at its prior mean). Set
            from that reasoning, not tuned.
        wheel_rate_proof_time, wheel_rate_trust_time, max_slip_share: when the wheels' yaw
            rate is fused. Only turning frames (faster than 0.1 rad/s, measured or expected)
            test it. Proven: the wheels have agreed with the gyro (below the slip gate, and
            the slope of their yaw rate against the gyro's over the turns so far within 10 %
            of 1, ``_ekf_core.PROOF_TOLERANCE``: the gate alone passes a skid-steer's gentle
            turns while the bias is uncertain) over
            ``wheel_rate_proof_time`` s of turning; before that their yaw rates are not fused
            (while the bias is still uncertain the gate passes a skid-steer base's first
            turns, which would pull the bias), and a twist above the gate is no slip either
            (its speed is fused with its own noise): until then nothing says whether its
            disagreement is slip or the base's way of turning.
            Disproven: the share of turning frames above the slip gate, an exponentially
            weighted mean with time constant ``wheel_rate_trust_time`` (s of turning),
            exceeds ``max_slip_share`` (1): the wheels' yaw rate does not measure this
            robot's rotation (a skid-steer base, as in the bundled Jackal bag, where 83 % of
            the twists turn unlike the gyro; a badly wrong wheel distance), so a
            disagreement is no sign of slip: only the speed is fused, with its own noise and
            no slip flag, until the share falls below half of it. The time constant is long
            enough that a burst of slips (tests/test_ekf_real.py: 3 s of 50 % slip within 5
            s, share 0.45) does not disprove a diff-drive's wheels, and short enough that a
            skid-steer base's first turns, flagged as slips and their speed down-weighted
            until then, cost little (Jackal bag: final position error 0.49 / 0.72 / 1.10 /
            2.53 % of the distance with 2 / 3 / 5 / 10 s). While the gyro is saturated, and for
            ``wheel_rate_proof_time`` after, the wheels are fused regardless (they are all
            there is). Set by hand from that reasoning, not tuned.
        straight_rate: rad/s (0: off). A wheel frame or twist whose yaw rate is not fused
            (not yet proven in turns, or disproven) but is below this while the robot moves
            still says the robot drives straight, if the source's yaw rate has so far
            correlated with the gyro's over its moving frames (by 0.9, whatever its scale,
            ``_ekf_core.LINEAR_SOURCE_CORRELATION``: a skid-steer base's twist, not the
            Jackal bag's): it is fused as such, through the wheel model's yaw-rate row, its
            noise widened by the rate itself (the source's scale unknown), and gated
            (``_ekf_core._straight_update``). Before the first stop that is all that tells
            the gyro's bias of a robot that starts moving. Chosen by leave-one-seed-out
            cross-validation over the terrain benchmark's bags
            (benchmarks/terrain/cv_straight_rate.py: outdoor-bag and hills-bag, seeds 1-6,
            position RMSE against GPS; grid 0, 0.005, 0.01, 0.02, 0.03, 0.05 rad/s): 0.02 in
            4 of 6 folds, cross-validated 2.25 m (2.78 m without); seeds 7-9 held out (2.50
            m, gyro at stops 2.42 m).
        wheel_scale_refit: standard deviations of ``calib_k_std`` (0: off, the default).
            When the slope of the wheel ticks' yaw rate fitted against the gyro's (moving
            tick frames since the last restart, once they hold ``wheel_rate_proof_time`` s
            of turning and correlate by 0.9) is more than this many prior standard
            deviations of ``k`` off ``1 + k``, ``k`` restarts at the slope and ``c`` at 0,
            both with their prior variances (``_ekf_core._refit_wheel_scale``): for a base
            whose robot.toml wheel_distance does not fit (a skid-steer base counted with its
            geometric track, a mistyped distance), which ``k`` would follow from its prior
            only after the turns' disagreement had bent the gyro bias and ``c``. 3 matches
            the trust check ``wheel_scale``'s 15 % with the default ``calib_k_std``. Opt-in:
            on a correct two-wheel base it can only misfire (a 10 % slip of one wheel for 6 s
            early in a drive restarted it once, yaw RMSE 1.23 -> 2.05 deg); with such a base
            the right fix is its wheel_distance (``fusion calibrate odometry``), which the
            ``wheel_scale`` warning asks for. With 3, the terrain benchmark's skid-steer
            ticks driving from the first sample: yaw RMSE 17.8 -> 9.9 deg mean on seeds 1-6,
            40.5 -> 35.9 on held-out seeds 7-12. Wheel ticks only: an external odometry's
            yaw rate is fused only once proven within 10 % of 1.

    Raises:
        ValueError: a value that is not a number, a measurement noise, prior, time step or
            limit that is not finite and > 0, any other value that is negative or not finite,
            ``zupt_frames`` not a whole number >= 1, ``still_scale`` > 1, or more than
            :data:`MAX_STEPS_PER_INPUT` prediction steps per input; the message names the
            field and the value.
    """

    gyro_std: float = math.radians(0.005) * 10.0
    accel_psd: float = 0.002
    accel_speed_psd: float = 0.0
    accel_offset_time: float = 5.0
    angular_accel_psd: float = 0.2
    bias_psd: float = (1e-4) ** 2
    tick_std: float = 0.5
    scale_std: float = 0.005
    separation_std: float = 0.005
    wheel_w_std: float = 0.002
    calib_k_std: float = 0.05
    calib_c_std: float = 0.05
    calib_k_psd: float = 1e-9
    calib_c_psd: float = 1e-9
    wheel_rate_scale: float = 0.0
    wheel_rate_per_speed: float = 0.0
    zupt_v_std: float = 1e-3
    zupt_w_std: float = 1e-4
    zupt_frames: int = 2
    still_scale: float = 1e-4
    slip_gate: float = 10.83
    slip_inflation: float = 1e5
    slip_window: float = 0.2
    stop_decel: float = 3.0
    turn_w_std: float = 0.0
    wheel_w_corr_time: float = 0.0
    yaw_fix_rate: float = math.radians(5.0)
    yaw_fix_burst: float = math.radians(1.0)
    late_tolerance: float = 0.05
    max_dt: float = 0.05
    max_extrapolation: float = 3.0
    wheel_latency: float = 0.0
    stamp_std: float = 0.02
    speed_ramp_time: float = 0.1
    twist_v_std: float = 0.01
    twist_w_std: float = 0.01
    twist_zero_v: float = 1e-3
    twist_zero_w: float = 1e-3
    gyro_limit: float = math.inf
    max_rate: float = 100.0
    max_speed: float = 50.0
    initial_bias: float = 0.0
    initial_bias_std: float = math.radians(2.0)
    gyro_scale: float = 0.0
    gyro_scale_std: float = 0.03
    gyro_scale_psd: float = 1e-9
    distance_scale_std: float = 0.01
    distance_scale_psd: float = 1e-9
    odometry_along_var: float = 0.0
    odometry_cross_var: float = 0.0
    slip_accel_psd: float = 0.02
    initial_speed_std: float = 0.05
    initial_rate_std: float = 1.0
    wheel_rate_proof_time: float = 2.0
    wheel_rate_trust_time: float = 5.0
    max_slip_share: float = 0.5
    straight_rate: float = 0.02
    wheel_scale_refit: float = 0.0

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f"EkfNoise.{name} must be a number, got {value!r}")
            if name in ("gyro_scale", "wheel_rate_scale"):
                ok, need = math.isfinite(value) and abs(value) < 0.5, "finite, in (-0.5, 0.5)"
            elif name in ("initial_bias", "wheel_rate_per_speed"):
                ok, need = math.isfinite(value), "finite (rad/s, rad/m)"
            elif name in ("gyro_limit", "yaw_fix_rate", "yaw_fix_burst"):
                ok, need = value > 0, "> 0 (rad/s or rad; or inf)"
            elif name == "zupt_frames":
                ok, need = value >= 1 and float(value).is_integer(), "a whole number >= 1"
            elif name in _POSITIVE:
                ok, need = math.isfinite(value) and value > 0, "finite and > 0"
            else:
                ok, need = math.isfinite(value) and value >= 0, "finite and >= 0"
            if not ok:
                raise ValueError(f"EkfNoise.{name} must be {need}, got {value!r}")
        if self.still_scale > 1:
            raise ValueError(f"EkfNoise.still_scale must be <= 1 (it shrinks the random walks "
                             f"while still), got {self.still_scale!r}")
        steps = self.max_extrapolation / self.max_dt
        if steps > MAX_STEPS_PER_INPUT:
            raise ValueError(f"EkfNoise.max_dt = {self.max_dt!r} s is absurdly short for "
                             f"max_extrapolation = {self.max_extrapolation!r} s: {steps:.3g} "
                             f"prediction steps per input (at most {MAX_STEPS_PER_INPUT})")


#: Fields of :class:`EkfNoise` that must be > 0: measurement noises (a zero one would make the
#: innovation covariance singular), priors, time steps, gates and plausibility limits.
_POSITIVE = frozenset({
    "gyro_std", "tick_std", "zupt_v_std", "zupt_w_std", "twist_v_std", "twist_w_std",
    "initial_bias_std", "initial_speed_std", "max_dt", "max_extrapolation", "slip_gate",
    "max_rate", "max_speed", "wheel_rate_trust_time", "max_slip_share", "initial_rate_std",
    "wheel_rate_proof_time", "accel_offset_time",
})
#: Upper bound on ``max_extrapolation / max_dt``: the prediction steps one input may cost.
MAX_STEPS_PER_INPUT = 10_000


def _state_vector(name: str, value: ArrayLike) -> NDArray[np.float64]:
    """A finite (NX,) state ``[x, y, yaw, v, w, b, k, c, g, s]``; ``ValueError`` naming
    ``name``."""
    x = np.array(value, dtype=float).reshape(-1)
    if x.shape != (NX,) or not np.all(np.isfinite(x)):
        raise ValueError(f"{name} must be {NX} finite values [x, y, yaw, v, w, b, k, c, g, s], "
                         f"got {x.tolist()}")
    return x


def _covariance(name: str, value: ArrayLike) -> NDArray[np.float64]:
    """A finite symmetric (NX, NX) covariance with a non-negative diagonal; ``ValueError``."""
    P = np.array(value, dtype=float)
    if P.shape != (NX, NX) or not np.all(np.isfinite(P)):
        raise ValueError(f"{name} must be a finite {NX} x {NX} covariance, got shape {P.shape}")
    if np.any(np.diag(P) < 0) or not np.allclose(P, P.T, rtol=1e-9, atol=1e-300):
        raise ValueError(f"{name} must be symmetric with a non-negative diagonal, got "
                         f"diagonal {np.diag(P).tolist()}")
    return P


def odometry_covariances(P: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """nav_msgs/Odometry covariances (36-element, row major) from the EKF covariance.

    Pose order ``(x, y, z, rot_x, rot_y, rot_z)`` in odom: the (x, y, yaw) block of ``P``;
    twist order ``(vx, vy, vz, wx, wy, wz)`` in base_footprint: v and w. Components the
    planar filter does not estimate (z, roll, pitch, their rates and the lateral speed) get
    seed 000's 99999 on the diagonal.
    """
    P = np.asarray(P, dtype=float)
    if P.ndim != 2 or P.shape[0] != P.shape[1] or P.shape[0] < 5:
        raise ValueError(f"P must be square with the state order x, y, yaw, v, w, got {P.shape}")
    u = UNOBSERVED_VARIANCE
    pose = np.diag([0.0, 0.0, u, u, u, 0.0])
    idx = [0, 1, 5]
    for a, i in zip(idx, (0, 1, 2), strict=True):
        for b, j in zip(idx, (0, 1, 2), strict=True):
            pose[a, b] = P[i, j]
    twist = np.diag([0.0, u, u, u, u, 0.0])
    twist[0, 0] = P[3, 3]
    twist[0, 5] = twist[5, 0] = P[3, 4]
    twist[5, 5] = P[4, 4]
    return pose.reshape(36), twist.reshape(36)


def pose_covariances(states: ArrayLike) -> NDArray[np.float64]:
    """(N, 3, 3) covariances of ``(x, y, yaw)`` from the rows of :meth:`PlanarEKF.process_batch`
    (m^2, m*rad, rad^2): those of the pose held in the rows
    (:meth:`PlanarEKF.reported_covariance`)."""
    s = np.asarray(states, dtype=float)
    if s.ndim != 2 or s.shape[1] < core.ROW_WIDTH:
        raise ValueError(f"states must be (N, {core.ROW_WIDTH}) rows of process_batch, got "
                         f"{s.shape}")
    P = np.empty((s.shape[0], 3, 3))
    P[:, 0, 0], P[:, 1, 1], P[:, 2, 2] = s[:, NX], s[:, NX + 1], s[:, NX + 2]
    P[:, 0, 1] = P[:, 1, 0] = s[:, 2 * NX]
    P[:, 0, 2] = P[:, 2, 0] = s[:, 2 * NX + 1]
    P[:, 1, 2] = P[:, 2, 1] = s[:, 2 * NX + 2]
    return P


def merge_events(
    imu_t: ArrayLike | None,
    gyro_z: ArrayLike | None,
    wheel_t: ArrayLike | None,
    ticks: ArrayLike | None,
    period: float,
    wheel_latency: float = 0.0,
    yaw_t: ArrayLike | None = None,
    yaw: ArrayLike | None = None,
    yaw_std: ArrayLike | float = 0.01,
    twist_t: ArrayLike | None = None,
    twist_v: ArrayLike | None = None,
    twist_w: ArrayLike | None = None,
    imu_motion: ArrayLike | None = None,
    wheel_slip: ArrayLike | None = None,
    accel_x: ArrayLike | None = None,
):
    """Merge gyro, wheel, absolute-yaw and twist inputs into one time-ordered event list.

    Args:
        imu_t, gyro_z: gyro stamps (s) and vertical rates (rad/s), or None.
        wheel_t, ticks: wheel frame stamps (s, end of period) and (M, 2) ticks, or None.
        period: ``encode_sampling_time``, s.
        wheel_latency: s, subtracted from wheel stamps with half a period.
        yaw_t, yaw, yaw_std: absolute yaw stamps (s), values (rad), standard deviations (rad).
        twist_t, twist_v, twist_w: external odometry twists: stamps (s), forward speed (m/s),
            yaw rate (rad/s), fused at their stamps.
        imu_motion: (N,) IMU motion code of each gyro sample
            (:func:`fusion.planar.imu_motion.imu_motion_codes`), or None (unknown).
        wheel_slip: (M,) bool, the wheel frames the accelerometer says slip
            (:func:`fusion.planar.accel_slip.accel_slip_flags`): their kind is
            ``EV_WHEELS_SLIP`` (fused as a slip), or None (none flagged).
        accel_x: (N,) forward specific force of each IMU sample (base frame x, m/s^2): an
            ``EV_ACCEL`` event at the sample's stamp, right after its gyro event; or None.

    Returns:
        ``(kinds, t_eff, a, b, stamp)`` arrays sorted by effective time (stable; at equal
        times gyro, wheels, yaw, twist). ``stamp`` is each input's own stamp.
    """
    kinds, ts, aa, bb, st = [], [], [], [], []
    if wheel_t is not None:
        wt = np.asarray(wheel_t, dtype=float).reshape(-1)
        tk = np.asarray(ticks, dtype=float).reshape(-1, 2)
        if tk.shape[0] != wt.size:
            raise ValueError(f"{wt.size} wheel stamps but {tk.shape[0]} tick rows")
        wheel_kinds = np.full(wt.size, core.EV_WHEELS)
        if wheel_slip is not None:
            slip = np.asarray(wheel_slip, dtype=bool).reshape(-1)
            if slip.size != wt.size:
                raise ValueError(f"{wt.size} wheel stamps but {slip.size} slip flags")
            wheel_kinds[slip] = core.EV_WHEELS_SLIP
        kinds.append(wheel_kinds)
        ts.append(wt - 0.5 * period - wheel_latency)
        aa.append(tk[:, 0])
        bb.append(tk[:, 1])
        st.append(wt)
    if imu_t is not None:
        it = np.asarray(imu_t, dtype=float).reshape(-1)

        def per_sample(values, what: str) -> NDArray[np.float64]:
            out = np.asarray(values, dtype=float).reshape(-1)
            if out.size != it.size:
                raise ValueError(f"{it.size} IMU stamps but {out.size} {what}")
            return out

        codes = np.zeros(it.size) if imu_motion is None else per_sample(imu_motion,
                                                                         "motion codes")
        imu_kinds = [(core.EV_GYRO, per_sample(gyro_z, "gyro rates"), codes)]
        if accel_x is not None:
            imu_kinds.append((core.EV_ACCEL, per_sample(accel_x, "forward specific forces"),
                              np.zeros(it.size)))
        for kind, a_col, b_col in imu_kinds:
            kinds.append(np.full(it.size, kind))
            ts.append(it)
            aa.append(a_col)
            bb.append(b_col)
            st.append(it)
    elif accel_x is not None:
        raise ValueError("accel_x needs the IMU stamps imu_t")
    if yaw_t is not None:
        yt = np.asarray(yaw_t, dtype=float).reshape(-1)
        kinds.append(np.full(yt.size, core.EV_YAW))
        ts.append(yt)
        aa.append(np.broadcast_to(np.asarray(yaw, dtype=float), yt.shape))
        bb.append(np.broadcast_to(np.asarray(yaw_std, dtype=float), yt.shape))
        st.append(yt)
    if twist_t is not None:
        tt = np.asarray(twist_t, dtype=float).reshape(-1)
        tv = np.asarray(twist_v, dtype=float).reshape(-1)
        tw = np.asarray(twist_w, dtype=float).reshape(-1)
        if not (tv.size == tw.size == tt.size):
            raise ValueError(f"{tt.size} twist stamps but {tv.size} v and {tw.size} w values")
        kinds.append(np.full(tt.size, core.EV_TWIST))
        ts.append(tt)
        aa.append(tv)
        bb.append(tw)
        st.append(tt)
    if not kinds:
        return (np.zeros(0, np.int64), *(np.zeros(0) for _ in range(4)))
    k = np.concatenate(kinds).astype(np.int64)
    t = np.concatenate(ts)
    # at equal times a slipping wheel frame sorts as a wheel frame, a forward specific force
    # as a gyro sample (after it: lexsort is stable), as the pipeline orders them
    rank = np.where(k == core.EV_WHEELS_SLIP, core.EV_WHEELS, k)
    order = np.lexsort((np.where(k == core.EV_ACCEL, core.EV_GYRO, rank), t))
    return (k[order], t[order], np.concatenate(aa)[order], np.concatenate(bb)[order],
            np.concatenate(st)[order])


class ReorderBuffer:
    """Release events in time order once they are older than the newest by ``window`` s.

    For live use with several sources whose stamps interleave imperfectly: ``push`` events as
    they arrive, feed what ``pop_ready`` returns to the filter, ``flush`` at the end.
    """

    def __init__(self, window: float) -> None:
        if not window >= 0:
            raise ValueError(f"window must be >= 0 s, got {window!r}")
        self.window = float(window)
        self._heap: list = []
        self._newest = -math.inf
        self._count = 0

    def push(self, t: float, event) -> None:
        """Hold ``event`` with time ``t`` s (finite, else ``ValueError``)."""
        if not math.isfinite(t):
            raise ValueError(f"ReorderBuffer.push needs a finite time in s, got {t!r}")
        heapq.heappush(self._heap, (float(t), self._count, event))
        self._count += 1
        self._newest = max(self._newest, float(t))

    def pop_ready(self) -> list:
        out = []
        while self._heap and self._heap[0][0] <= self._newest - self.window:
            t, _, ev = heapq.heappop(self._heap)
            out.append((t, ev))
        return out

    def flush(self) -> list:
        out = []
        while self._heap:
            t, _, ev = heapq.heappop(self._heap)
            out.append((t, ev))
        return out

    def __len__(self) -> int:
        return len(self._heap)


def _check_backend(backend: str) -> None:
    """The deprecated ``backend`` argument of :class:`PlanarEKF`: a warning or a clear error."""
    if backend == "filterpy":
        raise ValueError(
            "PlanarEKF(backend='filterpy') was removed: the filter has one implementation "
            "(fusion.planar._ekf_core over fusion.planar.model), compiled by numba when it is "
            "installed and run as plain Python otherwise, with the same results; leave "
            "backend out")
    if backend not in ("auto", "core"):
        raise ValueError(f"PlanarEKF backend is deprecated (leave it out), got {backend!r}")
    warnings.warn("PlanarEKF's backend argument is deprecated and has no effect: leave it out",
                  DeprecationWarning, stacklevel=3)


class PlanarEKF(ExtendedKalmanFilter):
    """Wheel + gyro EKF with a gyro-bias state (see the module docstring for the model).

    Args:
        robot: chassis parameters (``wheel_distance`` m, ``speed_ratio`` m/tick,
            ``encode_sampling_time`` s).
        noise: :class:`EkfNoise`.
        x0: initial state ``[x, y, yaw, v, w, b, k, c, g, s]`` (default zeros, except
            ``b = noise.initial_bias``, ``k = noise.wheel_rate_scale``,
            ``c = noise.wheel_rate_per_speed`` and ``g = noise.gyro_scale``).
        P0: initial covariance (default: pose variance 1e-9, v/w/b/k/c/g/s from ``noise``;
            with the default, w counts as unknown at the first gyro sample, which sets it
            alone: see ``EkfNoise.initial_rate_std``; a ``P0`` given here is taken as is).
        backend: deprecated, leave it out. There is one implementation, the core
            (:mod:`fusion.planar._ekf_core` over :mod:`fusion.planar.model`): compiled by numba
            when installed, interpreted otherwise, with the same results. ``"core"`` and
            ``"auto"`` are accepted with a :class:`DeprecationWarning`; ``"filterpy"`` (a
            second transcription of the model, removed) raises :class:`ValueError`.

    Attributes:
        t: filter time, s (None before the first input).
        stats: counters: ``slips`` (frames fused as slipping: yaw rate not fused, speed
            down-weighted, or with its own noise when only the persistent-disagreement test
            flagged the frame, ``slip_window``), ``accel_slips`` (of those, the
            ones the accelerometer flagged), ``wheel_rate_distrusted`` (turning frames or
            twists whose yaw rate was not fused because most turns disagreed with the gyro, or
            twists that disagreed before the external odometry was proven in turns),
            ``straight_frames`` (of the frames whose yaw rate was not trusted, those fused as
            driving straight, ``straight_rate``), ``wheel_scale_refits`` (times the wheels'
            yaw-rate scale ``k`` restarted at the slope fitted against the gyro, because it was
            more than ``wheel_scale_refit`` times ``calib_k_std`` off it: a skid-steer base, a
            wrong wheel_distance; off by default), ``bias_relearnt`` (stops whose ZUPTs kept
            finding the same gyro offset the bias did not explain, so the bias's variance was
            opened for it: a bias gone wrong before, :func:`fusion.planar._ekf_core.
            _relearn_bias_at_stop`),
            ``zupts``, ``late_dropped``, ``late_applied``,
            ``invalid`` (non-finite or implausible inputs), ``gyro_saturated``,
            ``gyro_spikes`` (gyro samples further from the predicted rate than any robot
            turns: a glitch, not fused; :data:`fusion.planar._ekf_core.MAX_ANGULAR_ACCEL`),
            ``encoder_faults``, ``fault_turn`` (rad, a float: the yaw rate state integrated
            over the intervals of those frames, the turn the odometry could not see),
            ``updates``, ``speed_resets`` (v or w forgotten by the gap policy),
            ``predictions`` (prediction steps).
    """

    def __init__(
        self,
        robot: DiffDriveParams,
        noise: EkfNoise | None = None,
        x0: ArrayLike | None = None,
        P0: ArrayLike | None = None,
        backend: str | None = None,
    ) -> None:
        super().__init__(dim_x=NX, dim_z=2)
        if backend is not None:
            _check_backend(backend)
        if not isinstance(robot, DiffDriveParams):
            raise ValueError(f"robot must be a DiffDriveParams, got {type(robot).__name__}")
        if noise is not None and not isinstance(noise, EkfNoise):
            raise ValueError(f"noise must be an EkfNoise, got {type(noise).__name__}")
        self.robot = robot
        self.noise = noise if noise is not None else EkfNoise()
        n = self.noise
        if x0 is None:
            self.x = np.zeros(NX)
            self.x[5] = n.initial_bias  # 0 unless known before the log
            self.x[6] = n.wheel_rate_scale  # 0 unless known (a replay's second pass)
            self.x[7] = n.wheel_rate_per_speed
            self.x[8] = n.gyro_scale  # a calibrated gyro's scale error, 0 if uncalibrated
        else:
            self.x = _state_vector("x0", x0)
        if P0 is None:
            s = n.initial_speed_std
            # the odom origin is the start pose; 1e-9 (m^2, rad^2) keeps P positive definite
            self.P = np.diag([1e-9, 1e-9, 1e-9, s * s, n.initial_rate_std ** 2,
                              n.initial_bias_std ** 2,
                              n.calib_k_std ** 2, n.calib_c_std ** 2, n.gyro_scale_std ** 2,
                              n.distance_scale_std ** 2])
        else:
            self.P = _covariance("P0", P0)
        self._par = np.zeros(core.PAR_SIZE)
        par = self._par
        par[core.P_SPEED_RATIO] = robot.speed_ratio
        par[core.P_WHEEL_DISTANCE] = robot.wheel_distance
        par[core.P_PERIOD] = robot.encode_sampling_time
        par[core.P_Q_V] = n.accel_psd
        par[core.P_Q_W] = n.angular_accel_psd
        par[core.P_Q_B] = n.bias_psd
        par[core.P_GYRO_VAR] = n.gyro_std ** 2
        par[core.P_TICK_STD] = n.tick_std
        par[core.P_SCALE_STD] = n.scale_std
        par[core.P_SEP_STD] = n.separation_std
        par[core.P_ZUPT_V_STD] = n.zupt_v_std
        par[core.P_ZUPT_W_STD] = n.zupt_w_std
        par[core.P_GATE] = n.slip_gate
        par[core.P_SLIP_INFLATION] = n.slip_inflation
        par[core.P_ZUPT_FRAMES] = n.zupt_frames
        par[core.P_LATE_TOLERANCE] = n.late_tolerance
        par[core.P_MAX_DT] = n.max_dt
        par[core.P_WHEEL_W_STD] = n.wheel_w_std
        par[core.P_Q_K] = n.calib_k_psd
        par[core.P_Q_C] = n.calib_c_psd
        par[core.P_STILL_SCALE] = n.still_scale
        par[core.P_TWIST_V_STD] = n.twist_v_std
        par[core.P_TWIST_W_STD] = n.twist_w_std
        par[core.P_TWIST_ZERO_V] = n.twist_zero_v
        par[core.P_TWIST_ZERO_W] = n.twist_zero_w
        par[core.P_GYRO_LIMIT] = n.gyro_limit
        par[core.P_STOP_DECEL] = n.stop_decel
        par[core.P_YAW_FIX_RATE] = n.yaw_fix_rate
        par[core.P_YAW_FIX_BURST] = n.yaw_fix_burst
        par[core.P_WHEEL_W_CORR] = n.wheel_w_corr_time
        par[core.P_TURN_W_STD] = n.turn_w_std
        par[core.P_HORIZON] = n.max_extrapolation
        par[core.P_SPEED_VAR0] = n.initial_speed_std ** 2
        par[core.P_MAX_RATE] = n.max_rate
        par[core.P_MAX_SPEED] = n.max_speed
        par[core.P_Q_G] = n.gyro_scale_psd
        par[core.P_Q_S] = n.distance_scale_psd
        par[core.P_TRUST_TIME] = n.wheel_rate_trust_time
        par[core.P_MAX_SLIP_SHARE] = n.max_slip_share
        par[core.P_PROOF_TIME] = n.wheel_rate_proof_time
        par[core.P_STRAIGHT_RATE] = n.straight_rate
        par[core.P_K_STD] = n.calib_k_std
        par[core.P_REFIT] = n.wheel_scale_refit
        par[core.P_C_MEAN] = n.wheel_rate_per_speed
        par[core.P_C_STD] = n.calib_c_std
        par[core.P_ODO_ALONG] = n.odometry_along_var
        par[core.P_ODO_CROSS] = n.odometry_cross_var
        par[core.P_SLIP_Q_V] = n.slip_accel_psd
        par[core.P_ACCEL_Q_V] = n.accel_speed_psd
        par[core.P_OFFSET_TIME] = n.accel_offset_time
        par[core.P_STAMP_STD] = n.stamp_std
        par[core.P_SPEED_RAMP_TIME] = n.speed_ramp_time
        par[core.P_SLIP_WINDOW] = n.slip_window
        self._aux = np.zeros(core.AUX_SIZE)
        self._aux[core.A_T] = math.nan
        self._aux[core.A_WHEEL_T] = math.nan
        self._aux[core.A_MOVED_T] = math.nan
        self._aux[core.A_MOVED_W] = math.nan
        self._aux[core.A_YAW_BUDGET] = n.yaw_fix_burst
        # the wheels' yaw rate: no disagreement seen, not yet proven in turns (A_AGREED 0)
        self._aux[core.A_CLIPPED] = math.nan
        self._aux[core.A_GYRO_T] = math.nan  # no gyro sample fused yet (the spike test)
        # no forward specific force yet, no accelerometer offset learnt
        self._aux[core.A_FX] = math.nan
        self._aux[core.A_FX_T] = math.nan
        self._aux[core.A_FX_OFFSET] = math.nan
        # the default prior does not know w: the first gyro sample sets it (step_core)
        self._aux[core.A_FIRST_GYRO] = 1.0 if P0 is None else 0.0
        # nor v: the first fused wheel frame or twist sets it (_ekf_core._wheel_event)
        self._aux[core.A_FIRST_SPEED] = 1.0 if P0 is None else 0.0
        self._aux[core.A_TWIST_T] = math.nan  # no wheel twist yet (stamp noise)
        # the persistent-disagreement test: no frame yet, no disagreement under way
        self._aux[core.A_WIN_T] = math.nan
        self._aux[core.A_WIN_SINCE] = math.nan
        self._aux[core.A_STEADY_W] = math.nan
        self._aux[core.A_STEADY_T] = math.nan

    # -- state -------------------------------------------------------------------------------
    @property
    def t(self) -> float | None:
        t = self._aux[core.A_T]
        return None if math.isnan(t) else float(t)

    @property
    def stats(self) -> dict[str, int | float]:
        a = self._aux
        return {
            "slips": int(a[core.A_SLIPS]),
            "accel_slips": int(a[core.A_ACCEL_SLIPS]),
            "wheel_rate_distrusted": int(a[core.A_DISTRUSTED]),
            "zupts": int(a[core.A_ZUPTS]),
            "late_dropped": int(a[core.A_LATE_DROPPED]),
            "late_applied": int(a[core.A_LATE_APPLIED]),
            "invalid": int(a[core.A_ERROR]),
            "gyro_saturated": int(a[core.A_SATURATED]),
            "gyro_spikes": int(a[core.A_GYRO_SPIKES]),
            "encoder_faults": int(a[core.A_FAULTS]),
            "catch_ups": int(a[core.A_CATCH_UPS]),
            "fault_turn": float(a[core.A_FAULT_TURN]),
            "updates": int(a[core.A_UPDATES]),
            "speed_resets": int(a[core.A_SPEED_RESETS]),
            "predictions": int(a[core.A_PREDICTIONS]),
            "straight_frames": int(a[core.A_STRAIGHTS]),
            "wheel_scale_refits": int(a[core.A_REFITS]),
            "bias_relearnt": int(a[core.A_BIAS_RELEARNT]),
        }

    @property
    def pose(self) -> NDArray[np.float64]:
        """``[x, y, yaw]`` (m, m, rad wrapped to (-pi, pi])."""
        return np.array([self.x[0], self.x[1], wrap_angle_scalar(float(self.x[2]))])

    @property
    def gyro_bias(self) -> float:
        """Estimated gyro bias about the vertical, rad/s."""
        return float(self.x[5])

    @property
    def odometry_rate_fit(self) -> tuple[int, float, float] | None:
        """How the wheels' or twists' yaw rate followed the gyro's over every moving frame so
        far: ``(frames, slope, correlation)``, the slope of the least-squares line of the
        odometry's rate against the gyro's (1: the same scale; a skid-steer base's twist
        computed with its geometric track: about 1.5) and their correlation (NaN while the
        odometry's rate has not varied); None until the gyro's rates spread by
        ``_ekf_core.PROOF_SPREAD`` (turns of one rate alone cannot tell a scale)."""
        n, slope, corr = core._linear_fit(self._aux, core.A_LIN_N)
        if math.isnan(slope):
            return None
        return int(n), float(slope), float(corr)

    def get_state(self) -> dict:
        """A snapshot (copies) that :meth:`set_state` restores exactly."""
        return {"x": self.x.copy(), "P": self.P.copy(), "aux": self._aux.copy()}

    def set_state(self, state: dict) -> None:
        """Restore a snapshot of :meth:`get_state`; ``ValueError`` (the filter unchanged) for
        a non-finite state, a covariance that is not symmetric with a non-negative diagonal,
        or bookkeeping of the wrong size."""
        x = _state_vector("state['x']", state["x"])
        P = _covariance("state['P']", state["P"])
        aux = np.array(state["aux"], dtype=float).reshape(-1)
        if aux.shape != (core.AUX_SIZE,) or np.any(np.isinf(aux)):
            raise ValueError(f"state['aux'] must be {core.AUX_SIZE} values from get_state, got "
                             f"{aux.size} ({aux.tolist()})")
        held = aux[[core.A_YAW_PENDING, core.A_HELD_X, core.A_HELD_Y]]
        if not np.all(np.isfinite(held)):
            raise ValueError("state['aux'] must hold a finite owed heading and held-pose offset "
                             f"(A_YAW_PENDING, A_HELD_X, A_HELD_Y), got {held.tolist()}")
        self.x, self.P, self._aux = x, P, aux

    def covariances_ros(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(pose_covariance, twist_covariance)`` in nav_msgs/Odometry layout; the pose's is
        :meth:`reported_covariance`'s."""
        return odometry_covariances(self.reported_covariance())

    def reported_covariance(self) -> NDArray[np.float64]:
        """``P`` with the pose block (x, y, yaw) about the pose held in ``x``: while a heading
        correction is owed (the yaw budget, ``yaw_fix_rate``) ``P`` is that of the full
        correction, and the held pose is off by a known amount
        (:func:`fusion.planar._ekf_core.held_pose_offset`) that this adds (``P + d d^T``);
        what the state rows and the pipeline's records report."""
        d = np.array(core.held_pose_offset(self._aux))
        reported = np.array(self.P, dtype=float)
        reported[:3, :3] += np.outer(d, d)
        return reported

    # -- streaming inputs --------------------------------------------------------------------
    def _step(self, kind: int, t: float, a: float, b: float) -> int:
        self.x = np.ascontiguousarray(self.x, dtype=float).reshape(NX)
        self.P = np.ascontiguousarray(self.P, dtype=float)
        return int(core.step_core(self.x, self.P, self._aux, self._par, kind, float(t),
                                  float(a), float(b)))

    def update_gyro(self, t: float, rate_z: float, motion: int = 0) -> int:
        """Fuse a heading rate (rad/s) stamped ``t`` (s), with the sample's IMU motion code
        ``motion`` (:mod:`fusion.planar.imu_motion`; 0 unknown).

        Use :func:`vertical_rate` for a tilted robot (on hills see the module docstring).
        Returns the status code of :func:`fusion.planar._ekf_core.step_core` (0 applied, 5
        dropped as too late, 6 invalid).
        """
        return self._step(core.EV_GYRO, t, rate_z, motion)

    def update_wheels(self, t: float, left: int, right: int, slip: bool = False) -> int:
        """Fuse one wheel frame: ``left``, ``right`` ticks counted in the period ending at
        host time ``t`` (s); ``slip``: the accelerometer says the frame slips
        (:mod:`fusion.planar.accel_slip`), fuse it as a slip whatever the gyro gate says.
        Returns the status (0 applied, 1 slip: speed down-weighted, yaw rate not fused,
        4 ZUPT, 5 too late, 7 encoder fault: not fused)."""
        t_eff = t - 0.5 * self.robot.encode_sampling_time - self.noise.wheel_latency
        return self._step(core.EV_WHEELS_SLIP if slip else core.EV_WHEELS, t_eff, left, right)

    def update_accel(self, t: float, f_x: float) -> int:
        """Feed the forward specific force ``f_x`` (m/s^2, base frame x, gravity included)
        of the IMU sample stamped ``t`` (s): it drives v when ``accel_speed_psd`` > 0 (see
        :class:`EkfNoise`). Returns the status (0 kept, 5 too late, 6 invalid)."""
        return self._step(core.EV_ACCEL, t, f_x, 0.0)

    def update_twist(self, t: float, v: float, w: float) -> int:
        """Fuse an external wheel-odometry twist: forward speed ``v`` (m/s) and yaw rate ``w``
        (rad/s) at time ``t`` (s), e.g. the twist of a nav_msgs/Odometry message. Noise from
        ``twist_v_std``/``twist_w_std``; near-zero twists trigger ZUPTs like zero ticks."""
        return self._step(core.EV_TWIST, t, v, w)

    def update_yaw(self, t: float, yaw: float, std: float) -> int:
        """Fuse an absolute yaw (rad, in odom) with standard deviation ``std`` (rad)."""
        if not (math.isfinite(std) and std > 0):
            raise ValueError(f"yaw std must be finite and > 0 rad, got {std!r}")
        return self._step(core.EV_YAW, t, yaw, std)

    def predict(self, u=0, dt: float | None = None) -> None:
        """filterpy's ``predict`` with the step made explicit: propagate by ``dt`` s.

        ``u`` is accepted for filterpy compatibility and must be 0 (the model has no control
        input). The filter time, if set, advances by ``dt``. Prefer :meth:`predict_to`.
        """
        if dt is None or not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"PlanarEKF.predict needs dt > 0 s (got {dt!r}); or use "
                             "predict_to(t)")
        if np.any(u != 0):
            raise ValueError("PlanarEKF has no control input: u must be 0")
        t = self.t
        if t is None:
            self._aux[core.A_T] = 0.0
            t = 0.0
        self.predict_to(t + dt)

    def predict_to(self, t: float) -> None:
        """Propagate to time ``t`` s without a measurement (ignored if ``t`` is not newer).

        The gap policy of the module docstring applies (bounded cost and extrapolation)."""
        if not math.isfinite(t):
            raise ValueError(f"predict_to needs a finite time in s, got {t!r}")
        if self.t is None or t <= self.t:
            return
        self.x = np.ascontiguousarray(self.x, dtype=float).reshape(NX)
        self.P = np.ascontiguousarray(self.P, dtype=float)
        core._advance(self.x, self.P, self._aux, self._par, float(t))

    # -- batch -------------------------------------------------------------------------------
    def process_batch(self, kinds, t_eff, a, b) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """Run a merged event list (see :func:`merge_events`) through the filter.

        Returns ``(states, status)``: ``states[k, :NX]`` is ``[x, y, yaw, v, w, b, k, c, g, s]``
        after event k (yaw continuous), ``states[k, NX:2*NX]`` the diagonal of P and
        ``states[k, 2*NX:2*NX+3]`` its pose cross terms ``P[x,y], P[x,yaw], P[y,yaw]`` (see
        :func:`pose_covariances`; the pose block is that of the held pose,
        :meth:`reported_covariance`);
        ``status[k]`` the update status. Exactly equal to calling the streaming methods one
        event at a time.
        """
        kinds = np.ascontiguousarray(kinds, dtype=np.int64)
        t_eff = np.ascontiguousarray(t_eff, dtype=float)
        a = np.ascontiguousarray(a, dtype=float)
        b = np.ascontiguousarray(b, dtype=float)
        n = kinds.size
        if not (t_eff.size == a.size == b.size == n):
            raise ValueError("kinds, t_eff, a, b must have the same length")
        out = np.empty((n, core.ROW_WIDTH))
        status = np.empty(n, dtype=np.int64)
        self.x = np.ascontiguousarray(self.x, dtype=float).reshape(NX)
        self.P = np.ascontiguousarray(self.P, dtype=float)
        core.batch_core(self.x, self.P, self._aux, self._par, kinds, t_eff, a, b, out, status)
        return out, status


@dataclass
class FusedTrack:
    """Filter output after every input event of :func:`fuse`.

    Attributes:
        t: (N,) host stamp of each event, s (a wheel frame's own stamp, not its effective time).
        kind: (N,) 0 gyro, 1 wheels, 2 absolute yaw, 3 twist.
        states: (N, ROW_WIDTH) rows of :meth:`PlanarEKF.process_batch` (state, diag(P), pose cross
            terms); yaw is continuous.
        status: (N,) update status codes.
        stats: the filter's counters at the end.
        t_filter: (N,) the filter's time after each event, s (a wheel frame's effective time,
            the midpoint of its period; the stamp for the other inputs).
    """

    t: NDArray[np.float64]
    kind: NDArray[np.int64]
    states: NDArray[np.float64]
    status: NDArray[np.int64]
    stats: dict = field(default_factory=dict)
    t_filter: NDArray[np.float64] | None = None

    def output_rows(self) -> NDArray[np.bool_]:
        """Mask of the rows to publish: every gyro event, or every wheel event without a gyro."""
        gyro = self.kind == core.EV_GYRO
        if gyro.any():
            return gyro
        return (self.kind == core.EV_WHEELS) | (self.kind == core.EV_TWIST)


def fuse(
    robot: DiffDriveParams,
    imu_t: ArrayLike | None = None,
    gyro_z: ArrayLike | None = None,
    wheel_t: ArrayLike | None = None,
    ticks: ArrayLike | None = None,
    noise: EkfNoise | None = None,
    yaw_t: ArrayLike | None = None,
    yaw: ArrayLike | None = None,
    yaw_std: ArrayLike | float = 0.01,
    twist_t: ArrayLike | None = None,
    twist_v: ArrayLike | None = None,
    twist_w: ArrayLike | None = None,
    imu_motion: ArrayLike | None = None,
    wheel_slip: ArrayLike | None = None,
    accel_x: ArrayLike | None = None,
) -> tuple[FusedTrack, PlanarEKF]:
    """Fuse recorded streams offline (merged by effective time, see the module docstring).

    Args:
        robot: chassis parameters.
        imu_t, gyro_z: gyro stamps (s) and heading rates (rad/s; for a tilted robot
            :func:`vertical_rate`, on hills see the module docstring).
        wheel_t, ticks: wheel frame stamps (s, end of each period) and (M, 2) ticks.
        noise: filter tuning.
        yaw_t, yaw, yaw_std: optional absolute yaw (s, rad, rad).
        twist_t, twist_v, twist_w: optional external odometry twists (s, m/s, rad/s), e.g.
            from a ROS bag's nav_msgs/Odometry, instead of (or besides) wheel ticks.
        imu_motion: (N,) IMU motion code per gyro sample
            (:func:`fusion.planar.imu_motion.imu_motion_codes` of the base-frame gyro and
            accelerometer), or None: the stops are then judged by the wheels and the gyro rate
            alone.
        wheel_slip: (M,) bool per wheel frame, True where the accelerometer says it slips
            (:func:`fusion.planar.accel_slip.accel_slip_flags`): fused as a slip (yaw rate
            not fused, speed down-weighted); None: the gyro gate alone decides.
        accel_x: (N,) forward specific force per IMU sample (base frame x, m/s^2), used
            when ``noise.accel_speed_psd`` > 0 (see :class:`EkfNoise`); its events give no
            rows in the track.

    Returns:
        ``(track, filter)``; the filter holds the final state.
    """
    ekf = PlanarEKF(robot, noise)
    kinds, t_eff, a, b, stamp = merge_events(
        imu_t, gyro_z, wheel_t, ticks, robot.encode_sampling_time, ekf.noise.wheel_latency,
        yaw_t, yaw, yaw_std, twist_t, twist_v, twist_w, imu_motion, wheel_slip, accel_x,
    )
    states, status = ekf.process_batch(kinds, t_eff, a, b)
    # a flagged wheel frame is a wheel frame in the track (its status says slip)
    kinds = np.where(kinds == core.EV_WHEELS_SLIP, core.EV_WHEELS, kinds)
    rows = kinds != core.EV_ACCEL
    return FusedTrack(stamp[rows], kinds[rows], states[rows], status[rows], ekf.stats,
                      t_eff[rows]), ekf
