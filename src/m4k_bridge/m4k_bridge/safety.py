"""The bridge's e-stop and odometry-reset interface (topic ``e_stop``, ``~/reset_odometry``).

The stop itself is not here: ``e_stop`` (std_msgs/Bool) becomes an E_STOP datagram on the
``cmd`` port, the same ordered port as the velocity commands, and the RT actuator latches it
(``m4k_rt.control.estop``), so the stop holds when this bridge dies. What the bridge adds:

* the subscription: reliable, volatile, depth 10 -- it matches volatile publishers and
  transient-local ("latched") ones alike (a transient-local subscription would refuse
  volatile publishers);
* the request persisted (:mod:`m4k_rt.estop_request`: ``<state_dir>/e_stop.request``, kept
  across service restarts and reboots, written atomically on every change; an unreadable or
  corrupt file reads as engaged): a restarted rt_core starts with its latch engaged, and a
  restarted bridge starts with the request engaged -- the latch survives both dying together;
* the **gate**: while the e-stop is requested, ``cmd_vel`` is not forwarded at all (counted
  as ``cmd_vel_gated_e_stop``), so nothing can reach an RT process that has not latched yet;
* E_STOP engage as the **first datagram of every (re-)link** of the ``cmd`` port, written by
  the port's own thread before anything queued (:meth:`link_preamble`), and re-sent on the
  0.25 s watch as before;
* the e-stop **contact**: when ODOMETRY flags ESTOP_OPEN (the amplifier enable read back low)
  the bridge takes it as an e-stop request (persisted, gated). Closing the contact never
  releases it: that takes ``e_stop`` false (or ``~/e_stop`` false), then a fresh command;
* with ``enable_stamped_cmd_vel``, :class:`CommandStampGate` drops TwistStamped commands stamped no
  later than the newest command seen before the last release, so a command held up in a queue
  (or re-sent) from before the release cannot restart the robot. The rule compares the
  sender's stamps with each other, never with this machine's clock, so a laptop whose clock is
  off still works. Unstamped (zero) commands pass: there is nothing to judge them by;
* the state the RT side reports (ODOMETRY flags E_STOP / HOLD) in ``rt_status`` and in the
  diagnostic ``m4k_bridge: e_stop``;
* ``~/reset_odometry`` (std_srvs/Trigger): an ODOM_RESET request with a fresh id, answered
  success only when the actuator's ODOM_RESET acknowledgement with that id comes back (the
  pose is zero from that cycle's ODOMETRY on), else success=false after
  ``reset_odometry_timeout`` with the reason; ``~/set_pose`` (m4k_msgs/SetPose) the same with
  a SET_POSE request carrying x, y, yaw;
* ``e_stop_state`` (std_msgs/Bool, transient local, like Clearpath's
  ``platform/emergency_stop``): the RT latch as fresh ODOMETRY flags report it, published on
  every change and at 1 Hz (true while engaged; a late subscriber gets the last state). The
  1 Hz republish runs only while the latch is known (ODOMETRY within ``_FRESH_NS``): a bridge
  that lost the RT side falls silent instead of repeating a state it no longer knows, and the
  ``m4k_bridge: e_stop`` diagnostic says the latch is unknown. The transient-local cache still
  holds the last value published (DDS cannot retract it): a late subscriber gets the last
  *known* state; the diagnostic tells whether it is current. The first fresh ODOMETRY after
  the outage publishes the state again at once;
* ``~/e_stop`` (std_srvs/SetBool): the same request as the topic, answered once the RT latch
  shows the requested state (engaged, or released), else success=false after
  ``e_stop_timeout``. Topic and service are one input: the last request wins, and its sender
  learns from the answer or from ``e_stop_state`` what the RT side holds.
"""

from __future__ import annotations

import math
import threading
import time
from typing import Any, Callable

from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from std_msgs.msg import Bool
from std_srvs.srv import SetBool, Trigger

from m4k_bridge.diagnostics import make_status
from m4k_msgs.srv import SetPose
from m4k_rt import protocol
from m4k_rt.estop_request import read_request, request_path, write_request

__all__ = ['CommandStampGate', 'SafetyInterface', 'E_STOP_QOS', 'E_STOP_STATE_QOS']

E_STOP_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
E_STOP_STATE_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                              durability=DurabilityPolicy.TRANSIENT_LOCAL)
_STATE_PERIOD_S = 1.0
_FRESH_NS = 1_000_000_000    # ODOMETRY flags older than this tell nothing about the latch


class CommandStampGate:
    """Refuse stamped commands from before the last e-stop release (pure)."""

    __slots__ = ('newest_ns', 'floor_ns', 'rejected')

    def __init__(self) -> None:
        self.newest_ns = 0      # newest command stamp seen
        self.floor_ns = 0       # commands stamped at or before this are from before a release
        self.rejected = 0

    def accept(self, stamp_ns: int) -> bool:
        """Return whether a command stamped ``stamp_ns`` (0: unstamped) may be forwarded."""
        if stamp_ns <= 0:
            return True
        if stamp_ns <= self.floor_ns:
            self.rejected += 1
            return False
        if stamp_ns > self.newest_ns:
            self.newest_ns = stamp_ns
        return True

    def released(self) -> None:
        """Note an e-stop release: only commands stamped after every earlier one pass now."""
        self.floor_ns = self.newest_ns


def latch_state(flags: int | None) -> tuple[bool, bool]:
    """Return (e-stop engaged, holding for a fresh command) from ODOMETRY flags (None: unknown)."""
    if flags is None:
        return False, False
    return bool(flags & protocol.ODOM_E_STOP), bool(flags & protocol.ODOM_HOLD)


class SafetyInterface:
    """E-stop topic, reset service and their state, attached to the bridge node."""

    def __init__(self, node: Any, send_cmd: Any, topic: str, reset_timeout: float,
                 state_topic: str = 'e_stop_state', e_stop_timeout: float = 1.0,
                 state_dir: str | None = None) -> None:
        """Create the subscription and the service; ``send_cmd(bytes)`` writes to ``cmd``.

        ``state_dir``: where the request is persisted (None: not persisted).
        """
        self.node = node
        self.state_dir = state_dir
        self._lock = threading.Lock()      # the seq counter: the pump thread encodes too
        self.gated = 0                     # cmd_vel not forwarded while the e-stop is requested
        self.contact_requests = 0          # e-stop requests taken from the contact opening
        self.persist_errors = 0
        self._send = send_cmd
        self.reset_timeout = reset_timeout
        self.e_stop_timeout = e_stop_timeout
        self.published_state: bool | None = None
        self.latch_rx_ns = 0          # when the last ODOMETRY's latch arrived (0: never)
        self.state_messages = 0       # e_stop_state messages published (change + periodic)
        self._latch_waiters: list[tuple[bool, Future]] = []
        self._pose_pending: dict[int, Future] = {}
        self.gate = CommandStampGate()
        self.requested: bool | None = None     # last e_stop value received (None: none yet)
        self.e_stop_messages = 0
        self.resets_ok = 0
        self.resets_failed = 0
        self._seq = 0
        self._reset_id = 0
        self._pending: dict[int, Future] = {}
        self._links_seen = 0
        if state_dir:
            persisted = read_request(state_dir)
            if persisted.problem:
                node.get_logger().error('e-stop request: {}'.format(persisted.problem))
            if persisted.engaged:
                self.requested = True
                node.get_logger().warning(
                    'e-stop request ENGAGED from {} (persisted before a restart): cmd_vel gated, '
                    'the RT latch re-asserted on link; release with e_stop false'.format(
                        request_path(state_dir)))
        # Every e_stop message as received, before it acts (the bridge's flight recorder).
        self.record: Callable[[Bool], None] = lambda msg: None
        node.create_subscription(Bool, topic, self._on_e_stop, E_STOP_QOS)
        # The service callback awaits the acknowledgement, which the node's default
        # (mutually exclusive) group delivers: in that group it would block its own answer.
        self._group = ReentrantCallbackGroup()
        node.create_service(Trigger, '~/reset_odometry', self._on_reset_odometry,
                            callback_group=self._group)
        node.create_service(SetPose, '~/set_pose', self._on_set_pose,
                            callback_group=self._group)
        node.create_service(SetBool, '~/e_stop', self._on_e_stop_service,
                            callback_group=self._group)
        self._state_pub = node.create_publisher(Bool, state_topic, E_STOP_STATE_QOS)
        node.create_timer(_STATE_PERIOD_S, self._publish_state_periodic)

    # --- e-stop ---------------------------------------------------------------------------------

    def _datagram(self, kind: int, *fields: Any) -> bytes:
        with self._lock:
            data = protocol.encode(kind, self._seq, time.monotonic_ns(), *fields)
            self._seq = protocol.next_seq(self._seq)
        return data

    @property
    def gating(self) -> bool:
        """Return True while cmd_vel must not be forwarded (the e-stop is requested)."""
        return self.requested is True

    def link_preamble(self) -> bytes | None:
        """Return E_STOP engage for the first write of a new ``cmd`` link (pump thread)."""
        if self.requested is True:
            return self._datagram(protocol.Kind.E_STOP, 1)
        return None

    def _on_e_stop(self, msg: Bool) -> None:
        self.record(msg)
        self._request(bool(msg.data))

    def _request(self, engage: bool, why: str = '') -> None:
        self.e_stop_messages += 1
        if engage != self.requested:
            self.node.get_logger().warning(
                'e_stop {}{}: sent to the RT actuator'.format(
                    'ENGAGED' if engage else 'released (the robot moves again only on a '
                    'newer cmd_vel)', why))
        if not engage:
            self.gate.released()
        changed = engage != self.requested
        self.requested = engage
        # Send first (the stop must not wait for the file system), then persist: the RT
        # latch holds meanwhile, and the file only matters to a process that starts later.
        self._send(self._datagram(protocol.Kind.E_STOP, 1 if engage else 0))
        if changed and self.state_dir:
            try:
                write_request(self.state_dir, engage)
            except OSError as exc:
                self.persist_errors += 1
                self.node.get_logger().error(
                    'cannot persist the e-stop request to {}: {} (a restart of rt_core and '
                    'the bridge together would forget it)'.format(
                        request_path(self.state_dir), exc))

    def on_flags(self, flags: int) -> None:
        """Take a fresh ODOMETRY's flags: an open e-stop contact becomes an e-stop request."""
        if flags & protocol.ODOM_ESTOP_OPEN and self.requested is not True:
            self.contact_requests += 1
            self._request(True, ' by the e-stop CONTACT (release: close it, then e_stop false, '
                          'then a fresh cmd_vel)')

    def on_cmd_links(self, links: int) -> None:
        """Re-send an engaged e-stop after the ``cmd`` port re-linked (call periodically)."""
        if links != self._links_seen:
            self._links_seen = links
            if self.requested and links > 0:
                self._send(self._datagram(protocol.Kind.E_STOP, 1))

    async def _on_e_stop_service(self, request: SetBool.Request,
                                 response: SetBool.Response) -> SetBool.Response:
        want = bool(request.data)
        done = Future()
        self._latch_waiters.append((want, done))
        timer = self.node.create_timer(
            self.e_stop_timeout, lambda: done.done() or done.set_result(False),
            callback_group=self._group)
        try:
            self._request(want)
            ok = await done
        finally:
            timer.cancel()
            self.node.destroy_timer(timer)
            self._latch_waiters = [w for w in self._latch_waiters if w[1] is not done]
        response.success = bool(ok)
        word = 'engaged' if want else 'released'
        response.message = ('e-stop {} in the RT actuator'.format(word) if ok else
                            'the RT actuator did not report the e-stop {} within {} s (is the '
                            'RT process running?)'.format(word, self.e_stop_timeout))
        return response

    def on_latch(self, engaged: bool, rx_ns: int | None = None) -> None:
        """Take the RT latch of a fresh ODOMETRY (arrived at ``rx_ns``, CLOCK_MONOTONIC).

        Answer waiting requests; publish a change, or the state known again after a stale gap.
        """
        now = time.monotonic_ns() if rx_ns is None else rx_ns
        was_fresh = self._fresh(now)
        self.latch_rx_ns = now
        for want, fut in self._latch_waiters:
            if want == engaged and not fut.done():
                fut.set_result(True)
        if engaged != self.published_state or not was_fresh:
            self.published_state = engaged
            self._publish(engaged)

    def _fresh(self, now_ns: int) -> bool:
        return bool(self.latch_rx_ns) and now_ns - self.latch_rx_ns <= _FRESH_NS

    def _publish(self, engaged: bool) -> None:
        self.state_messages += 1
        self._state_pub.publish(Bool(data=engaged))

    def _publish_state_periodic(self) -> None:
        # Only a latch we still know is repeated: with the RT side gone, silence (the
        # diagnostic says unknown) rather than a confident "not engaged" nobody measured.
        if (self.published_state is not None and self._fresh(time.monotonic_ns())
                and self.node.context.ok()):
            self._publish(self.published_state)

    # --- odometry reset -------------------------------------------------------------------------

    async def _on_set_pose(self, request: SetPose.Request,
                           response: SetPose.Response) -> SetPose.Response:
        values = (request.x, request.y, request.yaw)
        if not all(math.isfinite(v) for v in values):
            response.success = False
            response.message = 'x, y and yaw must be finite, got {!r}'.format(values)
            return response
        self._reset_id = (self._reset_id + 1) & protocol.SEQ_MASK
        rid = self._reset_id
        done = Future()
        self._pose_pending[rid] = done
        timer = self.node.create_timer(
            self.reset_timeout, lambda: done.done() or done.set_result(None),
            callback_group=self._group)
        try:
            self._send(self._datagram(protocol.Kind.SET_POSE, rid, *values))
            pose = await done
        finally:
            timer.cancel()
            self.node.destroy_timer(timer)
            self._pose_pending.pop(rid, None)
        response.success = pose is not None
        if pose is not None:
            self.resets_ok += 1
            response.message = 'odometry pose set to ({:.3f}, {:.3f}, {:.3f}) by the RT ' \
                'actuator (request {})'.format(*pose, rid)
        else:
            self.resets_failed += 1
            response.message = ('no acknowledgement from the RT actuator within {} s (request '
                                '{}); the pose may or may not have been set'.format(
                                    self.reset_timeout, rid))
        return response

    def on_set_pose_ack(self, ack: protocol.SetPose) -> bool:
        """Complete the set_pose request of ``ack``; False when none was waiting for it."""
        fut = self._pose_pending.get(ack.request_id)
        if fut is None or fut.done():
            return False
        fut.set_result((ack.x, ack.y, ack.yaw))
        return True

    async def _on_reset_odometry(self, request: Trigger.Request,
                                 response: Trigger.Response) -> Trigger.Response:
        self._reset_id = (self._reset_id + 1) & protocol.SEQ_MASK
        rid = self._reset_id
        done = Future()
        self._pending[rid] = done
        timer = self.node.create_timer(
            self.reset_timeout, lambda: done.done() or done.set_result(False),
            callback_group=self._group)
        try:
            self._send(self._datagram(protocol.Kind.ODOM_RESET, rid))
            ok = await done
        finally:
            timer.cancel()
            self.node.destroy_timer(timer)
            self._pending.pop(rid, None)
        response.success = bool(ok)
        if ok:
            self.resets_ok += 1
            response.message = 'odometry pose zeroed by the RT actuator (request {})'.format(rid)
        else:
            self.resets_failed += 1
            response.message = ('no acknowledgement from the RT actuator within {} s (request '
                                '{}): is the RT process running and the cmd port linked? The '
                                'pose may or may not have been reset'.format(
                                    self.reset_timeout, rid))
            self.node.get_logger().warning('reset_odometry: ' + response.message)
        return response

    def on_reset_ack(self, request_id: int) -> bool:
        """Complete the request ``request_id``; return False when none was waiting for it."""
        fut = self._pending.get(request_id)
        if fut is None or fut.done():
            return False
        fut.set_result(True)
        return True

    # --- state ----------------------------------------------------------------------------------

    def latch(self, odom: protocol.Odometry | None, odom_rx_ns: int,
              now_ns: int) -> tuple[bool, bool] | None:
        """Return the RT latch (engaged, holding) from fresh ODOMETRY, else None (unknown)."""
        if odom is None or now_ns - odom_rx_ns > _FRESH_NS:
            return None
        return latch_state(odom.flags)

    def status(self, odom: protocol.Odometry | None, odom_rx_ns: int, now_ns: int) -> Any:
        """Return the ``m4k_bridge: e_stop`` DiagnosticStatus."""
        latch = self.latch(odom, odom_rx_ns, now_ns)
        values = {'requested': {None: 'none', True: 'engaged', False: 'released'}[self.requested],
                  'rt_latch': 'unknown' if latch is None else
                  'engaged' if latch[0] else 'holding' if latch[1] else 'clear',
                  'e_stop_messages': self.e_stop_messages,
                  'stale_commands_rejected': self.gate.rejected,
                  'cmd_vel_gated_e_stop': self.gated,
                  'contact_requests': self.contact_requests,
                  'persisted_in': (request_path(self.state_dir) if self.state_dir
                                   else 'not persisted'),
                  'persist_errors': self.persist_errors,
                  'odometry_resets': self.resets_ok, 'odometry_resets_failed': self.resets_failed,
                  'e_stop_state_published': self.state_messages,
                  'e_stop_state_last': {None: 'none', True: 'true', False: 'false'}[
                      self.published_state],
                  'e_stop_state_republishing': latch is not None}
        if latch is None:
            if self.requested:
                level, msg = protocol.LEVEL_ERROR, ('e-stop requested but the RT actuator does '
                                                    'not report (no fresh odometry): latch state '
                                                    'unknown, e_stop_state not republished')
            else:
                level, msg = protocol.LEVEL_STALE, ('RT actuator not reporting: e-stop state '
                                                    'unknown (stale), e_stop_state not '
                                                    'republished')
        elif latch[0]:
            level, msg = protocol.LEVEL_WARN, 'e-stop latched in the RT actuator'
        elif self.requested:
            level, msg = protocol.LEVEL_ERROR, 'e-stop requested, RT actuator not latched yet'
        elif latch[1]:
            level, msg = protocol.LEVEL_OK, 'released; stopped until a newer cmd_vel'
        else:
            level, msg = protocol.LEVEL_OK, 'clear'
        return make_status('m4k_bridge: e_stop', level, msg, values, hardware_id='m4k_rt')
