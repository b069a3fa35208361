"""The RT side's safety figures and the motor fault, as ROS sees them (docs/safety.md).

* :class:`SafetyReport` (no rclpy state) keeps the monitor's SAFETY_STATUS: the guard's
  stated caps (top forward speed and why, t_react, a_brake, margin, reverse creep), whether
  the slow-down zone and wheel supervision are on, the test-only weakening, the latched motor
  fault and its cause. It renders the ``m4k_rt: safety`` diagnostic and the start-up
  statement the bridge logs once per RT session (the RT process cannot print).
* :class:`MotorFaultInterface` adds the fault-state output and its reset:
  ``motor_fault`` (std_msgs/Bool, transient local like ``e_stop_state``: true while latched,
  published on change and at 1 Hz while the RT side reports) and ``~/reset_motor_fault``
  (std_srvs/Trigger): a FAULT_RESET request with a fresh id, answered once the actuator's
  answer with that id comes back -- success true when a latched fault was cleared. The robot
  then stays still until a velocity command newer than the reset arrives.
"""

from __future__ import annotations

import time
from typing import Any

from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.task import Future
from std_msgs.msg import Bool
from std_srvs.srv import Trigger

from m4k_bridge.diagnostics import make_status
from m4k_bridge.safety import E_STOP_STATE_QOS
from m4k_rt import protocol
from m4k_rt.control.supervision import cause_text

__all__ = ['MotorFaultInterface', 'SafetyReport']

_FRESH_NS = 3_000_000_000       # SAFETY_STATUS comes every second
_ODOM_FRESH_NS = 1_000_000_000
_PERIOD_S = 1.0


class SafetyReport:
    """The last SAFETY_STATUS and what it means (pure)."""

    def __init__(self) -> None:
        self.last: protocol.SafetyStatus | None = None
        self.rx_ns = 0
        self.sessions = 0          # RT sessions whose statement was logged
        self._stated = False

    def feed(self, msg: protocol.SafetyStatus, rx_ns: int) -> str | None:
        """Keep a SAFETY_STATUS; return the statement to log when it is the first of a session."""
        self.last, self.rx_ns = msg, rx_ns
        if self._stated:
            return None
        self._stated = True
        self.sessions += 1
        return self.statement(msg)

    def lost(self) -> None:
        """Note that the RT process went away: its successor's statement is logged again."""
        self._stated = False

    def fresh(self, now_ns: int) -> protocol.SafetyStatus | None:
        """Return the last SAFETY_STATUS when fresh, else None."""
        if self.last is None or now_ns - self.rx_ns > _FRESH_NS:
            return None
        return self.last

    @staticmethod
    def statement(m: protocol.SafetyStatus) -> str:
        """Return the start-up statement of the guard's caps (one line)."""
        if not m.flags & protocol.SAFETY_GUARD_ENABLED:
            text = ('RT collision guard DISABLED: forward speed capped only by '
                    'linear.max_velocity ({:.2f} m/s); nothing stops the robot for what its '
                    'sensors see'.format(m.top_speed))
        else:
            text = ('RT collision guard: top forward speed {:.2f} m/s ({}; the sensors see in '
                    'time for {:.2f} m/s with t_react {:.3f} s, a_brake {:.2f} m/s^2, margin '
                    '{:.2f} m); reverse capped to {:.2f} m/s (no rear sensor); slow-down zone '
                    '{}'.format(m.top_speed,
                                'linear.max_velocity' if m.top_speed < m.sensor_speed - 1e-9
                                else 'CAPPED BY WHAT THE SENSORS SEE',
                                m.sensor_speed, m.reaction_time, m.brake_deceleration,
                                m.margin, m.reverse_creep,
                                'on' if m.flags & protocol.SAFETY_SLOW_DOWN else 'OFF'))
        text += '; wheel supervision {}'.format(
            'on' if m.flags & protocol.SAFETY_SUPERVISION else 'OFF')
        if m.flags & protocol.SAFETY_TEST_WEAKENED:
            text += ('; TEST HOOK ACTIVE: guard WEAKENED by {:.3f} m -- this stack must never '
                     'drive a real robot'.format(m.weaken))
        return text

    def status(self, now_ns: int) -> Any:
        """Return the ``m4k_rt: safety`` DiagnosticStatus."""
        m = self.fresh(now_ns)
        if m is None:
            return make_status('m4k_rt: safety', protocol.LEVEL_STALE,
                               'no SAFETY_STATUS from the RT process: guard and supervision '
                               'state unknown', {}, hardware_id='m4k_rt')
        f = m.flags
        values = {
            'guard': 'on' if f & protocol.SAFETY_GUARD_ENABLED else 'DISABLED',
            'top_forward_speed_mps': m.top_speed,
            'sensor_speed_limit_mps': m.sensor_speed,
            'reaction_time_s': m.reaction_time,
            'brake_deceleration_mps2': m.brake_deceleration,
            'margin_m': m.margin,
            'stop_distance_now_m': m.trip_distance,
            'reverse_creep_mps': m.reverse_creep,
            'slow_down_zone': 'on' if f & protocol.SAFETY_SLOW_DOWN else 'off',
            'guard_stop_now': bool(f & protocol.SAFETY_GUARD_STOP),
            'slowing_now': bool(f & protocol.SAFETY_SLOWING),
            'wheel_supervision': 'on' if f & protocol.SAFETY_SUPERVISION else 'OFF',
            'motor_fault': bool(f & protocol.SAFETY_MOTOR_FAULT),
            'motor_fault_cause': cause_text(m.fault_cause),
            'motor_faults': m.motor_faults,
            'e_stop_contact_open': bool(f & protocol.SAFETY_ESTOP_OPEN),
            'e_stop_latched': bool(f & protocol.SAFETY_E_STOP),
            'test_guard_weakened_m': m.weaken,
        }
        if f & protocol.SAFETY_TEST_WEAKENED:
            level, msg = protocol.LEVEL_ERROR, (
                'TEST HOOK: the guard is WEAKENED by {:.3f} m (M4K_TEST_GUARD_WEAKEN_M); never '
                'on a real robot'.format(m.weaken))
        elif f & protocol.SAFETY_MOTOR_FAULT:
            level, msg = protocol.LEVEL_ERROR, (
                'motor fault latched: {}; outputs zero, enable dropped; call '
                '~/reset_motor_fault'.format(cause_text(m.fault_cause)))
        elif f & protocol.SAFETY_ESTOP_OPEN:
            level, msg = protocol.LEVEL_WARN, 'e-stop contact open: amplifier cut, latch engaged'
        elif not f & protocol.SAFETY_GUARD_ENABLED or not f & protocol.SAFETY_SUPERVISION:
            level, msg = protocol.LEVEL_WARN, 'guard or wheel supervision switched off'
        else:
            level, msg = protocol.LEVEL_OK, 'guard caps forward speed at {:.2f} m/s'.format(
                m.top_speed)
        return make_status('m4k_rt: safety', level, msg, values, hardware_id='m4k_rt')

    def fill(self, msg: Any, now_ns: int, odom_flags: int | None) -> None:
        """Fill the safety fields of an m4k_msgs/RtStatus (zeros while unknown)."""
        m = self.fresh(now_ns)
        flags = 0 if odom_flags is None else odom_flags
        msg.e_stop_contact_open = bool(flags & protocol.ODOM_ESTOP_OPEN)
        msg.motor_fault = bool(flags & protocol.ODOM_MOTOR_FAULT)
        if m is not None:
            msg.motor_fault_cause = cause_text(m.fault_cause) if m.fault_cause else ''
            msg.guard_top_speed = float(m.top_speed)
            msg.guard_stop_distance = float(m.trip_distance)
            msg.guard_weakened = float(m.weaken)


class MotorFaultInterface:
    """``motor_fault`` (latched Bool) and ``~/reset_motor_fault`` on the bridge node."""

    def __init__(self, node: Any, send_cmd: Any, topic: str, reset_timeout: float) -> None:
        """Create the publisher, the service and the 1 Hz republish timer."""
        self.node = node
        self._send = send_cmd
        self.reset_timeout = reset_timeout
        self.published: bool | None = None
        self.rx_ns = 0
        self.messages = 0
        self.resets_ok = 0
        self.resets_none = 0
        self.resets_failed = 0
        self._seq = 0
        self._id = 0
        self._pending: dict[int, Any] = {}
        self._group = ReentrantCallbackGroup()
        self._pub = node.create_publisher(Bool, topic, E_STOP_STATE_QOS)
        node.create_service(Trigger, '~/reset_motor_fault', self._on_reset,
                            callback_group=self._group)
        node.create_timer(_PERIOD_S, self._periodic)

    def _fresh(self, now_ns: int) -> bool:
        return bool(self.rx_ns) and now_ns - self.rx_ns <= _ODOM_FRESH_NS

    def on_flags(self, flags: int, rx_ns: int) -> None:
        """Take a fresh ODOMETRY's flags: publish a change (or the state known again)."""
        fault = bool(flags & protocol.ODOM_MOTOR_FAULT)
        was_fresh = self._fresh(rx_ns)
        self.rx_ns = rx_ns
        if fault != self.published or not was_fresh:
            if fault and self.published is not True:
                self.node.get_logger().error(
                    'MOTOR FAULT latched by the RT wheel supervision: outputs zero, amplifier '
                    'enable dropped; see diagnostics "m4k_rt: safety" for the cause, then call '
                    '~/reset_motor_fault')
            self.published = fault
            self._publish(fault)

    def _publish(self, fault: bool) -> None:
        self.messages += 1
        self._pub.publish(Bool(data=fault))

    def _periodic(self) -> None:
        if (self.published is not None and self._fresh(time.monotonic_ns())
                and self.node.context.ok()):
            self._publish(self.published)

    async def _on_reset(self, request: Trigger.Request,
                        response: Trigger.Response) -> Trigger.Response:
        self._id = (self._id + 1) & protocol.SEQ_MASK
        rid = self._id
        done = Future()
        self._pending[rid] = done
        timer = self.node.create_timer(
            self.reset_timeout, lambda: done.done() or done.set_result(None),
            callback_group=self._group)
        try:
            data = protocol.encode(protocol.Kind.FAULT_RESET, self._seq, time.monotonic_ns(),
                                   rid, 0)
            self._seq = protocol.next_seq(self._seq)
            self._send(data)
            cleared = await done
        finally:
            timer.cancel()
            self.node.destroy_timer(timer)
            self._pending.pop(rid, None)
        if cleared is None:
            self.resets_failed += 1
            response.success = False
            response.message = ('no answer from the RT actuator within {} s (request {}): is '
                                'the RT process running?'.format(self.reset_timeout, rid))
        elif cleared:
            self.resets_ok += 1
            response.success = True
            response.message = ('motor fault cleared (request {}); the robot moves again on a '
                                'cmd_vel newer than the reset'.format(rid))
            self.node.get_logger().warning('motor fault reset: ' + response.message)
        else:
            self.resets_none += 1
            response.success = True
            response.message = 'no motor fault was latched (request {})'.format(rid)
        return response

    def on_reset_ack(self, ack: protocol.FaultReset) -> bool:
        """Complete the reset request of ``ack``; False when none was waiting for it."""
        fut = self._pending.get(ack.request_id)
        if fut is None or fut.done():
            return False
        fut.set_result(bool(ack.cleared))
        return True
