"""Control parameters: the ``control:`` section of ``config/control.yaml``, validated (pure).

``control_params(mapping)`` turns the parsed section into frozen dataclasses and raises
``ControlConfigError`` naming the offending field with its dotted path (e.g.
``control.linear.max_acceleration``) and the bad value. Unknown keys are errors too:
a misspelt key would otherwise silently keep a default.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
import math
from typing import Any, Mapping

from m4k_rt.control.guard import STALE_POLICIES
from m4k_rt.control.pid import ANTI_WINDUP_MODES

# Longest speed window in samples (1 s at the 10 ms actuator period): the ring is preallocated.
MAX_SPEED_WINDOW = 100


class ControlConfigError(ValueError):
    """A control parameter is missing, of the wrong type or out of range; ``field`` names it."""

    def __init__(self, field_path: str, message: str) -> None:
        super().__init__(f'{field_path}: {message}')
        self.field = field_path


@dataclass(frozen=True)
class AxisLimits:
    """Limits of one axis (linear in m/s, m/s^2, m/s^3 or angular in rad/s, ...)."""

    max_velocity: float = 2.0
    max_acceleration: float = 0.37
    max_deceleration: float | None = None   # None: same as max_acceleration
    max_jerk: float | None = None           # None: no jerk limit


@dataclass(frozen=True)
class PiGains:
    """Wheel-speed PI gains (normalized command per rad/s)."""

    kp: float = 0.02
    ki: float = 0.4
    kff: float | None = None    # None: 1 / full_scale_wheel_speed
    anti_windup: str = 'clamping'
    kt: float | None = None     # back-calculation tracking gain; None: ki / kp


@dataclass(frozen=True)
class GuardParams:
    """Collision guard settings (see ``control.guard``)."""

    enabled: bool = True
    stop_distance: float = 0.35
    release_margin: float = 0.05
    slow_distance: float = 0.0
    front_sector_deg: float = 30.0
    use_sonar: bool = True
    use_laser: bool = True
    sonar_timeout: float = 0.2
    laser_timeout: float = 0.5
    stale_policy: str = 'stop'


@dataclass(frozen=True)
class EStopParams:
    """Decelerations of the latched e-stop (``control.e_stop``); None: the axis's maximum."""

    linear_deceleration: float | None = None    # m/s^2
    angular_deceleration: float | None = None   # rad/s^2


def _axis_deceleration(limits: AxisLimits) -> float:
    return (limits.max_acceleration if limits.max_deceleration is None
            else limits.max_deceleration)


@dataclass(frozen=True)
class ControlParams:
    """All parameters of the base controller."""

    wheel_radius: float = 0.1016
    track_width: float = 0.40
    gear_ratio: float = 12.0
    full_scale_wheel_speed: float = 19.685  # wheel rad/s at DAC full scale (2 m/s top speed)
    max_wheel_speed: float | None = None    # wheel command saturation; None: full scale
    cmd_vel_timeout: float = 0.5            # s; 0 disables the stale-command brake
    motor_timeout: float = 0.1              # s without ENCODERS -> motor stale
    odom_every_n: int = 5
    odom_velocity_window: int = 5           # samples the published twist is differenced over
    speed_feedback_window: int = 2          # samples the PI's wheel speeds are differenced over
    speed_filter_alpha: float = 1.0         # EMA weight of a new wheel-speed sample; 1 = off
    linear: AxisLimits = field(default_factory=AxisLimits)
    angular: AxisLimits = field(default_factory=lambda: AxisLimits(1.5, 1.85, None, None))
    pi: PiGains = field(default_factory=PiGains)
    guard: GuardParams = field(default_factory=GuardParams)
    e_stop: EStopParams = field(default_factory=EStopParams)

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


def _number(path: str, value: Any, *, minimum: float | None = None, positive: bool = False,
            optional: bool = False, integer: bool = False) -> Any:
    if value is None and optional:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ControlConfigError(path, f'expected a number, got {value!r}')
    if integer and not isinstance(value, int):
        raise ControlConfigError(path, f'expected an integer, got {value!r}')
    if not math.isfinite(value):
        raise ControlConfigError(path, f'must be finite, got {value!r}')
    if positive and value <= 0:
        raise ControlConfigError(path, f'must be > 0, got {value!r}')
    if minimum is not None and value < minimum:
        raise ControlConfigError(path, f'must be >= {minimum}, got {value!r}')
    return value if integer else float(value)


def _section(path: str, value: Any, cls: type) -> dict[str, Any]:
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise ControlConfigError(path, f'expected a mapping, got {value!r}')
    known = {f.name for f in fields(cls)}
    for key in value:
        if key not in known:
            raise ControlConfigError(f'{path}.{key}', f'unknown key (known: {sorted(known)})')
    return dict(value)


def _axis(path: str, raw: Any, default: AxisLimits) -> AxisLimits:
    d = _section(path, raw, AxisLimits)
    out = {}
    for f in fields(AxisLimits):
        optional = f.name in ('max_deceleration', 'max_jerk')
        out[f.name] = _number(f'{path}.{f.name}', d.get(f.name, getattr(default, f.name)),
                              positive=True, optional=optional)
    return AxisLimits(**out)


def _choice(path: str, value: Any, choices: tuple[str, ...]) -> str:
    if value not in choices:
        raise ControlConfigError(path, f'must be one of {choices}, got {value!r}')
    return str(value)  # one of ``choices``


def _flag(path: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise ControlConfigError(path, f'expected true or false, got {value!r}')
    return value


def control_params(section: Mapping[str, Any] | None, path: str = 'control') -> ControlParams:
    """Validate the ``control:`` mapping and return ``ControlParams`` (defaults fill gaps)."""
    d = _section(path, section, ControlParams)
    base = ControlParams()
    p = f'{path}.pi'
    pi_raw = _section(p, d.get('pi'), PiGains)
    pi = PiGains(
        kp=_number(f'{p}.kp', pi_raw.get('kp', base.pi.kp), minimum=0.0),
        ki=_number(f'{p}.ki', pi_raw.get('ki', base.pi.ki), minimum=0.0),
        kff=_number(f'{p}.kff', pi_raw.get('kff', base.pi.kff), minimum=0.0, optional=True),
        anti_windup=_choice(f'{p}.anti_windup', pi_raw.get('anti_windup', base.pi.anti_windup),
                            ANTI_WINDUP_MODES),
        kt=_number(f'{p}.kt', pi_raw.get('kt', base.pi.kt), minimum=0.0, optional=True),
    )
    g = f'{path}.guard'
    g_raw = _section(g, d.get('guard'), GuardParams)
    gd = base.guard

    def gnum(name: str, **kw: Any) -> float:
        value: float = _number(f'{g}.{name}', g_raw.get(name, getattr(gd, name)), **kw)
        return value

    guard = GuardParams(
        enabled=_flag(f'{g}.enabled', g_raw.get('enabled', gd.enabled)),
        stop_distance=gnum('stop_distance', minimum=0.0),
        release_margin=gnum('release_margin', minimum=0.0),
        slow_distance=gnum('slow_distance', minimum=0.0),
        front_sector_deg=gnum('front_sector_deg', positive=True),
        use_sonar=_flag(f'{g}.use_sonar', g_raw.get('use_sonar', gd.use_sonar)),
        use_laser=_flag(f'{g}.use_laser', g_raw.get('use_laser', gd.use_laser)),
        sonar_timeout=gnum('sonar_timeout', positive=True),
        laser_timeout=gnum('laser_timeout', positive=True),
        stale_policy=_choice(f'{g}.stale_policy', g_raw.get('stale_policy', gd.stale_policy),
                             STALE_POLICIES),
    )
    if guard.front_sector_deg > 240.0:
        raise ControlConfigError(f'{g}.front_sector_deg',
                                 f'must be <= 240 (the scan width), got '
                                 f'{guard.front_sector_deg!r}')
    if guard.slow_distance and guard.slow_distance <= guard.stop_distance:
        raise ControlConfigError(f'{g}.slow_distance',
                                 f'must be 0 (off) or > stop_distance ({guard.stop_distance!r}), '
                                 f'got {guard.slow_distance!r}')

    e = f'{path}.e_stop'
    e_raw = _section(e, d.get('e_stop'), EStopParams)
    e_stop = EStopParams(**{
        f.name: _number(f'{e}.{f.name}', e_raw.get(f.name), positive=True, optional=True)
        for f in fields(EStopParams)})

    def num(name: str, **kw: Any) -> Any:
        return _number(f'{path}.{name}', d.get(name, getattr(base, name)), **kw)

    params = ControlParams(
        wheel_radius=num('wheel_radius', positive=True),
        track_width=num('track_width', positive=True),
        gear_ratio=num('gear_ratio', positive=True),
        full_scale_wheel_speed=num('full_scale_wheel_speed', positive=True),
        max_wheel_speed=num('max_wheel_speed', positive=True, optional=True),
        cmd_vel_timeout=num('cmd_vel_timeout', minimum=0.0),
        motor_timeout=num('motor_timeout', positive=True),
        odom_every_n=num('odom_every_n', minimum=1, integer=True),
        odom_velocity_window=num('odom_velocity_window', minimum=1, integer=True),
        speed_feedback_window=num('speed_feedback_window', minimum=1, integer=True),
        speed_filter_alpha=num('speed_filter_alpha', positive=True),
        linear=_axis(f'{path}.linear', d.get('linear'), base.linear),
        angular=_axis(f'{path}.angular', d.get('angular'), base.angular),
        pi=pi,
        guard=guard,
        e_stop=e_stop,
    )
    # An e-stop that brakes more gently than a stale command would stop the robot later than
    # losing the operator's link does.
    for axis, value, normal in (
            ('linear', params.e_stop.linear_deceleration, _axis_deceleration(params.linear)),
            ('angular', params.e_stop.angular_deceleration,
             _axis_deceleration(params.angular))):
        if value is not None and value < normal:
            raise ControlConfigError(
                f'{e}.{axis}_deceleration',
                f'must be >= {axis}.max_deceleration ({normal!r}: the e-stop may not brake '
                f'more gently than a stale command), got {value!r}')
    for name in ('odom_velocity_window', 'speed_feedback_window'):
        if getattr(params, name) > MAX_SPEED_WINDOW:
            raise ControlConfigError(f'{path}.{name}',
                                     f'must be <= {MAX_SPEED_WINDOW} samples, '
                                     f'got {getattr(params, name)!r}')
    if params.speed_filter_alpha > 1.0:
        raise ControlConfigError(f'{path}.speed_filter_alpha',
                                 f'must be in (0, 1], got {params.speed_filter_alpha!r}')
    return params
