"""The base controller: one actuator cycle of pure control logic.

Per cycle the actuator task feeds the controller what arrived on its ports (``command``,
``encoders``) and calls ``step`` with the time and the collision guard's cap; the controller
leaves the wheel DAC codes, the enable bit, the ODOMETRY flags and the robot mode in its
attributes. No sockets, no allocation beyond a few floats.

Order inside ``step``:

1. Motor supervision: no ENCODERS for ``motor_timeout`` -> *motor stale*: outputs zero and
   disabled, limiters and PI reset, flag MOTOR_STALE. When encoders return the controller
   *holds zero* until a command arrives that is newer than the recovery (the old command may
   be from before the fault; the robot must not lurch off on it).
2. Command supervision: no VELOCITY_CMD for ``cmd_vel_timeout`` (0 disables) -> the target
   becomes zero and the limiter decelerates at its limit; flag BRAKING.
3. Guard cap on the forward target (slow-down zone), speed limiters, then the guard's stop
   applied after the limiters (a zero cap takes effect this cycle, bypassing the ramp).
4. Inverse kinematics, wheel-speed saturation (keeping curvature), PI with feed-forward on the
   measured wheel speeds, DAC codes. Zero wheel setpoints output code 512 (zero armature
   voltage: the amplifier brakes the motor down with its own lag) and clear the integrators,
   so a residual integral or encoder quantization can never make a stopped robot creep.
   While a guard stop still brakes the robot forward, both wheel setpoints are zero (the
   rotation in the command waits until the robot has stopped): a PI braking toward the
   rotation's setpoints would wind up over the transient and drive the wheels backwards.

Between 1 and 2: the e-stop contact read back open (ENCODERS status ESTOP_OPEN in
``e_stop.contact_samples`` consecutive samples: contact bounce and the read-back glitch when
the heartbeat restarts are filtered) -> outputs zero (enable kept driven: its read-back
shows the release), PI reset, the e-stop latch engaged; flags ESTOP_OPEN | E_STOP. A
latched motor fault (``control.supervision``) -> a category-1 stop: the zero word with the
enable on (the amplifier brakes the motors on their back-EMF; no encoder needed), the enable
dropped once the braking time bound ``linear.max_velocity / guard.brake_deceleration`` has
passed, or earlier when the fault leaves the encoders trustworthy (a stall) and both read the
wheels at rest for 0.1 s; flag MOTOR_FAULT, until :meth:`reset_fault`. *Motor stale* after
encoders were seen stops the same way (the driver may still hear the zero word). After step 4
the supervisor compares the wheel setpoints, the PI efforts and the gyro's yaw rate with the
measured speeds and may latch the fault.
The guard's configuration also caps the forward target at the top speed the sensors can stop
for and reverse at a creep speed (``forward_limit``, ``reverse_limit``; flag CLAMPED).

The e-stop latch (``control.estop``) overrides steps 2-3: while it is engaged, or released but
no command has arrived since, both axes ramp to zero at the e-stop decelerations
(``control.e_stop``) and the operator's command is ignored; flags E_STOP / HOLD, mode E_STOP.
It survives *motor stale* (the latch is state, not an output).

Two speed estimates from the same ring of encoder samples (``control.odometry``), each an angle
difference over a baseline, never shorter than half its window's nominal span:

* the published twist (ODOMETRY v, w and wheel speeds) over ``odom_velocity_window`` samples
  (default 5 = 50 ms, like diff_drive_controller's rolling window): for /odom users;
* the PI feedback over ``speed_feedback_window`` samples (default 2 = 20 ms), then the optional
  EMA ``speed_filter_alpha``. Measured in the simulated loop (virtual time, ``World`` + sim
  motor handler, 0.25 m/s cruise; window 1 / 2 / 3 / 5): mean DAC code movement per cycle
  1.87 / 0.85 / 0.51 / 0.24 codes, cruise RMS speed error 0.37 / 0.33 / 0.26 / 0.22 mm/s, but
  the overshoot at the end of the acceleration ramp grows with the added delay (peak 0.2703 /
  0.2718 / 0.2734 / 0.2767 m/s; yaw rate 0.475 / 0.485 / 0.494 / 0.514 rad/s for a 0.4 rad/s
  step). Window 2 halves the chatter for +0.6 % overshoot; longer windows buy little more
  quiet (the motor's 80 ms lag filters it anyway) for a slower loop. What the feedback needs
  most is the minimum baseline: after a driver stall its queued replies arrive stamped
  microseconds apart, and a one-count difference over 60 us read as 25 rad/s kicked the
  integrators -- 20-50 ms stalls gave true speeds up to 0.35 m/s for ~0.3 s and up to 0.13 rad
  of real heading change; with the baseline rule, 0.253 m/s and 0.003 rad.

Motor supervision and odometry: a *motor stale* episode keeps the pose; when ENCODERS return
from the same driver (sequence numbers continue) the first step spans the gap and the motion
during the outage is integrated -- a stalled driver keeps its DACs driving, so discarding that
step lost the distance travelled meanwhile. A restarted driver (sequence numbers start over)
re-anchors its unwrapped angles, so then the odometry takes the first sample as a new baseline.
"""

from __future__ import annotations

import math

from m4k_rt.control.dac import command_to_code, DAC_ZERO
from m4k_rt.control.diffdrive import DiffDrive
from m4k_rt.control.estop import EStopLatch, ramp_to_zero
from m4k_rt.control.limiter import SpeedLimiter
from m4k_rt.control.odometry import Odometry
from m4k_rt.control.params import AxisLimits, ControlParams
from m4k_rt.control.pid import WheelSpeedPI
from m4k_rt.control.supervision import COUNT, ENCODER_TRUST, FROZEN_COUNTS, WheelSupervisor
from m4k_rt.protocol import (
    ENC_ESTOP_OPEN,
    ENC_INVALID_MASK,
    ENC_SAFE,
    ODOM_BRAKING,
    ODOM_CLAMPED,
    ODOM_E_STOP,
    ODOM_ESTOP_OPEN,
    ODOM_GUARD,
    ODOM_HOLD,
    ODOM_MOTOR_FAULT,
    ODOM_MOTOR_STALE,
    ODOM_SLOWDOWN,
    seq_newer,
)

# The controller's flags are the ODOMETRY flags (protocol.py owns the bits: ODOM_*).
MODE_IDLE = 0
MODE_DRIVING = 1
MODE_BRAKING = 2
MODE_OBSTACLE = 3
MODE_FAULT = 4
MODE_E_STOP = 5
MODE_NAMES = ('idle', 'driving', 'braking', 'obstacle', 'fault', 'e_stop')

_MOVING_EPS = 1e-3   # m/s or rad/s below which the commanded base counts as stopped
# rad/s, sum of the measured wheel speeds above which a guard stop is still braking the
# robot forward (0.1 rad/s each: 1 cm/s on 0.1 m wheels)
_GUARD_BRAKING = 0.2
# rad x direction: a held wheel this far on from where it last read still (3 encoder counts,
# as the PI's break-away) is rolling, not showing the encoder's noise
_HOLD_ROLLED = 3.0 * COUNT
# rad/s: a wheel the hold has seen still rolls at _HOLD_ROLLED on at this speed, further at less
_ROLL_SPEED = 1.0
# cycles after the setpoints reach zero in which the pulled test only follows the speed up
_PULL_GRACE_CYCLES = 3
# the pulled test's margin grows by this share of the speed: a sample 4 ms late or early
# (a loaded host) moves the 20 ms speed estimate by a fifth of it
_PULL_JITTER = 0.2
# per wheel: held by the standstill hold, judged by its standstill window (none held)
_NOT_HELD = (False, False)
# ns: a category-1 stop judges whether the zero word slows the wheels only after this (the
# 20 ms speed window and a cycle's latency behind the wheel)
_DRIVEN_GRACE_NS = 50_000_000
# s: a hold this long holds the wheel's load, and the drive PI starts from its effort
_HOLD_SETTLED_S = 0.2


def _limiter(limits: AxisLimits) -> SpeedLimiter:
    return SpeedLimiter(
        max_velocity=limits.max_velocity,
        max_acceleration=limits.max_acceleration,
        max_deceleration=limits.max_deceleration,
        max_jerk=math.inf if limits.max_jerk is None else limits.max_jerk)


class BaseController:
    """Velocity command + encoder feedback -> wheel DAC codes, odometry, flags and mode."""

    def __init__(self, params: ControlParams, period: float) -> None:
        if not (period > 0.0 and math.isfinite(period)):
            raise ValueError(f'period must be a finite number > 0 s, got {period!r}')
        self.params = params
        self.period = float(period)
        self.kin = DiffDrive(params.wheel_radius, params.track_width, params.gear_ratio)
        self.linear = _limiter(params.linear)
        self.angular = _limiter(params.angular)
        self.wheel_limit = params.wheel_limit
        pi = params.pi
        # one count of encoder noise over the feedback window reads as this speed
        count_speed = self._count_speed = 1.5 * COUNT / (params.speed_feedback_window
                                                         * self.period)
        self.pi_left = WheelSpeedPI(pi.kp, pi.ki, params.feed_forward,
                                    anti_windup=pi.anti_windup, kt=pi.kt,
                                    band=pi.integral_band,
                                    breakaway_rate=pi.breakaway_rate,
                                    breakaway_effort=pi.breakaway_effort,
                                    breakaway_still=count_speed)
        self.pi_right = WheelSpeedPI(pi.kp, pi.ki, params.feed_forward,
                                     anti_windup=pi.anti_windup, kt=pi.kt,
                                     band=pi.integral_band,
                                     breakaway_rate=pi.breakaway_rate,
                                     breakaway_effort=pi.breakaway_effort,
                                     breakaway_still=count_speed)
        # break-away: per wheel, the angle it starts from and whether it has been seen
        # turning its setpoint's way since the setpoint left zero (pid: breakaway_rate)
        self._angles = [0.0, 0.0]
        self._start_ref = [math.nan, math.nan]
        self._start_sp = [0.0, 0.0]
        # in a guard stop (forward cap zero), and still braking the robot forward in it
        # (cleared once it has stopped; set again only by the next guard stop)
        self._guard_stop = False
        self._guard_brake = False
        # Standstill hold (``control.hold``): with zero setpoints, once both wheels are slow
        # (or one is pulled), a PI at zero speed per wheel (``_hold_step``); its integral is
        # the effort that keeps the wheel where it came to rest.
        self._hold = params.hold
        self._boost = params.pi.breakaway_rate
        self.holding = False
        self.hold_effort = [0.0, 0.0]       # per wheel, the hold's integral (normalized)
        self._hold_ref = [0.0, 0.0]         # per wheel, the angle it last read still at
        self._hold_seen = -1                # encoder_samples when the hold's integral last ran
        self._hold_span = 0.0               # s since then
        self._hold_live = [False, False]    # per wheel, read still: its integral runs
        self._hold_pulled = [False, False]  # per wheel, found pulled: braked
        self._held_s = 0.0                  # how long the present hold has lasted
        self._hold_bound = [-1.0, -1.0]     # per wheel, the pulled test's falling bound
        self._hold_zero_cycles = 0          # cycles with zero setpoints (the pulled test's grace)
        self._pull_seen = -1                # encoder_samples when the pulled test last judged
        self._pull_span = 0.0               # s since then
        self._fb_window = params.speed_feedback_window
        self._fb_min_ns = max(1, int(0.5 * self._fb_window * self.period * 1e9))
        self.odom = Odometry(params.wheel_radius, params.track_width,
                             max_wheel_speed=params.full_scale_wheel_speed * 2.0,
                             velocity_window=params.odom_velocity_window,
                             sample_period=self.period,
                             history=max(params.odom_velocity_window, self._fb_window) + 16)
        self._alpha = params.speed_filter_alpha
        self.estop = EStopLatch(params.e_stop_linear_deceleration,
                                params.e_stop_angular_deceleration)
        self.supervisor = WheelSupervisor(params.supervision, params.wheel_radius,
                                          params.track_width, params.feed_forward)
        # Category-1 stop: after a fault the RT side detects, the zero word brakes with the
        # enable on for at most the time the guard's a_brake needs from the top speed, then
        # the enable drops (earlier once trustworthy encoders read the wheels at rest).
        self.fault_brake_ns = int(params.linear.max_velocity
                                  / params.guard.brake_deceleration * 1e9)
        self._fault_since_ns = 0    # when the present category-1 stop began; 0: none
        self._rest_ns = 0           # encoder time both wheels have read at rest in that stop
        # per wheel, a bound on |speed| in that stop that falls at still_deceleration (far
        # below what the zero word brakes); a wheel this much above it is driven, not braked,
        # by the zero word (4 counts over the feedback window: not noise)
        self._stop_floor = [0.0, 0.0]
        self._driven_margin = 2.0 * params.supervision.still_speed
        self._driven_slack = 0.5 * params.supervision.still_speed
        self._driven_fall = params.supervision.still_deceleration * self.period
        self._imu_timeout_ns = int(params.supervision.imu_timeout * 1e9)
        self.yaw_rate = math.nan    # the gyro's yaw rate about base_link z, rad/s
        self.imu_rx_ns = 0
        self.imu_slope = math.nan   # -sin(pitch) of base_link x (the IMU's orientation)
        # |slope| within this: level (-1: never -- the supervision does not use the IMU)
        self._level_sin = (math.sin(math.radians(params.supervision.level_grade))
                           if params.supervision.use_imu else -1.0)
        self._level = False         # this cycle: a fresh IMU sample says the floor is level
        self.left_u = self.right_u = 0.0   # PI outputs of the last cycle (0: zero word)
        self.estop_open = False     # the contact reads open (contact_samples in a row)
        self._open_samples = 0
        self._open_needed = params.e_stop.contact_samples
        self.driver_safe = False    # the last valid ENCODERS said the driver holds DACs safe
        self.fault_resets = 0
        self.commands_blocked = 0   # commands received while the e-stop latch was engaged
        self.pose_resets = 0
        self._enc_seq = -1          # last ENCODERS sequence number; -1: none yet
        self._cmd_timeout_ns = int(params.cmd_vel_timeout * 1e9)
        self._motor_timeout_ns = int(params.motor_timeout * 1e9)
        # inputs
        self.cmd_linear = 0.0
        self.cmd_angular = 0.0
        self.cmd_rx_ns = 0          # 0: never received
        self.enc_rx_ns = 0
        self.commands = 0
        self.encoder_samples = 0
        self.encoder_faults = 0
        # filtered wheel speed feedback
        self.left_speed = 0.0
        self.right_speed = 0.0
        # outputs
        self.v = 0.0                # limited body command, m/s
        self.w = 0.0                # rad/s
        self.left_setpoint = 0.0
        self.right_setpoint = 0.0
        self.left_code = DAC_ZERO
        self.right_code = DAC_ZERO
        self.enable = 0
        self.flags = ODOM_MOTOR_STALE
        self.mode = MODE_FAULT
        self.motor_stale = True
        self.hold_zero = True
        self.braking = False
        self._hold_since_ns = 0
        self._last_step_ns = 0
        # Speed caps the guard's configuration implies (set by the actuator at build time):
        # the top forward speed the sensors can stop for, the reverse creep (no rear sensor).
        self.forward_limit = math.inf
        self.reverse_limit = math.inf

    def command(self, linear: float, angular: float, rx_ns: int) -> None:
        """Take a fresh velocity command (already validated finite by the decoder).

        Call in the order commands and e-stop requests arrived: a command after an e-stop
        release ends the release's hold, one during the latch is kept but drives nothing.
        """
        self.cmd_linear = linear
        self.cmd_angular = angular
        self.cmd_rx_ns = rx_ns
        self.commands += 1
        if not self.estop.command():
            self.commands_blocked += 1

    def e_stop(self, engage: bool) -> None:
        """Latch (True) or release (False) the e-stop; takes effect at the next ``step``."""
        self.estop.set(engage)

    def reset_fault(self) -> bool:
        """Clear a latched motor fault (explicit request); return whether one was latched.

        The robot then holds still until a velocity command arrives after the reset (in port
        order), as after an e-stop release: the command from before the fault never restarts it.
        """
        was = self.supervisor.reset()
        self._fault_since_ns = 0
        if was:
            self.fault_resets += 1
            self.estop.holding = True
        return was

    def reset_pose(self, x: float = 0.0, y: float = 0.0, yaw: float = 0.0) -> None:
        """Set the odometry pose (zero by default); speeds and the encoder baseline are kept."""
        self.odom.set_pose(x, y, yaw)
        self.pose_resets += 1

    def encoders(self, left_angle: float, right_angle: float, stamp_ns: int, rx_ns: int,
                 status: int = 0, seq: int | None = None) -> None:
        """Take one ENCODERS sample (wheel angles in rad, unwrapped; driver stamp in ns).

        A sample whose status flags invalid angles is counted and does not refresh the motor's
        freshness, so a persistently failing encoder ends in *motor stale*. ``seq`` is the
        datagram's sequence number: after a *motor stale* episode a sample that does not follow
        the last one (the driver restarted, its angles have a new origin) re-baselines the
        odometry; without ``seq`` every recovery re-baselines.
        """
        if status & ENC_INVALID_MASK:
            self.encoder_faults += 1
            return
        if self.motor_stale and (seq is None or self._enc_seq < 0
                                 or not seq_newer(self._enc_seq, seq)):
            self.odom.rebase()
        self._enc_seq = -1 if seq is None else seq
        if status & ENC_ESTOP_OPEN:
            self._open_samples += 1
            if self._open_samples >= self._open_needed:
                self.estop_open = True
        else:
            self._open_samples = 0
            self.estop_open = False
        self.driver_safe = bool(status & ENC_SAFE)
        self.supervisor.encoders(left_angle, right_angle, stamp_ns)
        self._angles[0] = left_angle
        self._angles[1] = right_angle
        self.encoder_samples += 1
        self.enc_rx_ns = rx_ns
        odom = self.odom
        if odom.update(left_angle, right_angle, stamp_ns):
            hist = odom.history
            if hist.rates(self._fb_window, self._fb_min_ns):
                a = self._alpha
                self.left_speed += a * (hist.left_rate - self.left_speed)
                self.right_speed += a * (hist.right_rate - self.right_speed)

    def imu(self, yaw_rate: float, rx_ns: int, stamp_ns: int | None = None,
            slope: float = math.nan) -> None:
        """Take the gyro's yaw rate about base_link z (rad/s) received at ``rx_ns``.

        ``stamp_ns``: when the sample was taken (the datagram's stamp; None: ``rx_ns``). The
        newest sample is given every cycle; the supervision takes each stamp once.
        ``slope``: the z of base_link's x axis in the world, from the IMU's orientation
        (``-sin(pitch)``; NaN: none): the share of gravity a slope puts on the wheels along
        the track. Within ``supervision.level_grade`` of level, a held wheel holds no load.
        """
        self.yaw_rate = yaw_rate
        self.imu_rx_ns = rx_ns
        self.imu_slope = slope
        if rx_ns:
            self.supervisor.gyro(yaw_rate, rx_ns if stamp_ns is None else stamp_ns)

    def _brake_enable(self, now_ns: int, trust_rest: bool) -> int:
        """Return the enable of a category-1 stop that began at ``_fault_since_ns``.

        The zero word brakes with the enable on (back-EMF braking through the amplifier, no
        encoder needed) until the braking time bound has passed, or, when ``trust_rest``, both
        encoders have read the wheels at rest for 0.1 s; then the enable drops. And at once
        when a wheel does not slow under the zero word (above a bound falling at
        ``supervision.still_deceleration`` from its speed then): the amplifier drives it (an
        input offset, a stuck DAC), so the zero word is no brake -- measured, a 4-6 V offset
        that latched the still fault turned its wheel on 3,100-4,900 counts (0.5-0.75 m at the
        rim) before the time bound cut the power. Frozen, flipped or swapped encoders read a
        braked wheel slowing (or still); a robot rolling on a slope beyond the hold loses the
        zero word's back-EMF up to the time bound early -- it rolls once the bound has passed
        anyway.
        """
        ls, rs = abs(self.left_speed), abs(self.right_speed)
        floor = self._stop_floor
        if self._fault_since_ns == 0:
            self._fault_since_ns = now_ns
            self._rest_ns = 0
            floor[0], floor[1] = ls, rs
        elapsed = now_ns - self._fault_since_ns
        if elapsed >= self.fault_brake_ns:
            return 0
        if elapsed < _DRIVEN_GRACE_NS:
            # the speed estimate lags the wheel (a wheel the PI was accelerating reads faster
            # for a window after the zero word took over): the bound starts at its peak
            floor[0], floor[1] = max(floor[0], ls), max(floor[1], rs)
        else:
            # the bound follows a slowing wheel down with a half margin's slack, as the
            # still test's does: following one low reading to the count, the next reading
            # a few counts up near rest (0.15 then 0.31 rad/s at 1.5 cm/s) cut the enable
            # of a frozen-encoder stop at 1 m/s before the robot rested
            fall = self._driven_fall
            slack = self._driven_slack
            floor[0] = max(min(floor[0], ls + slack) - fall, 0.0)
            floor[1] = max(min(floor[1], rs + slack) - fall, 0.0)
            if ls > floor[0] + self._driven_margin or rs > floor[1] + self._driven_margin:
                self._fault_since_ns = now_ns - self.fault_brake_ns   # the bound: stays off
                return 0
        if trust_rest:
            ms = self.params.supervision.min_speed
            if abs(self.left_speed) < ms and abs(self.right_speed) < ms:
                self._rest_ns += int(self.period * 1e9)
                if self._rest_ns >= 100_000_000:
                    return 0
            else:
                self._rest_ns = 0
        return 1

    def _stop_outputs(self, enable: int) -> None:
        self.linear.reset(0.0)
        self.angular.reset(0.0)
        self.pi_left.reset()
        self.pi_right.reset()
        self._hold_disarm()
        self._start_sp[0] = self._start_sp[1] = 0.0
        self.v = self.w = 0.0
        self.left_setpoint = self.right_setpoint = 0.0
        self.left_u = self.right_u = 0.0
        self.left_code = self.right_code = DAC_ZERO
        self.enable = enable

    def step(self, now_ns: int, forward_cap: float = math.inf,
             guard_active: bool = False, ccw_cap: float = math.inf,
             cw_cap: float = math.inf) -> None:
        """Run one control cycle at ``now_ns`` with the guard's caps.

        ``forward_cap``: the forward guard's (m/s); ``ccw_cap`` / ``cw_cap``: the turn guard's
        on the yaw rate each way (rad/s, >= 0). A zero cap stops that motion after the ramp:
        the drive brakes it (``m4k_rt.control.guard``, ``m4k_rt.control.turnguard``).
        """
        dt = (now_ns - self._last_step_ns) * 1e-9 if self._last_step_ns else self.period
        if dt <= 0.0 or dt > 2.0 * self.period:
            dt = self.period if dt <= 0.0 else 2.0 * self.period
        self._last_step_ns = now_ns
        flags = 0
        # 1. motor supervision
        stale = self.enc_rx_ns == 0 or now_ns - self.enc_rx_ns > self._motor_timeout_ns
        if stale:
            if not self.motor_stale:
                # The pose and the baseline stay; whether the next sample continues them is
                # decided when it comes (``encoders``). No speed is known meanwhile, and the
                # PI restarts from rest either way.
                self.odom.zero_speeds()
                self.left_speed = self.right_speed = 0.0
                # A category-1 stop: the zero word brakes while the driver may still hear it
                # (encoders failing, driver alive); stale from the start there is nothing to
                # brake.
                self._fault_since_ns = 0 if self.enc_rx_ns == 0 else now_ns
            self.motor_stale = True
            self.supervisor.idle()
            self.hold_zero = True
            self.braking = False
            self._stop_outputs(0 if self._fault_since_ns == 0
                               else self._brake_enable(now_ns, False))
            self.flags = (ODOM_MOTOR_STALE | self._estop_flags()
                          | (ODOM_MOTOR_FAULT if self.supervisor.latched else 0))
            self.mode = MODE_FAULT
            return
        if self.motor_stale:
            self.motor_stale = False
            self._hold_since_ns = now_ns
            self._fault_since_ns = 0
        sup = self.supervisor
        if self.estop_open:
            # The contact cut the amplifier: whatever the PI would integrate is windup, and a
            # release must not restart the robot, so the latch engages (cleared only by an
            # explicit release, then a fresh command). The enable stays driven: its read-back
            # is how the release of the contact is seen.
            self.estop.engage()
            sup.idle()
            self.braking = False
            self._stop_outputs(1)
            self.flags = ODOM_ESTOP_OPEN | ODOM_E_STOP | (ODOM_MOTOR_FAULT if sup.latched
                                                          else 0)
            self.mode = MODE_E_STOP
            return
        if sup.latched:
            self.braking = False
            self._stop_outputs(self._brake_enable(now_ns, not sup.cause & ENCODER_TRUST))
            self.flags = ODOM_MOTOR_FAULT | self._estop_flags()
            self.mode = MODE_FAULT
            return
        if self.hold_zero and self.cmd_rx_ns > self._hold_since_ns:
            self.hold_zero = False
        # 2. command supervision
        cmd_stale = (self._cmd_timeout_ns > 0 and self.cmd_rx_ns != 0
                     and now_ns - self.cmd_rx_ns > self._cmd_timeout_ns)
        self.braking = cmd_stale
        if self.hold_zero or cmd_stale or self.cmd_rx_ns == 0:
            tv = tw = 0.0
        else:
            tv = self.cmd_linear
            tw = self.cmd_angular
        if cmd_stale:
            flags |= ODOM_BRAKING
        # 3. guard and limits
        top_clamped = False
        if tv > self.forward_limit:
            tv = self.forward_limit
            top_clamped = True
        elif tv < -self.reverse_limit:
            tv = -self.reverse_limit
            top_clamped = True
        if tv > forward_cap:
            tv = forward_cap
            flags |= ODOM_SLOWDOWN if forward_cap > 0.0 and not guard_active else ODOM_GUARD
        if guard_active:
            flags |= ODOM_GUARD
        turn_stop = False
        if tw > ccw_cap:
            tw = ccw_cap
            turn_stop = ccw_cap <= 0.0
            flags |= ODOM_GUARD if turn_stop else ODOM_SLOWDOWN
        elif tw < -cw_cap:
            tw = -cw_cap
            turn_stop = cw_cap <= 0.0
            flags |= ODOM_GUARD if turn_stop else ODOM_SLOWDOWN
        estop = self.estop
        if estop.blocking:
            # The e-stop's own ramp replaces the limiters; they restart from this output.
            v = ramp_to_zero(self.linear.value, estop.linear_deceleration, dt)
            w = ramp_to_zero(self.angular.value, estop.angular_deceleration, dt)
            self.linear.override(v)
            self.angular.override(w)
            flags |= self._estop_flags()
            clamped = False
        else:
            v = self.linear.step(tv, dt)
            w = self.angular.step(tw, dt)
            # Ramping to zero is the point of braking, not a clamp of the operator's command.
            clamped = not cmd_stale and (self.linear.clamped or self.angular.clamped)
        if forward_cap <= 0.0 and v > 0.0:
            v = 0.0
            self.linear.override(0.0)
            flags |= ODOM_GUARD
        if (ccw_cap <= 0.0 and w > 0.0) or (cw_cap <= 0.0 and w < 0.0):
            w = 0.0      # a turn stop: no ramp, the wheels brake the rotation
            self.angular.override(0.0)
            flags |= ODOM_GUARD
            turn_stop = True
        self.v = v
        self.w = w
        # 4. kinematics and wheel control
        wl, wr = self.kin.inverse(v, w)
        wl, wr, sat = self.kin.saturate(wl, wr, self.wheel_limit)
        if forward_cap > 0.0:
            self._guard_stop = self._guard_brake = False
        elif not self._guard_stop:
            self._guard_stop = self._guard_brake = True      # a guard stop begins
        if self._guard_brake:
            if self.left_speed + self.right_speed > _GUARD_BRAKING:
                # A guard stop still braking the robot forward: both wheels brake (zero
                # setpoints, below), the rotation waits until the robot has stopped. The PI
                # would otherwise integrate the braking transient toward the rotation's
                # setpoints and then drive the wheels past them -- backwards (0.24 m/s in
                # reverse on the stack).
                wl = wr = 0.0
            else:
                # Stopped: the rotation goes on, and this stop does not brake again. A wheel
                # sticking in the slow turn in place that follows (stick-slip at a creep)
                # makes the other wheel's speed alone read as forward motion: re-braking on
                # it reset both PIs every few cycles, so the wheels stuck again and again.
                self._guard_brake = False
        cs = self._count_speed
        if self._hold.enabled and -cs < wl < cs and -cs < wr < cs:
            # Both below what the encoders resolve over the feedback window (1.2 cm/s at the
            # rim): no speed the loop can follow -- the wheels stand, held. A heading hold's
            # correction while a guard stop holds the robot otherwise left both PIs at setpoints
            # their wheels read as still, where the never-against-the-setpoint rule dropped the
            # effort that held them, and the robot crept down a ramp at 5 mm/s. (The first
            # cycles of a ramp from rest are zeroed too: ~30 ms from a 1 rad/s command to the
            # first effort. Letting a ramp toward a resolvable target pass cut the bench's
            # cmd_vel -> motor p50 from 35 to 4-5 ms, but the restarts of a guard chattering
            # at its release line on an arc then turned the robot off its arc, and one
            # envelope run passed a leg at 8 cm: backed out, docs/results/README.md.)
            wl = wr = 0.0
        self.left_setpoint = wl
        self.right_setpoint = wr
        fresh = self.imu_rx_ns and now_ns - self.imu_rx_ns <= self._imu_timeout_ns
        # not NaN, within level_grade: the floor is level along the track -- nothing pulls a
        # wheel, and the hold's integral is held against nothing but a fault
        level = bool(fresh and abs(self.imu_slope) <= self._level_sin)
        self._level = level
        if wl == 0.0 and wr == 0.0:
            self.pi_left.reset()
            self.pi_right.reset()
            self._start_sp[0] = self._start_sp[1] = 0.0
            ls, rs = self.left_speed, self.right_speed
            if not self.holding and self._hold.enabled and self._hold_begins(ls, rs, dt):
                self.holding = True
                self.hold_effort[0] = self.hold_effort[1] = 0.0
                self._hold_ref[0], self._hold_ref[1] = self._angles
                self._hold_seen = -1
                self._hold_span = 0.0
                self._held_s = 0.0
            if self.holding:
                # The integral runs on each new encoder sample, over the time since the last
                # one: a cycle without a fresh sample adds nothing, where the last speed read
                # would be counted again (a stack short of CPU, samples every 3-10 cycles: the
                # integral wound at several times its rate, the wheel hunted, and the level
                # test latched a robot at rest). With a sample every cycle, span == dt.
                self._hold_span += dt
                if self.encoder_samples != self._hold_seen:
                    self._hold_seen = self.encoder_samples
                    span, self._hold_span = self._hold_span, 0.0
                else:
                    span = 0.0
                self._held_s += dt
                ul = self.left_u = self._hold_step(0, ls, dt, span)
                ur = self.right_u = self._hold_step(1, rs, dt, span)
                self.left_code = command_to_code(ul)
                self.right_code = command_to_code(ur)
            else:
                self.left_u = self.right_u = 0.0
                self.left_code = self.right_code = DAC_ZERO
        else:
            if self.holding and self._held_s >= _HOLD_SETTLED_S:
                # bumpless: the drive PI starts from the effort that has held the wheel (a
                # start uphill does not roll back while the PI winds up) -- when it pushes
                # the way the new setpoint asks: the load a start would roll back under. An
                # effort against it is what braked the wheel's last motion that way (a guard
                # chattering at its release line on the level: the creep it released to,
                # braked by the hold, handed over as load, backed the robot up at 4 cm/s).
                # A shorter hold -- a guard stop's last creep before the turn it releases
                # to -- holds no load yet, only the last of the braking.
                if self.hold_effort[0] * wl > 0.0:
                    self.pi_left.integral = self.hold_effort[0]
                if self.hold_effort[1] * wr > 0.0:
                    self.pi_right.integral = self.hold_effort[1]
            if self._hold_bound[0] >= 0.0:
                # armed by the zero-setpoint cycles before this one (never with the hold off)
                self._hold_disarm()
            ul = self.left_u = self.pi_left.update(wl, self.left_speed, dt,
                                                   self._starting(0, wl))
            ur = self.right_u = self.pi_right.update(wr, self.right_speed, dt,
                                                     self._starting(1, wr))
            sat = sat or self.pi_left.saturated or self.pi_right.saturated
            self.left_code = command_to_code(ul)
            self.right_code = command_to_code(ur)
        self.enable = 1
        yaw = self.yaw_rate if fresh else math.nan
        level_hold = self.hold_effort if self.holding and level else None
        if self.driver_safe:
            sup.idle()       # the driver holds the DACs at zero: the wheels cannot follow
        elif sup.step(dt, wl, wr, self.left_speed, self.right_speed, self.left_u, self.right_u,
                      self.pi_left.saturated, self.pi_right.saturated, yaw,
                      self._hold_live if self.holding else _NOT_HELD, level_hold, now_ns):
            self.braking = False
            self._fault_since_ns = 0
            self._stop_outputs(self._brake_enable(now_ns, False))
            self.flags = ODOM_MOTOR_FAULT | self._estop_flags()
            self.mode = MODE_FAULT
            return
        if clamped or sat or top_clamped:
            flags |= ODOM_CLAMPED
        self.flags = flags
        moving = abs(v) > _MOVING_EPS or abs(w) > _MOVING_EPS
        if estop.engaged:
            self.mode = MODE_E_STOP
        elif flags & ODOM_GUARD and (guard_active or forward_cap <= 0.0 or turn_stop):
            self.mode = MODE_OBSTACLE
        elif cmd_stale and moving:
            self.mode = MODE_BRAKING
        elif moving:
            self.mode = MODE_DRIVING
        else:
            self.mode = MODE_IDLE

    @property
    def wheel_angles(self) -> tuple[float, float]:
        """Return the newest valid encoder angles (left, right) in rad (benches, tests)."""
        return self._angles[0], self._angles[1]

    def _hold_disarm(self) -> None:
        """End the hold and forget its per-wheel state (the pulled test starts afresh)."""
        self.holding = False
        self._hold_bound[0] = self._hold_bound[1] = -1.0
        self._hold_zero_cycles = 0
        self._pull_seen = -1
        self._pull_span = 0.0
        self._hold_live[0] = self._hold_live[1] = False
        self._hold_pulled[0] = self._hold_pulled[1] = False

    def _hold_begins(self, ls: float, rs: float, dt: float) -> bool:
        """Return True when the standstill hold begins this cycle (zero setpoints, no hold).

        Both wheels slower than ``hold.speed`` (stopped, or never started), or a wheel pulled:
        faster than a bound that starts at its speed (+ ``hold.speed``) as the setpoints went
        to zero and falls at ``hold.pull_deceleration`` -- the zero word brakes a wheel on the
        level far faster (~28 rad/s^2); one it does not slow so is driven by something (a
        ramp). Never while a wheel is braked from speed: the hold would only brake harder.
        A wheel found pulled is braked by the hold's proportional part (``_hold_step``).
        Never on the level either (the IMU's orientation, ``supervision.level_grade``):
        nothing there pulls a wheel the zero word brakes, so a wheel that reads faster than
        its bound is a late encoder sample -- the hold, braking at its limit on a speed
        estimate that lags, drove the wheels back through zero and wound its integral into
        a false level fault -- or an amplifier driving it, which the still test's bound
        takes (and, once the wheel rests, the level test).
        """
        h = self._hold
        hb = self._hold_bound
        self._hold_zero_cycles += 1
        grace = self._hold_zero_cycles <= _PULL_GRACE_CYCLES
        # judged on a new encoder sample only, its bound fallen over the time since the last:
        # a speed read again in a cycle without one is as old as its sample, and the wheel
        # has slowed since -- against a bound that fell every cycle, the last speed of a
        # wheel braking down a ramp read pulled with samples every 5 cycles, and the hold's
        # braking on that stale speed drove it back (C22)
        self._pull_span += dt
        fresh = self.encoder_samples != self._pull_seen
        span = 0.0
        if fresh:
            self._pull_seen = self.encoder_samples
            span, self._pull_span = self._pull_span, 0.0
        pulled = False
        for k, m in ((0, abs(ls)), (1, abs(rs))):
            if hb[k] < 0.0 or grace:
                # the speed estimate lags the zero word (a wheel the PI was still speeding up
                # reads faster for a window): the bound follows it up, nothing is pulled yet --
                # with the margin a late sample gets at speed (``_pulled``): from the speed
                # alone, one sample 1 ms late in the first cycle after the grace read a 2 m/s
                # guard stop as pulled, and the hold braked and wound up through the whole stop
                hb[k] = max(hb[k], self._pull_limit(m))
            elif fresh and self._pulled(k, m, span):
                pulled = True
        return pulled or (abs(ls) < h.speed and abs(rs) < h.speed)

    def _pull_limit(self, m: float) -> float:
        """Return the speed above which a wheel now at ``m`` would read pulled (its margin)."""
        return m * (1.0 + _PULL_JITTER) + self._hold.speed

    def _pulled(self, k: int, m: float, dt: float) -> bool:
        """Return True (and mark wheel ``k`` pulled) when ``|m|`` is above its falling bound.

        The bound's margin grows with the speed: one late or early encoder sample moves the
        20 ms speed estimate by a share of it, at top speed beyond ``hold.speed`` (a guard
        stop in a 2 m/s arc read as pulled; the hold's braking effort then started the inner
        wheel's PI against its roll, a false wrong-way fault). On the level (``_level``) the
        bound goes on falling, but nothing is pulled (``_hold_begins``).
        """
        hb = self._hold_bound
        b = hb[k] = max(min(hb[k], self._pull_limit(m)) - self._hold.pull_deceleration * dt,
                        0.0)
        if m > b and not self._level:
            self._hold_pulled[k] = True
            return True
        return False

    def _hold_step(self, k: int, m: float, dt: float, span: float) -> float:
        """Return the hold's command for wheel ``k`` at measured speed ``m`` (rad/s).

        ``span``: the time the newest encoder sample's speed stands for (0 in a cycle
        without a new sample).

        * Integral: ``-ki`` x the angle turned once the wheel has read still -- not over the
          last of a stop's braking, which a wheel on the level would then be driven back
          over -- and below ``hold.speed`` only, within +-``limit``.
        * Proportional, on a pulled wheel only (``_hold_begins``): ``-kp`` x the speed beyond
          a count of encoder noise, to bring it to where it reads still. Otherwise none: the
          motor's back-EMF damps, and a gain on the noise only makes the wheel hunt the
          count.
        A wheel that has turned 3 counts on from where it last read still and turns on at
        1 rad/s (further at less: its integral already follows the angle), or one found pulled
        that has turned 3 counts on from where the hold began at any speed, is rolling, not
        showing the encoder's noise (which only ever makes a held wheel read 1-2 counts); one
        still braking from the motion before the hold is not (its pulled test goes on until
        it reads still):

        * against the integral, or with none: the integral is too small to stop it -- it
          grows at least at ``pi.breakaway_rate`` against the motion (static friction and an
          amplifier's dead band hold back a slow integral while the robot rolls), by at most
          a cycle's worth per encoder sample (samples far apart: the rate falls with them);
        * the way the integral pushes: the hold is more than the load needs (the integral of
          a wheel that came to rest on the level) -- it unwinds ten times as fast as it was
          built. The hold resists motion and never makes any.
        """
        h = self._hold
        i = self.hold_effort[k]
        a = self._angles[k]
        if -self._count_speed <= m <= self._count_speed:
            self._hold_ref[k] = a                   # reads still: rolled from here
            self._hold_live[k] = True
        if self._hold_live[k] and -h.speed <= m <= h.speed:
            i -= h.ki * m * span
        # a pulled wheel is braked beyond the encoder's noise, down to where it reads still
        # and its integral starts; otherwise the motor's back-EMF damps, and a gain on the
        # noise only makes the wheel hunt the count
        # -- in the cycle of a new encoder sample only: a speed read again in the cycles
        # without one is as old as its sample, and braking on it for all of them (samples
        # every 5 cycles: a 50 ms pulse on a 50 ms old speed) reversed the wheel, the next
        # sample braked it back harder, and the hold rocked the robot into a still fault (C22)
        cs = self._count_speed
        p = 0.0 if not self._hold_pulled[k] or span == 0.0 else \
            -h.kp * (m - cs) if m > cs else -h.kp * (m + cs) if m < -cs else 0.0
        if not (self._hold_live[k] or self._hold_pulled[k]) and span > 0.0:
            # neither read still nor found pulled since the hold began: still braking from
            # the motion before it (the pulled test goes on, on new samples: a ramp may take
            # it over)
            self._pulled(k, abs(m), span)
        rolled = a - self._hold_ref[k]
        live = self._hold_live[k]
        if live:
            # Read still in this hold: its integral already grows with the angle (-ki x the
            # roll); the boost is for a roll that outruns it -- 3 counts at 1 rad/s, further
            # the slower it rolls (a slow roll boosted at once overshoots the load: the wheel
            # then stands on an integral that pushes it, with nothing to unwind it but motion)
            rolling = rolled * m >= _HOLD_ROLLED * _ROLL_SPEED
        else:
            # Found pulled and never read still: nothing but the boost builds the effort that
            # will hold it, so 3 counts on at any speed (with ``rolled x m`` a wheel pulled
            # down a 4.8 deg ramp at 0.15 rad/s needed 20 counts, and rolled on into the still
            # test -- a category-1 stop, on a ramp)
            rolling = self._hold_pulled[k] and rolled * m > 0.0 and abs(rolled) >= _HOLD_ROLLED
        if rolling:
            # a wheel still braking from its last motion is no load: its roll would build an
            # integral that drives it back once it stops (a guard chattering at its release
            # line backed the robot up at 4 cm/s)
            # rolling on (not the encoder's noise): with the hold's push, or against it
            # At most a cycle's step per sample: the speed it acts on is as old as the gap
            # since the last, and a step that grew with the gap (samples every 5 cycles: 0.1
            # of full scale at a time) swung the wheel past the load and back, wider each
            # time, into a still fault (C22).
            reach = span if span < self.period else self.period
            if i * m > 0.0:
                step = 9.0 * h.ki * abs(m) * reach
                i = 0.0 if abs(i) <= step else i - math.copysign(step, i)
            else:
                i -= math.copysign(self._boost * reach, m)
        lim = h.limit
        i = lim if i > lim else -lim if i < -lim else i
        self.hold_effort[k] = i
        u = i + p
        return lim if u > lim else -lim if u < -lim else u

    def _starting(self, k: int, sp: float) -> bool:
        """Return True while wheel ``k`` has not turned FROZEN_COUNTS its setpoint's way.

        Counted from the angle at which its setpoint left zero or changed sign (moved along
        while the wheel still turns the old way); encoder counts, not the speed estimate, and
        whole FROZEN_COUNTS steps either way, so +/-1 count of noise neither starts it nor
        drags its reference. (No roll-back of the boost once it has started: measured, one
        noisy count made it roll back below the break-away and a creeping wheel stuck again.)
        """
        a = self._angles[k]
        if abs(sp) < self.supervisor.frozen_min:
            # too slow to move FROZEN_COUNTS + 1 within frozen_time: the supervision does not
            # judge it, and a boost would only throw the wheel (a heading hold's 4 mrad/s)
            self._start_sp[k] = 0.0
            return False
        if sp * self._start_sp[k] <= 0.0:           # left zero or changed sign: restart
            self._start_ref[k] = a
        self._start_sp[k] = sp
        ref = self._start_ref[k]
        if self.supervisor.unseen[k]:
            # turning unseen (its encoder frozen: the gyro and the other wheel show it turn):
            # more effort than the other wheel's would only speed it up until the latch
            pi = self.pi_left if k == 0 else self.pi_right
            other = abs((self.pi_right if k == 0 else self.pi_left).integral)
            if abs(pi.integral) > other:
                pi.integral = math.copysign(other, pi.integral)
            return False
        if ref != ref:                               # NaN: started
            return False
        d = (a - ref) if sp > 0.0 else (ref - a)
        if d >= FROZEN_COUNTS * COUNT:
            self._start_ref[k] = math.nan
            return False
        if d <= -FROZEN_COUNTS * COUNT:
            # still turning the old way (a reversal: the plain PI has error enough), or its
            # encoder counts against the effort (a sign flip): no boost either way
            self._start_ref[k] = a
            return False
        return True

    def _estop_flags(self) -> int:
        estop = self.estop
        if estop.engaged:
            return ODOM_E_STOP
        return ODOM_HOLD if estop.holding else 0
