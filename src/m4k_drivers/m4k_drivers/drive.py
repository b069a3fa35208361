"""The simulated M4K drive train: amplifier, DC motors, 12:1 gears, tyres, body (pure physics).

Per wheel: the DAC's armature command ``u`` (volts, plus the amplifier's input offset, less its
dead band) -> a voltage-mode amplifier with a current limit: ``I = clamp((u - ke * w_m) / R,
+/-I_max)`` while enabled; while disabled, ``I = -ke w_m / (R + R_db)`` through the dynamic
brake resistor when one is wired (``dynamic_brake_ohm``), else ``I = 0`` (the outputs float:
no drive and no back-EMF braking) -> motor torque ``kt * I`` (SI: ``kt = ke``) less the
drive train's dry friction (the motor's no-load current, ``kt * I0``) -> the gear (``N`` =
12, efficiency ``eta``: ``N * eta * T`` when the motor drives the wheel, ``N * T / eta`` when
the wheel drives the motor, i.e. when braking) -> the wheel, whose inertia includes the
rotor's reflected ``N^2 J_r``.

The ground pushes each wheel with a traction force ``F`` (and the body with ``-F``... forward on
the body). While the tyre holds (``|F| <= mu * load``), the wheel's rim speed equals the ground
speed of its contact point; the force that keeps it so is solved each step, implicitly in the
motor's back-EMF damping, so the 1 ms step is stable however stiff the motor is. When the force
needed exceeds ``mu * load``, the wheel slips: the ground's force is kinetic friction
``mu_kinetic * load`` against the slip, the wheel spins (or locks) on the motor's torque alone and
the body follows only the friction -- so the encoders (on the wheel shafts) report a rotation
the body did not make, as a real robot's odometry does. Rolling resistance (``Crr * load``) and
the drive train's friction are dry (Coulomb) friction: below them nothing moves, at a stop they
hold; at rest the drive train's sticks ``breakaway_friction`` times harder than it runs (a wheel
starts only above that, then runs against the running friction).

Defaults and their sources: docs/sim-physics.md. Each parameter is declared once, on its
:class:`RobotParams` field (type, default, unit, range, source; :data:`ROBOT_FIELDS` is the
table derived from them); ``world.robot`` overrides them.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
import math
from typing import Any, Callable, Mapping

from m4k_rt import schema
from m4k_rt.control.params import CONTROL
from m4k_rt.schema import check_keys, ConfigError, Field, setting, table

__all__ = ['DriveState', 'G', 'LEFT', 'RIGHT', 'ROBOT_FIELDS', 'RobotParams', 'WorldConfigError',
           'parse_robot', 'step_drive']

LEFT, RIGHT = 0, 1
G = 9.80665                   # m/s^2, standard gravity


class WorldConfigError(ConfigError):
    """Raise for a bad ``world:`` section; the message names the field."""


def _f(default: float, description: str, unit: str, lo: float | None = 0.0,
       hi: float | None = None, lo_open: bool = True) -> Field:
    return Field('float', default, description, unit=unit, lo=lo, hi=hi, lo_open=lo_open)


@dataclass(frozen=True)
class RobotParams:
    """Physical parameters of the M4K base: each field declared once, with its schema Field.

    Type, default, unit, range and source of every parameter are on its field
    (docs/sim-physics.md gives the sources); :data:`ROBOT_FIELDS` is the table derived from
    them, which validates ``world.robot`` and generates the docs.
    """

    # geometry (paper Table 2; the track width is our choice, world.py)
    wheel_diameter_m: float = setting(_f(
        0.2032, 'Wheel diameter (Table 2: 20.32 cm). Default: 2 * control.wheel_radius.', 'm'))
    gear_ratio: float = setting(_f(
        12.0, 'Motor turns per wheel turn (Table 2: 12:1). Default: control.gear_ratio.', ''))
    track_width_m: float = setting(_f(
        0.40, 'Wheel centre to wheel centre (not in the paper). Default: control.track_width.',
        'm'))
    length_m: float = setting(_f(
        0.45, 'Body length, the contact footprint (Table 2). Default: robot.body.length.', 'm'))
    width_m: float = setting(_f(
        0.28, 'Body width, the contact footprint (Table 2). Default: robot.body.width.', 'm'))
    wheel_width_m: float = setting(_f(
        0.05, 'Drive wheel width: the wheels stand outside the body (centres track_width '
        'apart) and are part of the contact footprint (m4k_rt.control.footprint). Default: '
        'robot.wheel_width.', 'm'))
    # drive
    top_speed_mps: float = setting(_f(
        2.0, 'Straight-line speed on the floor at full armature voltage (Table 2: 2 m/s); sets '
        'the motor constant ke. Default: control.full_scale_wheel_speed * wheel radius.', 'm/s'))
    supply_v: float = setting(_f(
        24.0, 'Amplifier supply: full-scale armature voltage (assumed 24 V).', 'V'))
    amp_offset_left_v: float = setting(_f(
        0.0, 'Left amplifier input offset (the zero error a DAC zero trim cancels), armature '
        'volts, any sign within the supply.', 'V', lo=None))
    amp_offset_right_v: float = setting(_f(
        0.0, 'Right amplifier input offset, armature volts.', 'V', lo=None))
    deadband_v: float = setting(_f(
        0.0, 'Amplifier dead band: armature volts below which it gives no voltage (friction adds '
        'its own, see no_load_current_a).', 'V', lo_open=False))
    amp_current_limit_a: float = setting(_f(
        3.0, "Amplifier's current (torque) limit, each motor: bounds drive and braking torque "
        '(assumed; docs/sim-physics.md: ~1.7 m/s^2 drive, ~2.9 m/s^2 braking on the default '
        'base).', 'A'))
    motor_resistance_ohm: float = setting(_f(
        0.6, "Armature (terminal) resistance: with ke sets the back-EMF braking and the drive's "
        'time constant (~0.08 s; assumed, 24 V 100-150 W brushed motor class).', 'ohm'))
    no_load_current_a: float = setting(_f(
        0.3, "Motor no-load current: the drive train's dry friction (brushes, bearings, gear) "
        'kt * I0, also while coasting (assumed, same class).', 'A', lo_open=False))
    breakaway_friction: float = setting(_f(
        1.3, 'Break-away (static) friction of the drive train over its running friction '
        '(no_load_current_a): brushes and gear teeth stick at rest, so a wheel starts only '
        'once its drive exceeds this multiple and then runs against the running friction '
        '(assumed: 1.2-1.5 for a brushed gearmotor; 1.0 is pure Coulomb friction).', '',
        lo=1.0, lo_open=False, hi=3.0))
    gear_efficiency: float = setting(_f(
        0.9, 'Gear efficiency under load (spur/planetary 12:1: 0.85-0.95).', '', hi=1.0))
    rotor_inertia_kgm2: float = setting(_f(
        5e-6, 'Motor rotor inertia (50 g cm^2, same motor class); reflected through the gear as '
        'N^2 J.', 'kg m^2', lo_open=False))
    wheel_inertia_kgm2: float = setting(_f(
        0.005, 'One wheel with hub about its axle (~1 kg, 20 cm).', 'kg m^2', lo_open=False))
    # body and tyres
    mass_kg: float = setting(_f(30.0, 'Whole robot (Table 2: 30 kg).', 'kg'))
    yaw_inertia_kgm2: float = setting(_f(
        0.70, 'Yaw inertia about the centre (uniform 0.45 x 0.28 m box of 30 kg: '
        'm (l^2 + w^2) / 12 = 0.70).', 'kg m^2'))
    drive_load_fraction: float = setting(_f(
        0.5, 'Share of the weight on the two drive wheels; the rest on the two casters (robot.'
        'caster_x: front and rear on the centre line), whose rolling resistance slows the '
        'body. 0.5 from the geometry: drive axle through the CoG, casters symmetric, all four '
        'contacts equally stiff on a flat floor (docs/sim-physics.md). Each drive wheel '
        'carries half of it (no load transfer modelled).', '', hi=1.0))
    mu: float = setting(_f(
        0.6, 'Static tyre-floor friction coefficient (rubber on indoor floor: 0.6-0.7; above 0.7 '
        'needs a source). Traction per wheel = mu * load.', '', hi=1.5))
    mu_kinetic: float = setting(_f(
        0.5, 'Sliding friction coefficient of a slipping tyre (<= mu).', '', hi=1.5))
    rolling_resistance: float = setting(_f(
        0.015, 'Rolling resistance coefficient Crr (rubber tyre on a hard floor: 0.01-0.02), '
        'drive wheels and casters alike.', '', lo_open=False, hi=0.2))
    dynamic_brake_ohm: float | None = setting(Field(
        'float', 8.0, 'Dynamic brake on enable loss: the armatures shorted through this '
        'resistor (each motor) while the enable is off, by a normally-closed contact of the '
        "enable relay, as wheelchair and AGV drives do: the motor's back-EMF brakes it with no "
        'power (docs/real-robot.md, recommended wiring). 8 ohm: 2.75 A at top speed, under the '
        "amplifier's 3 A the motors and wiring are sized for, braking 2.7 m/s^2 from 2 m/s "
        '(within traction). null: no such contact, the outputs float and the robot coasts.',
        unit='ohm', lo=0, nullable=True))

    @classmethod
    def from_control(cls, control: dict[str, Any] | None,
                     body: dict[str, Any] | None = None,
                     wheel_width: Any = None) -> RobotParams:
        """Return the robot ``control:`` and ``robot.body`` describe (unset keys: the defaults).

        Full scale is the wheel speed at code 1023, so the top speed is that times the radius.
        The body (``robot.body.length``/``width``, the URDF's) and the drive wheels outside it
        (``control.track_width``, ``robot.wheel_width``) make the outline the simulator's
        contacts use (:mod:`m4k_rt.control.footprint`).
        """
        base = cls()
        given: dict[str, float] = {}
        for where, section, keys, table_ in (
                ('robot.body', body, _BODY_KEYS, schema.ROBOT),
                ('control', control, _CONTROL_KEYS, CONTROL)):
            if section is None:
                continue
            if not isinstance(section, Mapping):
                raise WorldConfigError(where, f'expected a mapping, got {section!r}')
            for key in keys:
                v = section.get(key)
                if v is not None:     # null or absent: the simulator's default
                    name = key if where == 'control' else f'body.{key}'
                    given[key] = float(table_[name].validate(f'{where}.{key}', v,
                                                             WorldConfigError))
        if wheel_width is not None:
            given['wheel_width'] = float(schema.ROBOT['wheel_width'].validate(
                'robot.wheel_width', wheel_width, WorldConfigError))
        radius = given.get('wheel_radius', base.wheel_radius_m)
        out = replace(base, wheel_diameter_m=2.0 * radius,
                      length_m=given.get('length', base.length_m),
                      width_m=given.get('width', base.width_m),
                      wheel_width_m=given.get('wheel_width', base.wheel_width_m),
                      track_width_m=given.get('track_width', base.track_width_m),
                      gear_ratio=given.get('gear_ratio', base.gear_ratio))
        if 'full_scale_wheel_speed' in given:
            out = replace(out, top_speed_mps=given['full_scale_wheel_speed'] * radius)
        return out

    def replace(self, **kw: float) -> RobotParams:
        """Return a copy with some fields changed."""
        return replace(self, **kw)

    # -- derived quantities -----------------------------------------------------------------
    @property
    def wheel_radius_m(self) -> float:
        """Return the wheel radius."""
        return self.wheel_diameter_m / 2.0

    @property
    def max_wheel_rad_s(self) -> float:
        """Return the wheel speed at full armature voltage on the floor (top speed)."""
        return self.top_speed_mps / self.wheel_radius_m

    @property
    def max_motor_rad_s(self) -> float:
        """Return the motor-shaft speed at full armature voltage."""
        return self.max_wheel_rad_s * self.gear_ratio

    @cached_property
    def wheel_load_n(self) -> float:
        """Return the normal load on each drive wheel."""
        return self.mass_kg * G * self.drive_load_fraction / 2.0

    @cached_property
    def rolling_force_n(self) -> float:
        """Return each wheel's rolling resistance force."""
        return self.rolling_resistance * self.wheel_load_n

    @cached_property
    def caster_force_n(self) -> float:
        """Return the casters' rolling resistance on the body (both together)."""
        return self.rolling_resistance * self.mass_kg * G * (1.0 - self.drive_load_fraction)

    @cached_property
    def resist_force_n(self) -> float:
        """Return the rolling resistance each drive wheel overcomes in a straight line."""
        return self.rolling_force_n + 0.5 * self.caster_force_n

    @cached_property
    def ke(self) -> float:
        """Return the motor constant (V s/rad = N m/A) that makes top_speed_mps the top speed.

        At the top speed the armature current carries the rolling resistance and the drive
        train's friction through the gear: ``V = R I + ke w_m`` with
        ``I = (I0 + F_rr r / (N ke)) / eta``, a quadratic in ``ke``.
        """
        n, eta, r = self.gear_ratio, self.gear_efficiency, self.wheel_radius_m
        wm = self.max_motor_rad_s
        a = self.supply_v - self.motor_resistance_ohm * self.no_load_current_a / eta
        c = self.motor_resistance_ohm * self.resist_force_n * r / (n * eta)
        disc = a * a - 4.0 * wm * c
        if disc <= 0.0 or a <= 0.0:
            raise ValueError('world.robot: the supply cannot overcome the friction at any '
                             'speed (raise supply_v or lower motor_resistance_ohm, '
                             'no_load_current_a, rolling_resistance)')
        return (a + math.sqrt(disc)) / (2.0 * wm)

    @cached_property
    def wheel_inertia_total(self) -> float:
        """Return one wheel's inertia with its rotor reflected through the gear."""
        return self.wheel_inertia_kgm2 + self.gear_ratio ** 2 * self.rotor_inertia_kgm2

    @cached_property
    def friction_torque_nm(self) -> float:
        """Return the drive train's dry friction at the wheel (motor no-load current)."""
        return self.gear_ratio * self.ke * self.no_load_current_a

    @property
    def breakaway_torque_nm(self) -> float:
        """Return the drive train's friction at rest (what a start must exceed), at the wheel."""
        return self.breakaway_friction * self.friction_torque_nm

    @property
    def equivalent_mass_kg(self) -> float:
        """Return the mass the two wheels' torques accelerate in a straight line."""
        return self.mass_kg + 2.0 * self.wheel_inertia_total / self.wheel_radius_m ** 2

    @property
    def motor_tau_s(self) -> float:
        """Return the drive's time constant in a straight line below the current limit.

        The back-EMF damping ``N^2 kt ke eta / R`` at each wheel against half the equivalent
        mass: the first-order lag the PI (and ``calibrate``) see.
        """
        c = self.gear_ratio ** 2 * self.ke ** 2 * self.gear_efficiency / self.motor_resistance_ohm
        return 0.5 * self.equivalent_mass_kg * self.wheel_radius_m ** 2 / c

    @property
    def coast_decel_mps2(self) -> float:
        """Return the deceleration with the enable off (friction alone: coasting)."""
        r = self.wheel_radius_m
        return (2.0 * (self.rolling_force_n + self.friction_torque_nm / r)
                + self.caster_force_n) / self.equivalent_mass_kg

    def dynamic_brake_decel_mps2(self, v: float) -> float:
        """Return the deceleration at straight speed ``v`` with the enable off (dynamic brake).

        The shorted armature's current ``ke w_m / (R + R_db)`` brakes each wheel with
        ``N ke I / eta``, on top of the friction; without a brake resistor: coasting.
        """
        if self.dynamic_brake_ohm is None:
            return self.coast_decel_mps2
        n, r, ke = self.gear_ratio, self.wheel_radius_m, self.ke
        cur = ke * n * abs(v) / r / (self.motor_resistance_ohm + self.dynamic_brake_ohm)
        brake = 2.0 * n * ke * cur / self.gear_efficiency / r
        return min(brake / self.equivalent_mass_kg + self.coast_decel_mps2,
                   self.traction_decel_mps2)

    @property
    def traction_decel_mps2(self) -> float:
        """Return the hardest the tyres can stop the robot (static friction, both wheels)."""
        return self.mu * G * self.drive_load_fraction

    def braking_decel_mps2(self, enabled: bool = True) -> float:
        """Return the peak deceleration of a zero (or full reverse) command from speed.

        Enabled: the current limit's braking torque (``N kt I_max / eta`` at each wheel) plus
        friction, capped by traction; disabled: friction only (coasting).
        """
        if not enabled:
            return self.coast_decel_mps2
        r = self.wheel_radius_m
        brake = self.gear_ratio * self.ke * self.amp_current_limit_a / self.gear_efficiency
        total = 2.0 * (brake / r + self.rolling_force_n + self.friction_torque_nm / r)
        return min((total + self.caster_force_n) / self.equivalent_mass_kg,
                   self.traction_decel_mps2)

    def amp_offset_v(self, side: int) -> float:
        """Return one amplifier's input offset in armature volts."""
        return self.amp_offset_right_v if side == RIGHT else self.amp_offset_left_v

    def effective_volts(self, side: int, volts: float) -> float:
        """Return the armature voltage the amplifier gives for DAC volts (offset, dead band)."""
        u = volts + self.amp_offset_v(side)
        return math.copysign(max(abs(u) - self.deadband_v, 0.0), u)

    def steady_wheel_speed(self, volts: float, side: int = LEFT) -> float:
        """Return the steady wheel speed (rad/s) of a straight run with both wheels at ``volts``.

        Below the friction nothing turns; above it the speed line is shifted by the current
        the friction needs (the DC motor's torque-speed line at that load).
        """
        u = self.effective_volts(side, volts)
        n, eta, r, ke = self.gear_ratio, self.gear_efficiency, self.wheel_radius_m, self.ke
        load_i = (self.no_load_current_a + self.resist_force_n * r / (n * ke)) / eta
        excess = abs(u) - self.motor_resistance_ohm * load_i
        if excess <= 0.0:
            return 0.0
        return math.copysign(excess / ke / n, u)

    @classmethod
    def field_names(cls) -> list[str]:
        """Return the names ``world.robot`` accepts."""
        return list(ROBOT_FIELDS)


# The table of ``world.robot``, derived from the declaration above (validation, docs).
ROBOT_FIELDS: dict[str, Field] = table(RobotParams)
# The configuration's values the simulated robot defaults to (RobotParams.from_control).
_BODY_KEYS = ('length', 'width')
_CONTROL_KEYS = ('wheel_radius', 'track_width', 'gear_ratio', 'full_scale_wheel_speed')


class DriveState:
    """The moving state of the drive: wheel speeds, body speeds, which tyres slip."""

    __slots__ = ('wheel', 'v', 'w', 'slipping', 'current', 'blocked')

    def __init__(self) -> None:
        self.wheel = [0.0, 0.0]           # rad/s, positive = forward
        self.v = 0.0                      # body, m/s
        self.w = 0.0                      # body yaw rate, rad/s
        self.slipping = [False, False]
        self.current = [0.0, 0.0]         # armature current, A
        self.blocked = [False, False]     # a wheel mechanically blocked (fault injection)

    def contact_speed(self, side: int, half_track: float) -> float:
        """Return the ground speed of one wheel's contact point along the heading."""
        return self.v + (half_track if side == RIGHT else -half_track) * self.w


def _sign(x: float) -> float:
    return 1.0 if x > 0.0 else -1.0 if x < 0.0 else 0.0


def step_drive(rob: RobotParams, st: DriveState, volts: tuple[float, float], enabled: bool,
               dt: float, mu: tuple[float, float, float, float] | None = None,
               grade_n: float = 0.0) -> None:
    """Advance the drive by ``dt`` seconds (in place).

    ``volts``: each amplifier's input in armature volts; ``enabled``: the amplifier enable;
    ``mu``: (static left, static right, kinetic left, kinetic right) under each tyre now
    (a wet patch under one wheel); None: ``rob.mu`` / ``rob.mu_kinetic`` under both;
    ``grade_n``: gravity's pull on the body along its heading on a slope (N, + forward;
    m4k_drivers.floor.grade_force), which the tyres' forces solve against like any other.
    """
    mu_s = (rob.mu, rob.mu) if mu is None else (mu[0], mu[1])
    mu_k = (rob.mu_kinetic, rob.mu_kinetic) if mu is None else (mu[2], mu[3])
    n, eta, r = rob.gear_ratio, rob.gear_efficiency, rob.wheel_radius_m
    ke, res = rob.ke, rob.motor_resistance_ohm
    s = rob.track_width_m / 2.0
    m, iz = rob.mass_kg, rob.yaw_inertia_kgm2
    jw = rob.wheel_inertia_total
    load = rob.wheel_load_n
    # The casters' rolling resistance acts on the body (explicitly: a small dry force).
    if st.v != 0.0 and rob.caster_force_n > 0.0:
        dv = rob.caster_force_n * dt / m
        st.v = st.v - dv if st.v > dv else st.v + dv if st.v < -dv else 0.0
    fric_max = rob.friction_torque_nm + rob.rolling_force_n * r    # dry friction at the wheel
    # at rest the drive train sticks harder than it runs (break-away); rolling resistance not
    fric_rest = rob.breakaway_torque_nm + rob.rolling_force_n * r
    a_free = [0.0, 0.0]           # wheel torque but for traction, at the present speed
    drive = [0.0, 0.0]            # the motor's torque at the wheel
    p = [0.0, 0.0]                # dt / (J + c dt): implicit in the back-EMF damping
    for i in (LEFT, RIGHT):
        wi = st.wheel[i]
        c = 0.0
        if enabled:
            u = rob.effective_volts(i, volts[i])
            cur = (u - ke * n * wi) / res
            if abs(cur) > rob.amp_current_limit_a:
                cur = math.copysign(rob.amp_current_limit_a, cur)
            else:
                c = n * n * ke * ke / res       # d(torque)/d(speed) at the wheel, below the limit
        elif rob.dynamic_brake_ohm is not None:
            # enable off: the armature shorted through the brake resistor (no current limit:
            # the resistor sets the current), braking on the back-EMF alone
            rt = res + rob.dynamic_brake_ohm
            cur = -ke * n * wi / rt
            c = n * n * ke * ke / rt
        else:
            cur = 0.0
        st.current[i] = cur
        motoring = cur * wi >= 0.0
        gain = n * (eta if motoring else 1.0 / eta)
        tau = drive[i] = gain * ke * cur
        c *= eta if motoring else 1.0 / eta
        # Dry friction opposes the rotation; at a standstill it holds up to its maximum.
        if wi != 0.0:
            tau -= math.copysign(fric_max, wi)
        else:
            tau -= max(-fric_rest, min(fric_rest, tau))
        a_free[i] = tau
        p[i] = dt / (jw + c * dt)
    c_wheel = [dt / pi - jw for pi in p]      # the damping each p was built with, * dt
    # A wheel at rest whose drive is below its dry friction is held by that friction (like a
    # blocked one: zero speed) as long as the torque needed to hold it stays below it too.
    held = [st.blocked[i] or (st.wheel[i] == 0.0 and abs(drive[i]) <= fric_rest)
            for i in (LEFT, RIGHT)]
    for i in (LEFT, RIGHT):
        if held[i]:
            st.wheel[i] = 0.0
            a_free[i] = p[i] = 0.0
    alpha, beta = dt / m, dt * s * s / iz
    pull = grade_n * dt / m        # the slope's change of the body's speed over this step
    slip0 = [r * st.wheel[i] - st.contact_speed(i, s) - pull for i in (LEFT, RIGHT)]
    kin = [_sign(slip0[i]) for i in (LEFT, RIGHT)]     # direction of a sliding tyre's force
    stuck = [not st.slipping[i] for i in (LEFT, RIGHT)]
    x = alpha - beta
    f = [0.0, 0.0]
    for _ in range(5):
        e = [r * st.wheel[i] + r * p[i] * a_free[i] - st.contact_speed(i, s) - pull
             for i in (LEFT, RIGHT)]
        d = [r * r * p[i] + alpha + beta for i in (LEFT, RIGHT)]
        for i in (LEFT, RIGHT):
            if not stuck[i]:
                f[i] = mu_k[i] * load * kin[i]
        if stuck[LEFT] and stuck[RIGHT]:
            det = d[0] * d[1] - x * x
            f[0] = (e[0] * d[1] - x * e[1]) / det
            f[1] = (d[0] * e[1] - x * e[0]) / det
        elif stuck[LEFT]:
            f[0] = (e[0] - x * f[1]) / d[0]
        elif stuck[RIGHT]:
            f[1] = (e[1] - x * f[0]) / d[1]
        over = [i for i in (LEFT, RIGHT) if stuck[i] and abs(f[i]) > mu_s[i] * load]
        for i in over:              # beyond static friction: the tyre slides from now on
            stuck[i] = False
            st.slipping[i] = True
            kin[i] = _sign(f[i])
        # A held wheel the ground turns harder than its friction holds starts to roll.
        freed = [i for i in (LEFT, RIGHT) if held[i] and not st.blocked[i] and stuck[i]
                 and abs(drive[i] - f[i] * r) > fric_rest]
        for i in freed:
            held[i] = False
            p[i] = dt / (jw + c_wheel[i])
            a_free[i] = drive[i] - math.copysign(fric_max, drive[i] - f[i] * r)   # now running
        if not over and not freed:
            break
    old = list(st.wheel)
    for i in (LEFT, RIGHT):
        st.wheel[i] = old[i] + p[i] * (a_free[i] - f[i] * r)
    st.v += alpha * (f[0] + f[1]) + pull
    st.w += dt * s * (f[1] - f[0]) / iz
    for i in (LEFT, RIGHT):
        # A sliding tyre grips again when its slip has run out (reached or crossed zero).
        if st.slipping[i]:
            after = r * st.wheel[i] - st.contact_speed(i, s)
            if abs(after) < 1e-4 or _sign(after) != kin[i]:
                st.slipping[i] = False
        # Dry friction stops a wheel: crossing zero with less drive than friction is a stop.
        elif (old[i] != 0.0 and _sign(st.wheel[i]) != _sign(old[i])
              and abs(drive[i]) <= fric_rest):
            st.wheel[i] = 0.0
    if not any(st.slipping):      # gripping: the body goes where the wheels roll
        st.v = 0.5 * r * (st.wheel[0] + st.wheel[1])
        st.w = r * (st.wheel[1] - st.wheel[0]) / (2.0 * s)


def parse_robot(rob: Any, base: RobotParams, where: str,
                error: Callable[[str, str], Exception] = WorldConfigError) -> RobotParams:
    """Return ``base`` with the ``world.robot`` keys of ``rob`` applied (errors name the key).

    Each value is judged by its field's declaration (:data:`ROBOT_FIELDS`); what involves
    several fields is checked here: the offsets within the supply, ``mu_kinetic <= mu``, and a
    supply that overcomes the friction. ``error(path, message)`` builds the exception.
    """
    if not isinstance(rob, Mapping):
        raise error(where, f'expected a mapping of {", ".join(ROBOT_FIELDS)}, got {rob!r}')
    check_keys(rob, ROBOT_FIELDS, where, error)
    vals = {k: ROBOT_FIELDS[k].validate(f'{where}.{k}', v, error) for k, v in rob.items()}
    out = replace(base, **vals)
    for k in ('amp_offset_left_v', 'amp_offset_right_v'):
        if k in vals and abs(vals[k]) >= out.supply_v:
            raise error(f'{where}.{k}', f'must be within the supply (+/-{out.supply_v} V), '
                        f'got {vals[k]!r}')
    if out.mu_kinetic > out.mu:
        raise error(f'{where}.mu_kinetic', f'must be <= mu ({out.mu!r}), got {out.mu_kinetic!r}')
    try:
        _ = out.ke                    # the supply must overcome the friction
    except ValueError as exc:
        raise error(where, str(exc).partition(': ')[2]) from None
    return out
