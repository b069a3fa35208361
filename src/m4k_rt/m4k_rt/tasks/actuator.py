"""Actuator task body (10 ms): velocity command -> wheel DAC codes; encoders -> odometry.

Ports: ``cmd`` (bridge: VELOCITY_CMD in, ODOMETRY out) and ``motor`` (driver host motor
handler: WHEEL_CMD out, ENCODERS and DEVICE_STATUS in).

One-cycle pipeline. The motor handler answers each WHEEL_CMD with one ENCODERS sample taken
when it applied the command. The body never waits for that reply inside its cycle (a wait
would put the driver host's scheduling into the highest-priority task's response time);
instead cycle k runs:

1. drain ``motor``: the ENCODERS replying to WHEEL_CMD k-1 (sent last cycle; the driver had a
   whole period to answer) -> odometry, wheel speeds by differencing the *driver's* stamps,
   so how late the reply is read does not distort the speeds;
2. drain ``cmd`` in arrival order: VELOCITY_CMD (the latest wins), E_STOP (latch / release,
   effective in this cycle's step; a command after a release ends its hold) and ODOM_RESET
   (pose zeroed now, acknowledged with an ODOM_RESET carrying the same id on ``cmd``), SET_POSE
   likewise (pose set to the request's x, y, yaw; acknowledged with the pose as set);
3. guard cap from the sonar/lrf readings in the shared state, then the controller's step
   (supervision, limits, IK, PI on the feedback of step 1);
4. send WHEEL_CMD k; every ``odom_every_n``-th cycle send ODOMETRY and APPLIED_VELOCITY (the
   body velocity this cycle applies: after limits, guard, e-stop ramp and timeout) on ``cmd``.

So the PI acts on feedback one period old (a pure one-sample delay, well inside the motor's
80 ms lag), and the response time of the task stays a few tens of microseconds. WHEEL_CMD is
sent every cycle even when the motor is stale (zero, disabled): the reply to it is how the
controller notices the motor is back, and it keeps the driver's watchdog fed.

ODOMETRY flags are the OR of the controller's flags over the cycles since the last ODOMETRY,
so a one-cycle event (a guard stop) is not lost to the 5:1 decimation.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
import os
import sys
import time
from typing import Any, Callable, Mapping

from m4k_rt.config import shipped_period_s, TaskConfig
from m4k_rt.control.base import BaseController, MODE_FAULT
from m4k_rt.control.dac import DAC_ZERO
from m4k_rt.control.footprint import half_width_of
from m4k_rt.control.guard import (
    body_front,
    CollisionGuard,
    front_offset,
    sensor_x,
    speed_for_distance,
)
from m4k_rt.control.memory import ObstacleMemory
from m4k_rt.control.params import control_params, ControlParams
from m4k_rt.control.reaction import reaction
from m4k_rt.control.sightings import SightingFeed
from m4k_rt.control.turnguard import make_turn_guard, turn_reach
from m4k_rt.estop_request import read_request, request_path, state_dir
from m4k_rt.protocol import Kind
from m4k_rt.tasks.interfaces import CycleContext, RtPort
from m4k_rt.tasks.portio import PortReader, PortWriter
from m4k_rt.tasks.state import robot_state, RobotState

__all__ = ['ActuatorBody', 'control_section', 'GuardPlan', 'guard_plan', 'imu_x_axis',
           'imu_z_axis', 'make_actuator', 'make_guard', 'TEST_HOOKS_ENV', 'track_slope',
           'WEAKEN_ENV']

# Test-only: weaken the guard by this many metres (the scenario suite's negative control).
# Read once when the actuator is built; refused unless TEST_HOOKS_ENV is '1'.
TEST_HOOKS_ENV = 'M4K_TEST_HOOKS'
WEAKEN_ENV = 'M4K_TEST_GUARD_WEAKEN_M'

_VELOCITY_CMD = Kind.VELOCITY_CMD
_ENCODERS = Kind.ENCODERS
_DEVICE_STATUS = Kind.DEVICE_STATUS
_HOST_DROPS = Kind.HOST_DROPS
_WHEEL_CMD = Kind.WHEEL_CMD
_ODOMETRY = Kind.ODOMETRY
_E_STOP = Kind.E_STOP
_ODOM_RESET = Kind.ODOM_RESET
_SET_POSE = Kind.SET_POSE
_APPLIED = Kind.APPLIED_VELOCITY
_FAULT_RESET = Kind.FAULT_RESET


@dataclass(frozen=True)
class GuardPlan:
    """What the guard's configuration implies, fixed at start-up (stated, never silent).

    ``reaction_time`` t_react (s) and ``brake_deceleration`` a_brake (m/s^2) of the stop zone
    d(v) = v t_react + v^2 / (2 a_brake) + ``margin``; ``visible`` (m) how far ahead of the
    front face the guard's full-face sensor sees (laser range less its mount offset; the
    sonar's when the laser is not used; 0: no sensor); ``sensor_speed`` the speed whose d(v)
    is ``visible`` (inf: unguarded); ``top_speed`` the forward cap actually applied (the
    smaller of that and linear.max_velocity); ``reverse_creep`` the reverse cap (inf when the
    guard is off); ``weaken`` the test-only weakening (m).
    """

    enabled: bool
    reaction_time: float
    brake_deceleration: float
    margin: float
    visible: float
    sensor: str
    sensor_speed: float
    top_speed: float
    reverse_creep: float
    weaken: float
    slow_down: bool = True
    supervision: bool = True
    reaction_parts: str = ''      # t_react in its three parts (m4k_rt.control.reaction)
    unknown_speed: float = math.inf
    turn_reach: float = 0.0       # m: the turn guard watches points this near (0: none)

    def line(self) -> str:
        """Return the start-up statement of the caps (one line)."""
        if not self.enabled:
            return ('collision guard DISABLED (control.guard.enabled false): no forward or '
                    'reverse speed cap, nothing stops the robot for what its sensors see')
        text = ('collision guard: top forward speed {:.2f} m/s ({}: d(v) = v * {:.3f} s + '
                'v^2 / (2 * {:.2f} m/s^2) + {:.2f} m reaches the {:.2f} m the {} sees ahead of '
                'the front face at {:.2f} m/s); reverse capped to {:.2f} m/s (no rear sensor)'
                ).format(self.top_speed,
                         'the configured linear.max_velocity' if self.top_speed <
                         self.sensor_speed else 'CAPPED BY THE SENSORS',
                         self.reaction_time, self.brake_deceleration, self.margin,
                         self.visible, self.sensor, self.sensor_speed, self.reverse_creep)
        if self.reaction_parts:
            text += '; t_react ' + self.reaction_parts
        if self.unknown_speed < self.top_speed:
            text += ('; a laser error code in the corridor (unknown) caps it to {:.2f} m/s (the '
                     'sonar alone covers d(v) across the corridor)'.format(self.unknown_speed))
        if self.turn_reach > 0.0:
            text += ('; turns capped so the outline + lateral margin stops short of what the '
                     'laser saw within {:.3f} m of the axle (rear 120 deg blind)'
                     .format(self.turn_reach))
        if not self.supervision:
            text += '; wheel supervision OFF (control.supervision.enabled false)'
        if self.weaken:
            text += ('; TEST HOOK: guard WEAKENED by {:.3f} m ({}) -- never on a real robot'
                     .format(self.weaken, WEAKEN_ENV))
        return text


def _task_period(shared: Any, body: str) -> float:
    cfg = getattr(shared, 'config', None)
    for t in getattr(cfg, 'tasks', None) or ():
        if getattr(t, 'body', None) == body or getattr(t, 'name', None) == body:
            return float(t.period_ns) * 1e-9
    # Not a task of this configuration (a bare rig, or the task disabled): the period the
    # shipped configuration declares for it (config/m4k.yaml tasks:), never a second number.
    return shipped_period_s(body)


def test_weaken(environ: Mapping[str, str] = os.environ) -> float:
    """Return the test-only guard weakening from the environment (0 when unset).

    Raise ValueError when it is set without ``M4K_TEST_HOOKS=1`` or is not a number >= 0.
    """
    raw = environ.get(WEAKEN_ENV, '').strip()
    if not raw:
        return 0.0
    if environ.get(TEST_HOOKS_ENV) != '1':
        raise ValueError('{}={!r} refused: test hooks are off (set {}=1 in a test, never on a '
                         'robot)'.format(WEAKEN_ENV, raw, TEST_HOOKS_ENV))
    try:
        value = float(raw)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value >= 0.0):
        raise ValueError('{} must be a number of metres >= 0, got {!r}'.format(WEAKEN_ENV, raw))
    return value


def guard_plan(params: ControlParams, actuator_period: float, shared: Any = None,
               robot: Any = None, weaken: float = 0.0) -> GuardPlan:
    """Compute t_react, the top forward speed and the reverse creep from the configuration."""
    g = params.guard
    if g.use_laser:
        sensor, period = 'laser', _task_period(shared, 'lrf')
        visible = g.laser_range - front_offset(robot, 'laser')
    elif g.use_sonar:
        sensor, period = 'sonar', _task_period(shared, 'sonar')
        visible = g.sonar_range - front_offset(robot, 'sonar')
    else:
        sensor, period, visible = 'no sensor', 0.0, 0.0
    # sensor part + RT part + actuation part, always (calibrate writes the last one only)
    r = reaction(g, sensor if sensor != 'no sensor' else 'sonar', period, actuator_period,
                 timeouts=True)
    t_react = r.total
    if not g.enabled:
        return GuardPlan(False, t_react, g.brake_deceleration, g.stop_distance, visible, sensor,
                         math.inf, params.linear.max_velocity, math.inf, weaken, False,
                         params.supervision.enabled)
    sensor_speed = speed_for_distance(max(visible, 0.0), t_react, g.brake_deceleration,
                                      g.stop_distance)
    return GuardPlan(True, t_react, g.brake_deceleration, g.stop_distance, visible, sensor,
                     sensor_speed, min(params.linear.max_velocity, sensor_speed),
                     g.reverse_creep_speed, weaken, g.slow_down, params.supervision.enabled,
                     r.text(), unknown_speed(params, robot, t_react),
                     turn_reach(params, robot) if g.use_laser else 0.0)


def corridor_half_width(params: ControlParams, robot: Any) -> float:
    """Return the guard's corridor half width: the robot's outline's + the lateral margin (m).

    The laser's corridor (lrf task), the memory's and the sonar's coverage all take this one.
    """
    return half_width_of(robot, params.track_width) + params.guard.lateral_margin


def sonar_full_width(params: ControlParams, robot: Any) -> float:
    """Return how far ahead of the front face the sonar's cone spans the whole corridor (m)."""
    return (corridor_half_width(params, robot) / math.tan(params.guard.sonar_cone / 2.0)
            - front_offset(robot, 'sonar'))


def unknown_speed(params: ControlParams, robot: Any, t_react: float) -> float:
    """Return the forward cap while the laser reports an error code in the corridor (m/s).

    An error code measured nothing there (a black surface: docs/sensor-outcomes.md), so only
    the sonar can see it: the cap is the speed whose stop zone d(v) the sonar's cone covers
    across the whole corridor (and within its reach). Without the sonar, nothing sees what
    the laser cannot: the reverse creep.
    """
    g = params.guard
    if not g.use_sonar:
        return g.reverse_creep_speed
    reach = g.sonar_range - front_offset(robot, 'sonar')
    full = min(sonar_full_width(params, robot), reach)
    v = speed_for_distance(max(full, 0.0), t_react, g.brake_deceleration, g.stop_distance)
    return v if v > g.slow_floor else g.slow_floor


def make_guard(params: ControlParams, plan: GuardPlan | None = None) -> CollisionGuard:
    """Build the collision guard from the control parameters (and the start-up plan)."""
    g = params.guard
    if plan is None:
        plan = guard_plan(params, _task_period(None, 'actuator'))
    return CollisionGuard(enabled=g.enabled, stop_distance=g.stop_distance,
                          release_margin=g.release_margin, slow_down=g.slow_down,
                          slow_deceleration=(params.linear.max_acceleration
                                             if params.linear.max_deceleration is None
                                             else params.linear.max_deceleration),
                          slow_floor=g.slow_floor, reaction_time=plan.reaction_time,
                          brake_deceleration=g.brake_deceleration,
                          use_sonar=g.use_sonar, use_laser=g.use_laser,
                          sonar_timeout=g.sonar_timeout, laser_timeout=g.laser_timeout,
                          stale_policy=g.stale_policy, weaken=plan.weaken,
                          unknown_speed=plan.unknown_speed)


def make_feed(params: ControlParams, robot: Any) -> SightingFeed:
    """Build the guard's obstacle memory and the feed that fills it (the robot's geometry)."""
    g = params.guard
    sx = sensor_x(robot, 'sonar')
    front = body_front(robot)
    if front <= 0.0:
        front = sx       # a bare test config: the face where the sonar is
    return SightingFeed(ObstacleMemory(g.memory_points), sonar_x=sx,
                        laser_x=sensor_x(robot, 'laser'), front_x=front,
                        half_width=corridor_half_width(params, robot),
                        sonar_half_angle=g.sonar_cone / 2.0,
                        sonar_reach=g.sonar_range, near=ObstacleMemory(g.memory_points),
                        near_reach=turn_reach(params, robot))


class ActuatorBody:
    """The actuator task's per-cycle body (see the module docstring for the pipeline)."""

    def __init__(self, cmd_sock: RtPort, motor_sock: RtPort, state: RobotState,
                 params: ControlParams, period_s: float,
                 clock: Callable[[], int] = time.monotonic_ns,
                 plan: GuardPlan | None = None, imu_z: float = 1.0,
                 robot: Any = None,
                 imu_x: tuple[float, float, float] = (1.0, 0.0, 0.0)) -> None:
        self.params = params
        self.state = state
        self.ctl = BaseController(params, period_s)
        self.plan = plan if plan is not None else guard_plan(params, period_s, None, robot)
        self.guard = make_guard(params, self.plan)
        self.feed = make_feed(params, robot)
        self.turn = make_turn_guard(params, robot, self.plan.reaction_time)
        # the turn guard's points: the laser's within reach (the corridor memory's are ahead of
        # the face, beyond any turn's reach once the forward guard has held the robot off them)
        self._memories = (self.feed.near,)
        self._use_sonar = params.guard.use_sonar
        self._use_laser = params.guard.use_laser
        if self.plan.enabled:
            self.ctl.forward_limit = self.plan.top_speed
            self.ctl.reverse_limit = self.plan.reverse_creep
        state.set_guard_plan(self.plan)
        state.fault_trace = self.ctl.supervisor.trace
        self._cmd_in = PortReader(cmd_sock)
        self._motor_in = PortReader(motor_sock)
        self._cmd_out = PortWriter(cmd_sock)
        self._motor_out = PortWriter(motor_sock)
        self._clock = clock
        self._imu_z = imu_z        # base_link z seen in imu_link (mount): gyro z -> yaw rate
        self._imu_x = imu_x        # base_link x in imu_link: orientation -> the track's slope
        self._odom_every = params.odom_every_n
        self._vmax = params.linear.max_velocity
        self._odom_countdown = params.odom_every_n
        self._odom_flags = 0
        self.cycles = 0
        self.unexpected = 0          # valid datagrams of a kind this port does not carry
        self.failed_ns = 0           # when a cycle first raised (0: never); latched
        self.failed_cycles = 0       # cycles run in that failed state

    @property
    def counters(self) -> Mapping[str, int]:
        """Return a snapshot of the body's counters (NRT use)."""
        c = self.ctl
        return {'cycles': self.cycles, 'commands': c.commands,
                'encoder_samples': c.encoder_samples, 'encoder_faults': c.encoder_faults,
                'unexpected': self.unexpected, 'wheel_cmd_sent': self._motor_out.sent,
                'wheel_cmd_dropped': self._motor_out.dropped, 'odom_sent': self._cmd_out.sent,
                'odom_dropped': self._cmd_out.dropped,
                'guard_activations': self.guard.activations,
                'memory_points': self.feed.memory.used,
                'memory_added': self.feed.memory.added,
                'memory_freed': self.feed.memory.freed,
                'memory_evicted': self.feed.memory.evicted,
                'near_points': self.feed.near.used, 'turn_stops': self.turn.stops,
                'e_stop_engagements': c.estop.engagements, 'e_stop_releases': c.estop.releases,
                'commands_blocked': c.commands_blocked, 'pose_resets': c.pose_resets,
                'motor_faults': c.supervisor.faults, 'fault_resets': c.fault_resets,
                'failed_cycles': self.failed_cycles}

    def __call__(self, ctx: CycleContext | None = None) -> None:
        """Run one actuator cycle (``ctx.t_start`` is the cycle's start time when given).

        A cycle that raises latches the body failed: the outputs computed so far cannot be
        trusted, nor the state the next cycle would start from. From that cycle on, without
        touching the controller, it sends the zero word with the enable on (the amplifier
        brakes on the back-EMF) for the braking time bound, then with the enable off -- the
        category-1 stop of a fault (docs/safety.md) -- reports mode ``fault``, and drains its
        ports. Only a restart of rt_core ends it. The exception is raised on to the task, which
        counts it and names it in TASK_HEALTH (``body_errors``, ``last_error``).
        """
        if self.failed_ns:
            self._failed_cycle(ctx)
            return
        try:
            self._cycle(ctx)
        except Exception:
            now = ctx.t_start if ctx is not None else self._clock()
            self.failed_ns = now or 1
            self._failed_cycle(ctx)
            raise

    def _failed_cycle(self, ctx: CycleContext | None) -> None:
        """Brake, then cut the enable; never the controller (its state is suspect)."""
        now = ctx.t_start if ctx is not None else self._clock()
        enable = 1 if now - self.failed_ns < self.ctl.fault_brake_ns else 0
        self._motor_out.send(_WHEEL_CMD, now, DAC_ZERO, DAC_ZERO, enable)
        self._motor_in.discard()
        self._cmd_in.discard()
        self.state.mode = MODE_FAULT
        self.failed_cycles += 1

    def _cycle(self, ctx: CycleContext | None) -> None:
        now = ctx.t_start if ctx is not None else self._clock()
        ctl = self.ctl
        state = self.state
        # 1. encoders replying to last cycle's WHEEL_CMD
        reader = self._motor_in
        reader.start_cycle()
        while (got := reader.next()) is not None:
            hdr, msg = got
            if hdr.kind == _ENCODERS:
                ctl.encoders(msg.left_angle, msg.right_angle, hdr.stamp_ns, now, msg.status,
                             hdr.seq)
            elif hdr.kind == _DEVICE_STATUS:
                state.record_device_status('motor', msg, now)
            elif hdr.kind == _HOST_DROPS:
                state.record_host_drops('motor', msg, now)
            else:
                self.unexpected += 1
        odom = ctl.odom
        feed = self.feed
        feed.history.record(now, odom.x, odom.y, odom.yaw)
        resets = ctl.pose_resets
        before = (odom.x, odom.y, odom.yaw)
        # 2. velocity commands, e-stop and pose reset, in the order they arrived
        reader = self._cmd_in
        reader.start_cycle()
        latest = None
        while (got := reader.next()) is not None:
            hdr, msg = got
            kind = hdr.kind
            if kind == _VELOCITY_CMD:
                latest = msg
            elif kind == _E_STOP:
                # Commands before the request are taken before it, so a release only counts
                # commands that came after it as fresh.
                if latest is not None:
                    ctl.command(latest.linear_x, latest.angular_z, now)
                    latest = None
                ctl.e_stop(msg.engage == 1)
            elif kind == _ODOM_RESET:
                ctl.reset_pose()
                self._cmd_out.send(_ODOM_RESET, now, msg.request_id)
            elif kind == _FAULT_RESET:
                # Commands before the reset are taken before it (they stay held).
                if latest is not None:
                    ctl.command(latest.linear_x, latest.angular_z, now)
                    latest = None
                cleared = ctl.reset_fault()
                self._cmd_out.send(_FAULT_RESET, now, msg.request_id, 1 if cleared else 0)
            elif kind == _SET_POSE:
                ctl.reset_pose(msg.x, msg.y, msg.yaw)
                o = ctl.odom
                self._cmd_out.send(_SET_POSE, now, msg.request_id, o.x, o.y, o.yaw)
            else:
                self.unexpected += 1
        if latest is not None:
            ctl.command(latest.linear_x, latest.angular_z, now)
        if ctl.pose_resets != resets:
            # the odometry frame moved under the robot: carry the memory into the new one
            feed.rebase(before, (odom.x, odom.y, odom.yaw))
        # 3. the gyro's yaw rate for the wheel supervision's cross-check; the guard (memory
        # fed first) + control
        imu_rx = state.imu_rx_ns
        ctl.imu(state.imu_gz * self._imu_z, imu_rx, state.imu_stamp_ns,
                track_slope(state.imu_qx, state.imu_qy, state.imu_qz, state.imu_qw,
                            self._imu_x))
        guard = self.guard
        unknown = False
        if self._use_sonar:
            feed.take_sonar(state.sonar_sighting)
        if self._use_laser:
            scan = state.laser_sighting
            feed.take_laser(scan)
            unknown = scan is not None and scan.unknown
        memory_min = feed.nearest(odom.x, odom.y, odom.yaw)
        speed = ctl.v if ctl.v > odom.v else odom.v
        if speed > 0.0:
            # on an arc: the memory's gaps along the arc of the motion and of the command too
            g = feed.nearest_on_arcs(odom.v, odom.w, ctl.cmd_linear, ctl.cmd_angular, odom.x,
                                     odom.y, odom.yaw, guard.stop_distance_at(speed))
            if g < memory_min:
                memory_min = g
        cap = guard.evaluate(now, self._vmax, state.sonar_range, state.sonar_rx_ns,
                             state.laser_front_min, state.laser_rx_ns, speed, memory_min,
                             unknown)
        # the turn guard, whenever a turn is asked for or under way
        turn = self.turn
        w_now = ctl.w if abs(ctl.w) >= abs(odom.w) else odom.w
        if turn.enabled and (w_now != 0.0 or ctl.cmd_angular != 0.0):
            turn.evaluate(self._memories, odom.x, odom.y, odom.yaw, w_now,
                          guard.laser_stale and guard.stale_policy == 'stop')
        ctl.step(now, cap, guard.active, turn.ccw_cap, turn.cw_cap)
        # 4. outputs
        self._motor_out.send(_WHEEL_CMD, now, ctl.left_code, ctl.right_code, ctl.enable)
        odom = ctl.odom
        flags = self._odom_flags | ctl.flags
        self._odom_countdown -= 1
        if self._odom_countdown <= 0:
            self._odom_countdown = self._odom_every
            self._cmd_out.send(_ODOMETRY, now, odom.x, odom.y, odom.yaw, odom.v, odom.w,
                               odom.left_speed, odom.right_speed, odom.left_position,
                               odom.right_position, flags)
            self._cmd_out.send(_APPLIED, now, ctl.v, ctl.w)
            flags = 0
        self._odom_flags = flags
        state.odom_flags = ctl.flags
        state.v = odom.v
        state.w = odom.w
        state.x = odom.x
        state.y = odom.y
        state.yaw = odom.yaw
        state.guard_active = guard.active
        state.guard_trip_distance = guard.trip_distance
        sup = ctl.supervisor
        state.motor_fault_cause = sup.cause
        state.motor_faults = sup.faults
        state.guard_slowing = guard.slowing
        state.estop_open = ctl.estop_open
        state.e_stop_engaged = ctl.estop.engaged
        state.mode = ctl.mode
        self.cycles += 1
        state.actuator_cycles = self.cycles


def control_section(task: TaskConfig, shared: Any) -> Any:
    """Find the raw ``control:`` section: task params, then the shared config, else None.

    The section is returned as parsed from YAML, unvalidated: the control parameter parser
    checks it (a non-mapping is a configuration error there).
    """
    return raw_section(task, shared, 'control')


def raw_section(task: TaskConfig, shared: Any, name: str) -> Any:
    """Find the raw ``name:`` section: task params, then the shared config, else None."""
    params = getattr(task, 'params', None) or {}
    if name in params:
        return params[name]
    for holder in (shared, getattr(shared, 'config', None)):
        raw = getattr(holder, 'raw', None)
        if isinstance(raw, Mapping) and name in raw:
            return raw[name]
        if isinstance(holder, Mapping) and name in holder:
            return holder[name]
    return None


def imu_z_axis(robot: Any) -> float:
    """Return base_link's z axis seen along imu_link's z (1: mounted upright, -1: upside down).

    From ``robot.sensors.imu.pose`` (roll, pitch): the gyro's z reading times this is the
    body's yaw rate. Without a mount the IMU is taken as upright.
    """
    mount = _imu_mount(robot)
    return 1.0 if mount is None else math.cos(mount[0]) * math.cos(mount[1])


def _imu_mount(robot: Any) -> tuple[float, float, float] | None:
    """Return the IMU's mount (roll, pitch, yaw) in base_link, rad (None: none configured)."""
    try:
        pose = robot['sensors']['imu']['pose']
        return float(pose[3]), float(pose[4]), float(pose[5])
    except (KeyError, IndexError, TypeError, ValueError):
        return None


def imu_x_axis(robot: Any) -> tuple[float, float, float]:
    """Return base_link's x axis in imu_link coordinates (the mount's first row).

    From ``robot.sensors.imu.pose`` (roll, pitch, yaw; R = Rz Ry Rx): turned by the IMU's
    orientation, it is base_link's x in the world. Without a mount: (1, 0, 0).
    """
    mount = _imu_mount(robot)
    if mount is None:
        return 1.0, 0.0, 0.0
    r, p, y = mount
    cr, sr, cp, sp, cy, sy = (math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y),
                              math.sin(y))
    return cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr


def track_slope(qx: float, qy: float, qz: float, qw: float,
                x_axis: tuple[float, float, float]) -> float:
    """Return the z of base_link's x axis in the world: ``-sin(pitch)`` of the track.

    ``q``: the IMU's orientation (imu_link in the world, REP-103); ``x_axis``: base_link x in
    imu_link (:func:`imu_x_axis`). The third row of the quaternion's rotation matrix times
    it. NaN in, NaN out (no sample: no slope known).
    """
    xx, xy, xz = x_axis
    return (2.0 * (qx * qz - qw * qy) * xx + 2.0 * (qy * qz + qw * qx) * xy
            + (1.0 - 2.0 * (qx * qx + qy * qy)) * xz)


def make_actuator(task: TaskConfig, ports: Mapping[str, RtPort], shared: Any) -> ActuatorBody:
    """Build the actuator body from its task config, its ``cmd``/``motor`` ports and state."""
    params = control_params(control_section(task, shared))
    period = task.period_ns * 1e-9
    plan = guard_plan(params, period, shared, raw_section(task, shared, 'robot'), test_weaken())
    body = ActuatorBody(ports['cmd'], ports['motor'], robot_state(shared), params, period,
                        plan=plan, imu_z=imu_z_axis(raw_section(task, shared, 'robot')),
                        robot=raw_section(task, shared, 'robot'),
                        imu_x=imu_x_axis(raw_section(task, shared, 'robot')))
    # Start-up, before any loop runs: the one place the RT process may read the e-stop
    # request the bridge persisted, and write to stderr.
    lines = [plan.line()]
    runtime_dir = getattr(shared, 'runtime_dir', '')
    if runtime_dir:
        where = state_dir(runtime_dir=runtime_dir)
        persisted = read_request(where)
        if persisted.problem:
            lines.append('e-stop request: {}'.format(persisted.problem))
        if persisted.engaged:
            body.ctl.e_stop(True)
            lines.append('e-stop latch ENGAGED at start-up: {} says the e-stop is requested '
                         '(release it with e_stop false, then send a fresh command)'.format(
                             request_path(where)))
    for line in lines:
        sys.stderr.write('rt_core: {}\n'.format(line))
    sys.stderr.flush()
    return body
