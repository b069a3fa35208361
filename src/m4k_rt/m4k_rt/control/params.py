"""Control parameters: the ``control:`` section of ``config/control.yaml``, validated (pure).

Each setting is declared once, on its dataclass field, by its :class:`m4k_rt.schema.Field`
(type, default, unit, range or choices, what a wrong value does): ``kp: float =
setting(Field(...))``. :data:`CONTROL`, the section's dotted table that validates the file
and generates ``docs/configuration.md``, is derived from the dataclasses
(:func:`m4k_rt.schema.table`); the linear and angular limits share :class:`AxisLimits`,
whose two tables :func:`_axis` makes.
``control_params(mapping)`` validates a parsed section into the frozen dataclasses and raises
``ControlConfigError`` naming the offending field with its dotted path and the bad value, e.g.
``control.linear.max_acceleration: expected a number > 0, got -1``. Unknown keys are errors
too: a misspelt key would otherwise silently keep a default. The RT tasks read plain dataclass
attributes; no table is looked up per cycle.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

from m4k_rt.control.guard import STALE_POLICIES
from m4k_rt.control.pid import ANTI_WINDUP_MODES
from m4k_rt.schema import build, ConfigError, Field, section, setting, table, validate_tree

# Longest speed window in samples (1 s at the 10 ms actuator period): the ring is preallocated.
MAX_SPEED_WINDOW = 100


class ControlConfigError(ConfigError):
    """A control parameter is missing, of the wrong type or out of range; ``field`` names it."""

    def __init__(self, field_path: str, message: str) -> None:
        super().__init__(field_path, message)
        self.field = field_path


def _pos(unit: str, default: float | None, description: str, nullable: bool = False,
         hi: float | None = None) -> Field:
    return Field('float', default, description, unit=unit, lo=0, lo_open=True, hi=hi,
                 nullable=nullable)


def _nonneg(unit: str, default: float | None, description: str,
            nullable: bool = False) -> Field:
    return Field('float', default, description, unit=unit, lo=0, nullable=nullable)


def _axis(name: str, unit: str, vel: float, acc: float, dec: float | None) -> dict[str, Field]:
    return {
        'max_velocity': _pos(
            unit, vel, "Speed limit; commands beyond it are clamped (also the bridge's "
            'max_{}_velocity). Above what the motors reach, the PI saturates.'.format(name)),
        'max_acceleration': _pos(
            unit + '/s', acc, 'Acceleration limit of the ramp. Too high: wheel slip and '
            'current peaks; too low: sluggish response.'),
        'max_deceleration': _pos(
            unit + '/s', dec, 'Deceleration limit (braking on timeout too); null: '
            'max_acceleration. Too low lengthens every stop.', nullable=True),
        'max_jerk': _pos(
            unit + '/s^2', None, 'Jerk limit; null: none. Low values smooth the ramp and '
            'lengthen stops.', nullable=True),
    }



@dataclass(frozen=True)
class AxisLimits:
    """Limits of one axis (linear in m/s, m/s^2, m/s^3 or angular in rad/s, ...).

    Declared by :func:`_axis` for each axis (defaults and units differ); None: see the table.
    """

    max_velocity: float
    max_acceleration: float
    max_deceleration: float | None   # None: same as max_acceleration
    max_jerk: float | None           # None: no jerk limit


@dataclass(frozen=True)
class EStopParams:
    """Decelerations of the latched e-stop (``control.e_stop``); None: the axis's maximum."""

    linear_deceleration: float | None = setting(_pos(
        'm/s^2', None, 'Latched e-stop ramp; null: linear.max_deceleration. Below it is '
        'refused (the e-stop may not stop later than a stale command).', nullable=True))
    angular_deceleration: float | None = setting(_pos(
        'rad/s^2', None, 'Latched e-stop ramp; null: the angular maximum deceleration.',
        nullable=True))
    contact_samples: int = setting(Field(
        'int', 5, 'Consecutive ENCODERS samples with ESTOP_OPEN before the open contact counts '
        '(5 = 50 ms): filters contact bounce and the read-back glitch when the enable '
        'heartbeat restarts. The contact cuts the amplifier in hardware at once either way; '
        'larger only delays the latch and the PI reset.', lo=1, hi=50))


@dataclass(frozen=True)
class PiGains:
    """Wheel-speed PI gains (normalized command per rad/s)."""

    kp: float = setting(_nonneg(
        '1/(rad/s)', 0.02, 'Proportional gain of the wheel-speed PI '
        '(normalized command per rad/s). Too high: oscillation.'))
    ki: float = setting(_nonneg(
        '1/rad', 0.4, 'Integral gain. Too high: overshoot; 0: steady-state '
        'error under load.'))
    kff: float | None = setting(_nonneg(
        '1/(rad/s)', None, 'Feed-forward gain; null: 1 / '
        'full_scale_wheel_speed.', nullable=True))
    anti_windup: str = setting(Field(
        'str', 'clamping', 'Integrator anti-windup at saturation.',
        choices=ANTI_WINDUP_MODES))
    kt: float | None = setting(_nonneg(
        '', None, 'Back-calculation tracking gain; null: ki / kp.',
        nullable=True))
    integral_band: float = setting(_pos(
        'rad/s', 1.5, 'Integral separation on braking: while a wheel '
        'turns faster than its setpoint by more than this, the integrator '
        'holds, so a braking transient (a guard stop, its release) cannot '
        'wind it up to drive the wheels past the setpoint -- backwards '
        'after a stop. Underspeed (load, stall) integrates as always. Too '
        'small: slow correction of an overspeed; too large: windup.'))
    breakaway_rate: float = setting(_nonneg(
        '1/s', 2.0, 'Break-away: while a wheel has not yet turned 3 encoder counts its '
        "setpoint's way since the setpoint left zero (or changed sign), and reads no motion "
        'beyond a count of noise, the integrator rises at least this fast (normalized per s) '
        "in the setpoint's direction. Static friction and an amplifier dead band (up to "
        '~2.4 V uncalibrated, supervision.moving_effort) hold a wheel at rest at a creep, where '
        'ki alone takes over a second to wind through them; this starts it within ~0.1 s, and '
        'gives the wheel supervision an effort to judge a blocked wheel or a frozen encoder '
        'by. 0: off. Too high: a jerk when an uncalibrated wheel breaks away.'))
    breakaway_effort: float = setting(_pos(
        '', 0.15, 'Break-away: the boost stops once |PI output| reaches this (normalized; '
        'above supervision.moving_effort, so a wheel that has not moved by then is judged '
        'frozen or blocked): it caps what a frozen encoder makes the wheel do before the '
        'supervision latches.', hi=1.0))


@dataclass(frozen=True)
class HoldParams:
    """Standstill hold (``control.hold``): the wheels held where they stopped, on a ramp too."""

    enabled: bool = setting(Field(
        'bool', True, 'Hold the wheels at zero speed once they have stopped with zero '
        'setpoints (a stop, a guard stop, the e-stop ramp, no command yet), and stand both '
        'wheels whose setpoints are below what the encoders resolve; the supervision judges a '
        'held wheel by supervision.standstill_window. false: the zero word only (the back-EMF '
        'brakes, nothing holds): on a ramp steeper than ~2.7 deg the robot rolls away and the '
        'still test latches a motor fault (hazard C19).'))
    kp: float = setting(_nonneg(
        '1/(rad/s)', 0.2, 'Hold: normalized command per rad/s of wheel speed beyond a count '
        'of encoder noise, on a pulled wheel only (brakes it to where it reads still and the '
        'integral starts). 0: the zero word alone brakes a pulled wheel, which on a steep '
        'ramp may never bring it to rest.'))
    ki: float = setting(_pos(
        '1/rad', 1.0, 'Hold: normalized command per rad the wheel has turned since the hold '
        'began (stiffness; 4.8 deg needs ~0.03, a few mm at the rim). Too low: the robot '
        'creeps downhill before it holds; too high: overshoot.'))
    limit: float = setting(_pos(
        '', 0.25, 'Hold: the largest |command| (normalized) it applies: what a 15 deg ramp '
        '(~0.08), an amplifier dead band and an uncalibrated zero (up to ~2.4 V, 0.1; '
        'supervision.moving_effort) need. A wheel driven harder at a zero command (an '
        'amplifier offset, a stuck DAC) or a steeper slope rolls it, and the still test '
        'latches the fault; too high hides such a fault behind stall current.', hi=1.0))
    speed: float = setting(_pos(
        'rad/s', 0.3, 'Hold: begins once both wheels turn slower than this, and integrates '
        'only below it (a faster wheel is braked, never driven back toward where it '
        'was).'))
    pull_deceleration: float = setting(_pos(
        'rad/s^2', 10.0, 'Hold: also begins when a wheel slows less than this from its speed '
        'when the setpoints went to zero (+ speed): pulled (a ramp), not braked by the zero '
        'word (~28 rad/s^2 on the level). Keep it above supervision.still_deceleration, so '
        'the hold acts before the still test judges the wheel.'))


@dataclass(frozen=True)
class GuardParams:
    """Collision guard settings (see ``control.guard``)."""

    enabled: bool = setting(Field(
        'bool', True, 'Collision guard on forward motion. false: the '
        'robot drives into what its sensors see.'))
    stop_distance: float = setting(_nonneg(
        'm', 0.35, 'Margin of the speed-aware stop zone: the gap '
        'kept ahead of the front face at rest. The stop zone is '
        'd(v) = v t_react + v^2 / (2 brake_deceleration) + this; '
        'too small: contact from sensor noise or a late reading.'))
    release_margin: float = setting(_nonneg(
        'm', 0.05, 'Hysteresis: once stopped, released above '
        'd(slow_floor) + margin (stop_distance + margin without '
        'the slow-down zone); 0 lets noise toggle the guard.'))
    brake_deceleration: float = setting(_pos(
        'm/s^2', 1.5, 'a_brake: the deceleration the drive gives on a guard stop (zero '
        'command, ramp bypassed), bounded by tyre traction (about mu g, mu <= 0.7) and the '
        "amplifier's current limit. calibrate writes the measured value here. Too high: the "
        'stop zone is too short and the robot hits what it sees at speed.', hi=9.81))
    pipeline_latency: float = setting(_nonneg(
        's', 0.02, 'Datagram hops sensor driver -> RT task -> actuator -> motor driver: part '
        'of t_react (m4k_rt.control.reaction). Too low: the robot stops late.'))
    scheduling_allowance: float = setting(_nonneg(
        's', 0.03, 'Wake-up latency of the RT tasks on their host (a shared 2-vCPU VM shows '
        'tens of ms): part of t_react, and the scenario judge allows no more. Too low: the '
        'robot stops late on a loaded host.'))
    laser_scan_time: float = setting(_nonneg(
        's', 0.1, 'One laser sweep (URG-04LX: 600 rpm, 0.1 s): the scan is stamped at its '
        "start and sent after it, so a point at the sweep's end is that much older; part of "
        "t_react when the laser sets it."))
    amplifier_lag: float = setting(_nonneg(
        's', 0.05, "t_react's actuation part: from the zero DAC word to the wheels' "
        'deceleration (amplifier and motor current rise). calibrate measures it and writes '
        'this key only: the sensor and RT parts of t_react stay (docs/safety.md). Too low: '
        'the robot stops late.'))
    slow_down: bool = setting(Field(
        'bool', True, 'Slow-down zone ahead of the stop zone: the forward '
        'target is capped at the inverse of d(v) with linear.'
        'max_deceleration, so the ramp can follow it. false: the robot '
        'drives at full speed until the stop zone brakes it hard.'))
    slow_floor: float = setting(_nonneg(
        'm/s', 0.05, 'Lowest slow-down cap: the robot keeps this '
        'speed until the stop zone stops it (0: it creeps toward the '
        'stop line ever more slowly).'))
    lateral_margin: float = setting(_nonneg(
        'm', 0.05, "Added to each side of the robot's half width (the drive wheels' "
        "outer faces, m4k_rt.control.footprint) for the laser's corridor test. 0: an "
        'obstacle grazing the side is not seen.'))
    reverse_creep_speed: float = setting(_pos(
        'm/s', 0.1, 'Reverse speed cap: no rear sensor guards '
        'reversing, so it is limited to a creep. Higher: the '
        'robot backs into what it cannot see faster.'))
    laser_range: float = setting(_pos(
        'm', 5.6, 'Farthest range the laser measures (URG-04LX: 5.6 m): '
        'with the mount offset it bounds the top forward speed the guard '
        'can stop for.'))
    sonar_range: float = setting(_pos(
        'm', 4.5, 'Farthest range the sonar measures (US-100: 4.5 m); '
        'bounds the top speed when the laser is not used.'))
    use_sonar: bool = setting(Field(
        'bool', True, 'Feed the sonar to the guard.'))
    use_laser: bool = setting(Field(
        'bool', True, "Feed the laser's corridor minimum to the guard."))
    sonar_timeout: float = setting(_pos(
        's', 0.2, 'A sonar reading older than this (aged from its ping) leaves the sonar '
        'stale (see stale_policy). Part of t_react (its sensor part is never shorter).'))
    laser_timeout: float = setting(_pos(
        's', 0.7, 'A scan older than this (aged from its stamp, the start of the sweep) leaves '
        'the laser stale. Part of t_react (its sensor part is never shorter). Normal scans '
        'are up to about 0.6 s old when the next one replaces them (a 0.1 s sweep and its '
        'transfer, then up to two 0.2 s lrf periods): shorter stops the robot on every '
        'late scan.'))
    memory_points: int = setting(Field(
        'int', 64, 'Obstacle memory size (points in the odometry frame, m4k_rt.control.memory): '
        'what a sensor saw in the corridor is kept until a sensor sees that place free. Full: '
        'the point farthest from the robot is replaced. Too small: a busy scene pushes out '
        'what only the memory still knows.', lo=8, hi=1024))
    sonar_cone: float = setting(_pos(
        'rad', 0.2618, "The sonar's full beam angle (US-100: about 15 deg): where its echo may "
        'come from and what its cone covers when it frees memory points. Too wide: the sonar '
        'frees places it cannot hear; too narrow: arcs miss the corridor edges.', hi=1.0))
    stale_policy: str = setting(Field(
        'str', 'stop', 'stop: a stale sensor counts as an obstacle '
        '(fail-safe); ignore: drive on without it.',
        choices=STALE_POLICIES))


@dataclass(frozen=True)
class SupervisionParams:
    """Wheel supervision settings (see ``control.supervision``): the one declaration."""

    enabled: bool = setting(Field(
        'bool', True, 'Wheel supervision: wrong direction, stall, '
        'frozen or swapped encoders, a wheel turning while commanded still and wheels '
        'disagreeing with the IMU latch a motor fault. false: a wrong-sign encoder drives the '
        'PI to full scale.'))
    speed_threshold: float = setting(_pos(
        'rad/s', 0.5, 'The wrong-way, saturation-stall and swap tests act while |wheel '
        'setpoint| is above this (0.5 rad/s = 5 cm/s at the rim); below it the frozen, '
        'effort, still and IMU tests watch the wheels. Too low: a reversal read as wrong way.'))
    min_speed: float = setting(_pos(
        'rad/s', 0.3, 'A measured wheel speed below this has no direction (the wrong-way and '
        'swap tests ignore it; a category-1 stop after a stall counts it as rest). Too low: a '
        'reversal read as wrong way.'))
    wrong_way_time: float = setting(_pos(
        's', 0.1, 'A wheel turning against its setpoint this '
        'long latches the fault.', hi=0.3))
    frozen_time: float = setting(_pos(
        's', 0.15, 'An encoder angle unchanged this long while the '
        'wheel is told to turn (seen following its setpoint, or moving_effort) latches the '
        'fault.', hi=0.3))
    moving_effort: float = setting(_pos(
        '', 0.12, 'The frozen test acts on a wheel never seen turning with its setpoint '
        'once |PI output| (normalized, 1 = full scale) is at least this: enough to break any '
        'plausible wheel away from rest (friction takes ~0.014 on the simulated base; an '
        'uncalibrated amplifier zero and dead band up to ~2.4 V more), so a PI winding up on '
        'a frozen reading is caught at any setpoint; the break-away boost (pi.breakaway_rate, '
        'up to pi.breakaway_effort, which must be above this) gets a wheel that has not moved '
        'there within ~0.1 s. Too low: an uncalibrated wheel still breaking away trips it; '
        'too high: a wheel blocked or an encoder frozen from the start is judged late.',
        hi=1.0))
    stall_time: float = setting(_pos(
        's', 0.2, 'A wheel not following its drive effort (stall_ratio at saturation, or '
        'effort_margin) this long latches the fault.', hi=0.3))
    stall_ratio: float = setting(_pos(
        '', 0.2, 'Stall at saturation: measured speed below this fraction of the '
        'setpoint.', hi=1.0))
    effort_margin: float = setting(_pos(
        'rad/s', 3.0, 'Effort against speed: the PI output over the feed-forward gain (the '
        'speed it drives a free wheel at) exceeding the measured speed by this is a stall. '
        '3 rad/s = 0.15 of full scale, 3.7 V beyond the back-EMF: above the current limit '
        'times the armature resistance (the wheel would accelerate at the limit) and above '
        'what an uncalibrated amplifier zero and dead band hold back (~2.4 V, moving_effort). '
        'Too low: an uncalibrated wheel breaking away, a hard acceleration or a slope trips '
        'it.'))
    still_speed: float = setting(_pos(
        'rad/s', 0.15, 'Still test: a wheel turning this much faster than its falling bound '
        'while its setpoint is zero is a symptom (0.15 rad/s = 1.5 cm/s at the rim: two '
        'encoder counts over the 20 ms feedback window, which noise does not hold for '
        'still_time). Slower creeps at a zero command go unseen.'))
    still_deceleration: float = setting(_pos(
        'rad/s^2', 6.0, 'Still test: with a zero setpoint (zero word, the drive brakes) the '
        "wheel's speed must stay under a bound falling at this rate from its speed when the "
        'setpoint went to zero (the drive brakes at ~28 rad/s^2, friction alone 3.6, the '
        'ramps reach a zero setpoint with the wheel within 0.3 rad/s of it). Too high: a '
        'traction-limited stop on a slippery floor trips it.'))
    still_time: float = setting(_pos(
        's', 0.15, 'A wheel above the still bound (+ still_speed) this long latches the fault.',
        hi=0.3))
    standstill_window: float = setting(_pos(
        'counts', 60.0, 'Standstill window of a held wheel (control.hold): a wheel the hold '
        'holds is judged by where it is, not by its speed (IEC 61800-5-2 safe operating '
        'stop): turned more than this many encoder counts from where it first read still in '
        'its hold (60: '
        '9 mm at the rim) latches the fault at once. Above what a held wheel turns while '
        'the hold takes the load of a 4.8 deg ramp (15-40 counts, python -m m4k_bench.latch '
        '--hold); a wheel driven beyond the hold (an amplifier offset over ~2 V, a slope past '
        'hold.limit) leaves it. The speed still test does not judge a held wheel: a hold '
        'still taking its load rolls it slowly for longer than still_time.'))
    level_hold_effort: float = setting(Field(
        'float', 0.1, 'On the level, the most load the standstill hold may hold on a wheel '
        '(its integral, normalized command; 1: no such test): with a fresh IMU sample saying '
        'the floor is level along the track (level_grade), a hold holding more latches the '
        'still fault at once -- nothing on a level floor leans on a wheel standing still that '
        'hard, so the amplifier drives it (an input offset, a stuck DAC). Measured in virtual '
        'time (python -m m4k_bench.latch --hold): healthy holds on the level hold at most '
        '0.008 (three bases; stops and guard stops from a creep to 2 m/s, straight, arcs, '
        'reversing, turning in place, a guard chattering at its release line); a 2-6 V offset '
        'passes 0.1 within 0.10 s (the window alone latched 2-3 V in 0.29-0.86 s).',
        lo=0, lo_open=True, hi=1.0))
    level_grade: float = setting(_pos(
        'deg', 1.0, "The floor counts as level for level_hold_effort while the IMU's "
        "orientation (its AHRS fusion, not the accelerometer alone, which reads the wheels' "
        'motion too) puts base_link x within this angle of the horizontal (robot.sensors.imu.'
        'pose turns imu_link into base_link). On a steeper slope, or without a fresh IMU '
        'sample, the test is skipped; the standstill window still applies.', hi=10.0))
    swap_time: float = setting(_pos(
        's', 0.1, "Wheels answering each other's setpoints this "
        'long (swapped channels) latch the fault.', hi=0.3))
    use_imu: bool = setting(Field(
        'bool', True, "Compare the wheels' yaw rate with the IMU gyro's (fresh samples "
        'only; a stale IMU skips the test). false: an encoder frozen from the start at a creep '
        'latches only once the PI has reached moving_effort (the break-away boost: ~0.1 s).'))
    yaw_tolerance: float = setting(_pos(
        'rad/s', 0.08, "Yaw test: |wheels' yaw rate - gyro| beyond this (plus yaw_ratio) is a "
        'symptom. Covers gyro noise and bias (myAHRS+: ~0.003 rad/s each) and the skew of '
        'the IMU and encoder samples (0.04 rad/s). Too low: turns trip it.'))
    yaw_ratio: float = setting(Field(
        'float', 0.25, 'Yaw test: the tolerance grows by this fraction of the larger yaw rate '
        '(tyre slip, track-width error).', lo=0, hi=1.0))
    yaw_time: float = setting(_pos(
        's', 0.15, 'The yaw symptom this long latches the fault.', hi=0.3))
    imu_timeout: float = setting(_pos(
        's', 0.05, 'A gyro sample older than this (IMU task receive time) is not used by the '
        'yaw test.', hi=1.0))


def _axis_deceleration(limits: AxisLimits) -> float:
    return (limits.max_acceleration if limits.max_deceleration is None
            else limits.max_deceleration)


@dataclass(frozen=True)
class ControlParams:
    """All parameters of the base controller: the one declaration of ``control:``."""

    wheel_radius: float = setting(_pos(
        'm', 0.1016, 'Wheel radius (Table 2: 20.32 cm diameter). Wrong: '
        'odometry and commanded speeds scale by the error.'))
    track_width: float = setting(_pos(
        'm', 0.40, 'Wheel centre to wheel centre. Wrong: turn rates and '
        'odometry heading scale by the error.'))
    gear_ratio: float = setting(_pos(
        '', 12.0, 'Motor turns per wheel turn (Table 2).'))
    full_scale_wheel_speed: float = setting(_pos(
        'rad/s', 19.685, 'Wheel speed at DAC code 1023 (feed-forward). Wrong: the PI must '
        'make up the difference, with overshoot.'))
    max_wheel_speed: float | None = setting(_pos(
        'rad/s', None, 'Wheel command saturation; null: '
        'full_scale_wheel_speed.', nullable=True))
    cmd_vel_timeout: float = setting(_nonneg(
        's', 0.5, 'Without VELOCITY_CMD this long, the actuator brakes at the deceleration '
        "limit; 0 = off (the robot keeps the last command forever). The bridge's "
        'cmd_vel_timeout is derived from it.'))
    motor_timeout: float = setting(_pos(
        's', 0.1, 'Without valid ENCODERS this long the motor is stale: '
        'outputs zero, disabled.'))
    odom_every_n: int = setting(Field(
        'int', 5, 'ODOMETRY every n-th actuator cycle (5 x 10 ms = 50 ms, '
        'the paper). Larger: coarser odom for Nav2.', lo=1))
    odom_velocity_window: int = setting(Field(
        'int', 5, 'Encoder samples the published twist is differenced over (1 = 10 ms: noisy '
        'with a 12-bit encoder).', lo=1, hi=MAX_SPEED_WINDOW))
    speed_feedback_window: int = setting(Field(
        'int', 2, 'Samples the PI wheel speed is differenced over. Longer: less DAC chatter, '
        'more lag and overshoot.', lo=1, hi=MAX_SPEED_WINDOW))
    speed_filter_alpha: float = setting(Field(
        'float', 1.0, 'EMA weight of a new wheel-speed sample for the PI; 1 = no filter. Low '
        'values add lag.', lo=0, lo_open=True, hi=1.0))
    linear: AxisLimits = section(AxisLimits, _axis('linear', 'm/s', 2.0, 0.37, 0.37))
    angular: AxisLimits = section(AxisLimits, _axis('angular', 'rad/s', 1.5, 1.85, None))
    e_stop: EStopParams = section(EStopParams)
    pi: PiGains = section(PiGains)
    hold: HoldParams = section(HoldParams)
    guard: GuardParams = section(GuardParams)
    supervision: SupervisionParams = section(SupervisionParams)
    @property
    def e_stop_linear_deceleration(self) -> float:
        """Return the e-stop's linear deceleration actually used [m/s^2]."""
        d = self.e_stop.linear_deceleration
        return _axis_deceleration(self.linear) if d is None else d

    @property
    def e_stop_angular_deceleration(self) -> float:
        """Return the e-stop's angular deceleration actually used [rad/s^2]."""
        d = self.e_stop.angular_deceleration
        return _axis_deceleration(self.angular) if d is None else d

    @property
    def feed_forward(self) -> float:
        """Return the PI feed-forward gain actually used."""
        return 1.0 / self.full_scale_wheel_speed if self.pi.kff is None else self.pi.kff

    @property
    def wheel_limit(self) -> float:
        """Return the wheel speed command saturation actually used."""
        return (self.full_scale_wheel_speed if self.max_wheel_speed is None
                else self.max_wheel_speed)


# The section's dotted table, derived from the declaration above (docs, validation, bridge).
CONTROL: dict[str, Field] = table(ControlParams)


def control_params(mapping: Mapping[str, Any] | None, path: str = 'control') -> ControlParams:
    """Validate the ``control:`` mapping and return ``ControlParams`` (defaults fill gaps)."""
    params: ControlParams = build(
        ControlParams, validate_tree(CONTROL, mapping, path, ControlConfigError))
    lin_dec = _axis_deceleration(params.linear)
    if params.guard.brake_deceleration < lin_dec:
        raise ControlConfigError(
            f'{path}.guard.brake_deceleration',
            f'must be >= linear.max_deceleration ({lin_dec!r}: the ramp cannot brake harder '
            f'than the drive can), got {params.guard.brake_deceleration!r}')
    # An e-stop that brakes more gently than a stale command would stop the robot later than
    # losing the operator's link does.
    for axis, value, normal in (
            ('linear', params.e_stop.linear_deceleration, _axis_deceleration(params.linear)),
            ('angular', params.e_stop.angular_deceleration,
             _axis_deceleration(params.angular))):
        if value is not None and value < normal:
            raise ControlConfigError(
                f'{path}.e_stop.{axis}_deceleration',
                f'must be >= {axis}.max_deceleration ({normal!r}: the e-stop may not brake '
                f'more gently than a stale command), got {value!r}')
    # A boost that stops below the effort the frozen test waits for would leave a blocked
    # wheel at a creep to the slow plain PI again (1.5 s at 2 cm/s).
    sup = params.supervision
    if params.pi.breakaway_rate > 0.0 and sup.enabled \
            and params.pi.breakaway_effort <= sup.moving_effort:
        raise ControlConfigError(
            f'{path}.pi.breakaway_effort',
            f'must be > supervision.moving_effort ({sup.moving_effort!r}: a wheel that has '
            f'not moved must reach the effort it is judged by), got '
            f'{params.pi.breakaway_effort!r}')
    if params.hold.enabled and sup.enabled \
            and params.hold.pull_deceleration <= sup.still_deceleration:
        raise ControlConfigError(
            f'{path}.hold.pull_deceleration',
            f'must be > supervision.still_deceleration ({sup.still_deceleration!r}: the hold '
            f'must take a pulled wheel before the still test judges it), got '
            f'{params.hold.pull_deceleration!r}')
    return params
