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

import time
from typing import Any, Callable, Mapping

from m4k_rt.config import TaskConfig
from m4k_rt.control.base import BaseController
from m4k_rt.control.guard import CollisionGuard
from m4k_rt.control.params import control_params, ControlParams
from m4k_rt.protocol import Kind
from m4k_rt.tasks.interfaces import CycleContext, RtPort
from m4k_rt.tasks.portio import PortReader, PortWriter
from m4k_rt.tasks.state import robot_state, RobotState

__all__ = ['ActuatorBody', 'control_section', 'make_actuator', 'make_guard']

_VELOCITY_CMD = Kind.VELOCITY_CMD
_ENCODERS = Kind.ENCODERS
_DEVICE_STATUS = Kind.DEVICE_STATUS
_WHEEL_CMD = Kind.WHEEL_CMD
_ODOMETRY = Kind.ODOMETRY
_E_STOP = Kind.E_STOP
_ODOM_RESET = Kind.ODOM_RESET
_SET_POSE = Kind.SET_POSE
_APPLIED = Kind.APPLIED_VELOCITY


def make_guard(params: ControlParams) -> CollisionGuard:
    """Build the collision guard from the control parameters."""
    g = params.guard
    return CollisionGuard(enabled=g.enabled, stop_distance=g.stop_distance,
                          release_margin=g.release_margin, slow_distance=g.slow_distance,
                          use_sonar=g.use_sonar, use_laser=g.use_laser,
                          sonar_timeout=g.sonar_timeout, laser_timeout=g.laser_timeout,
                          stale_policy=g.stale_policy)


class ActuatorBody:
    """The actuator task's per-cycle body (see the module docstring for the pipeline)."""

    def __init__(self, cmd_sock: RtPort, motor_sock: RtPort, state: RobotState,
                 params: ControlParams, period_s: float,
                 clock: Callable[[], int] = time.monotonic_ns) -> None:
        self.params = params
        self.state = state
        self.ctl = BaseController(params, period_s)
        self.guard = make_guard(params)
        self._cmd_in = PortReader(cmd_sock)
        self._motor_in = PortReader(motor_sock)
        self._cmd_out = PortWriter(cmd_sock)
        self._motor_out = PortWriter(motor_sock)
        self._clock = clock
        self._odom_every = params.odom_every_n
        self._vmax = params.linear.max_velocity
        self._odom_countdown = params.odom_every_n
        self._odom_flags = 0
        self.cycles = 0
        self.unexpected = 0          # valid datagrams of a kind this port does not carry

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
                'e_stop_engagements': c.estop.engagements, 'e_stop_releases': c.estop.releases,
                'commands_blocked': c.commands_blocked, 'pose_resets': c.pose_resets}

    def __call__(self, ctx: CycleContext | None = None) -> None:
        """Run one actuator cycle (``ctx.t_start`` is the cycle's start time when given)."""
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
            else:
                self.unexpected += 1
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
            elif kind == _SET_POSE:
                ctl.reset_pose(msg.x, msg.y, msg.yaw)
                o = ctl.odom
                self._cmd_out.send(_SET_POSE, now, msg.request_id, o.x, o.y, o.yaw)
            else:
                self.unexpected += 1
        if latest is not None:
            ctl.command(latest.linear_x, latest.angular_z, now)
        # 3. guard + control
        guard = self.guard
        cap = guard.evaluate(now, self._vmax, state.sonar_range, state.sonar_rx_ns,
                             state.laser_front_min, state.laser_rx_ns)
        ctl.step(now, cap, guard.active)
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


def make_actuator(task: TaskConfig, ports: Mapping[str, RtPort], shared: Any) -> ActuatorBody:
    """Build the actuator body from its task config, its ``cmd``/``motor`` ports and state."""
    params = control_params(control_section(task, shared))
    return ActuatorBody(ports['cmd'], ports['motor'], robot_state(shared), params,
                        task.period_ns * 1e-9)
