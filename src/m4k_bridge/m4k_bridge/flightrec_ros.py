"""The flight recorder inside the bridge process: ROS subscriptions and RT datagrams in, bags out.

Always on with the bridge (``flight_recorder.enabled``). It keeps, in a bounded ring
(:class:`m4k_bridge.flightrec.Ring`), the serialized messages of:

* commands: ``cmd_vel`` as received (the type the bridge subscribes), ``e_stop``, and
  ``cmd_vel_out``, the velocity the RT actuator applies;
* odometry: ``odom``;
* guard and supervisor state: ``flight_recorder/rt_flags`` (diagnostic_msgs/DiagnosticStatus,
  kept here only, never published): the actuator's ODOMETRY flags by name (GUARD, SLOWDOWN,
  E_STOP, HOLD, MOTOR_FAULT, ESTOP_OPEN, ...) at every change and once a second, and
  ``e_stop_state``;
* faults: ``diagnostics`` (devices, link, e-stop) and ``flight_recorder/trigger``, one
  DiagnosticStatus per trigger seen (rate-limited or not);
* RT timing: ``rt_status`` (per-task release latency, response time, overruns, deadline
  misses);
* what the guard saw: ``scan`` and ``sonar`` as the bridge publishes them (the guard's own
  state is in ``rt_flags``: GUARD, SLOWDOWN), so a guard-stop dump shows the obstacle.

Its own health goes on ``diagnostics`` as ``m4k_bridge: flight recorder`` (once a second):
ERROR while the last dump failed (the reason in ``last_error``), with the dumps written,
failed and pruned and the bytes the dump directory takes against
``flight_recorder.max_disk_bytes``.

The bridge's inputs, ``cmd_vel`` and ``e_stop``, are handed over by the bridge's own callbacks
(:meth:`FlightRecorder.keep_cmd_vel`, :meth:`FlightRecorder.keep_e_stop`): the recorder keeps
exactly what the bridge received, with the cmd_vel type actually subscribed (with
``enable_stamped_cmd_vel: auto`` the bridge re-subscribes with the first publisher's type and
tells :meth:`FlightRecorder.set_cmd_vel_type`), and the bridge holds one subscription per input
topic (a second one would show in every matched count, and one participant cannot subscribe a
topic with two types). The bridge's outputs it subscribes best effort (it never slows a
publisher down) on the bridge's own node; its callbacks only copy bytes into the ring.
The triggers come from the RT datagrams the bridge decodes anyway
(:meth:`FlightRecorder.on_datagram`), and a dump is written by a thread of its own
(:class:`m4k_bridge.flightrec.Dumper`). It never runs in the RT process.
"""

from __future__ import annotations

import json
import time
from typing import Any, Callable

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message

from m4k_bridge.bag.metadata import qos_entries
from m4k_bridge.bag.record import qos_yaml
from m4k_bridge.flightrec import (
    default_directory,
    Dumper,
    RateLimit,
    Ring,
    TopicSpec,
    Trigger,
    Triggers,
)
from m4k_bridge.interfaces import interface_class
from m4k_bridge.provenance import COMMIT_KEY, commit_text
from m4k_rt import protocol

__all__ = ['FlightRecorder']

_NS = 1_000_000_000
_SUB_QOS = QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT)
_RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
_BEST_EFFORT = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
_LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)
_DIAG_STATUS = 'diagnostic_msgs/msg/DiagnosticStatus'
_FLAGS_KEEPALIVE_NS = _NS       # the flags are kept at every change and at least once a second


def _spec(topic: str, type_name: str, qos: QoSProfile) -> TopicSpec:
    return TopicSpec(topic, type_name, qos_entries([qos]), qos_yaml([qos]))


def provenance(values: dict[str, Any]) -> dict[str, str]:
    """Return the custom_data that says what a dump ran with: commit and bridge parameters.

    The parameters as JSON, without ``robot_description`` (the URDF: tens of KiB, and in the
    bag's own ``/robot_description`` when recorded).
    """
    params = {k: v for k, v in sorted(values.items()) if k != 'robot_description'}
    return {COMMIT_KEY: commit_text(),
            'm4k.bridge_parameters': json.dumps(params, sort_keys=True, default=str)}


def flag_names(flags: int) -> str:
    """Return the set ODOMETRY flags by name, ``|``-joined ('' when none)."""
    return '|'.join(f.name or '' for f in protocol.OdomFlag if flags & f)


class FlightRecorder:
    """Feed the ring from the bridge node's topics and datagrams; dump on triggers."""

    def __init__(self, node: Any, p: Any, cmd_vel_type: str) -> None:
        """Subscribe on ``node`` (the bridge) with its parameters ``p`` and start the dumper."""
        self.node = node
        self.enabled = bool(p['flight_recorder.enabled'])
        pre, post = p['flight_recorder.seconds'], p['flight_recorder.post_seconds']
        self.ring = Ring(pre + post, p['flight_recorder.max_bytes'])
        self.triggers = Triggers()
        self.limit = RateLimit(p['flight_recorder.min_interval'])
        self.directory = p['flight_recorder.directory'] or default_directory()
        self.dumper: Dumper | None = None
        self._flags_ns = 0
        self.seen: list[Trigger] = []
        if not self.enabled:
            return
        ns = node.get_namespace().rstrip('/')
        # Inputs: fed by the bridge's callbacks (no subscription here); topic names resolved.
        self._cmd_vel_topic = node.resolve_topic_name(p.topic('cmd_vel'))
        self._specs: dict[str, TopicSpec] = {
            'e_stop': _spec(node.resolve_topic_name(p.topic('e_stop')), 'std_msgs/msg/Bool',
                            _RELIABLE)}
        self._cmd_vel_key = ''
        self.set_cmd_vel_type(cmd_vel_type, dumper=False)
        # Outputs of the bridge, as published.
        topics = {
            'cmd_vel_out': (p.topic('cmd_vel_out'), 'geometry_msgs/msg/TwistStamped', _RELIABLE),
            'odom': (p.topic('odom'), 'nav_msgs/msg/Odometry', _RELIABLE),
            'e_stop_state': (p.topic('e_stop_state'), 'std_msgs/msg/Bool', _LATCHED),
            'rt_status': (p.topic('rt_status'), 'm4k_msgs/msg/RtStatus', _RELIABLE),
            'diagnostics': (p.topic('diagnostics'), 'diagnostic_msgs/msg/DiagnosticArray',
                            _RELIABLE),
            # What the guard saw (sensor QoS, as published).
            'scan': (p.topic('scan'), 'sensor_msgs/msg/LaserScan', _BEST_EFFORT),
            'sonar': (p.topic('sonar'), 'sensor_msgs/msg/Range', _BEST_EFFORT),
        }
        specs = self._specs
        self._subs = []
        for key, (topic, type_name, qos) in topics.items():
            sub = node.create_subscription(interface_class(type_name), topic,
                                           self._keeper(key), _SUB_QOS, raw=True)
            self._subs.append(sub)
            specs[key] = _spec(sub.topic_name, type_name, qos)
        for key in ('rt_flags', 'trigger'):
            specs[key] = _spec('{}/flight_recorder/{}'.format(ns, key), _DIAG_STATUS,
                               _RELIABLE)
        log = node.get_logger()

        def emit(level: str, text: str) -> None:
            (log.error if level == 'error' else log.warning)(text)

        self.dumper = Dumper(self.ring, specs, self.directory, pre, post, emit,
                             limits=(p['flight_recorder.max_disk_bytes'],
                                     p['flight_recorder.max_age_days'] * 86400.0),
                             provenance=provenance(p.values))
        self._diag_pub = node.create_publisher(DiagnosticArray, p.topic('diagnostics'), 10)
        node.create_timer(1.0, self.publish_status)
        log.info('flight recorder: last {:g} s (+{:g} s after a trigger, at most {} bytes) '
                 'dumped to {} on {}'.format(pre, post, self.ring.max_bytes, self.directory,
                                             ', '.join(('e_stop', 'guard_stop', 'motor_fault',
                                                        'deadline_miss', 'device_fault'))))

    def set_cmd_vel_type(self, type_name: str, dumper: bool = True) -> None:
        """Record cmd_vel as ``type_name`` from now on (the bridge re-subscribed with it).

        Each type is its own ring key: a message of the type before is never written under the
        new one (it is left out of later dumps; a bag topic has one type).
        """
        if not self.enabled:
            return
        key = 'cmd_vel:' + type_name
        if key == self._cmd_vel_key:
            return
        self._specs.pop(self._cmd_vel_key, None)
        self._specs[key] = _spec(self._cmd_vel_topic, type_name, _BEST_EFFORT)
        if dumper and self.dumper is not None:
            self.dumper.set_topics(self._specs)
        self._cmd_vel_key = key

    def keep_cmd_vel(self, msg: Any) -> None:
        """Keep a cmd_vel message as the bridge received it (its callback; cheap)."""
        if self.enabled:
            self.ring.add(time.time_ns(), self._cmd_vel_key, serialize_message(msg))

    def keep_e_stop(self, msg: Any) -> None:
        """Keep an e_stop message as the bridge received it (its callback; cheap)."""
        if self.enabled:
            self.ring.add(time.time_ns(), 'e_stop', serialize_message(msg))

    def _keeper(self, key: str) -> Callable[[bytes], None]:
        ring = self.ring

        def keep(data: bytes) -> None:
            ring.add(time.time_ns(), key, data)
        return keep

    def on_datagram(self, kind: int, payload: Any) -> None:
        """Watch a decoded RT datagram for triggers (the bridge's executor thread; cheap)."""
        if not self.enabled:
            return
        if kind == protocol.Kind.ODOMETRY:
            prev = self.triggers.flags
            found = self.triggers.on_odometry(payload.flags, payload.v)
            now = time.monotonic_ns()
            if payload.flags != prev or now - self._flags_ns >= _FLAGS_KEEPALIVE_NS:
                self._flags_ns = now
                self._keep_status('rt_flags', 'm4k_rt: actuator flags', flag_names(
                    payload.flags), {'flags': '0x{:x}'.format(payload.flags),
                                     'v': '{:.4f}'.format(payload.v),
                                     'w': '{:.4f}'.format(payload.w)})
        elif kind == protocol.Kind.TASK_STATS:
            found = self.triggers.on_task_stats(payload)
        elif kind == protocol.Kind.DEVICE_STATUS:
            found = self.triggers.on_device_status(payload)
        else:
            return
        for trig_kind, detail in found:
            self.trigger(trig_kind, detail)

    def trigger(self, kind: str, detail: str) -> bool:
        """Note a trigger in the ring and queue a dump unless rate-limited; True if queued."""
        mono, wall = time.monotonic_ns(), time.time_ns()
        allowed = self.limit.allow(kind, mono)
        self._keep_status('trigger', 'm4k_bridge: flight recorder trigger', kind,
                          {'detail': detail, 'dumped': 'yes' if allowed else
                           'no (rate limit)'}, level=DiagnosticStatus.ERROR)
        trig = Trigger(kind, detail, wall, mono)
        self.seen.append(trig)
        del self.seen[:-100]
        if allowed and self.dumper is not None:
            self.dumper.submit(trig)
        return allowed

    def _keep_status(self, key: str, name: str, message: str, values: dict[str, str],
                     level: bytes = DiagnosticStatus.OK) -> None:
        st = DiagnosticStatus(level=level, name=name, message=message, hardware_id='m4k',
                              values=[KeyValue(key=k, value=v) for k, v in values.items()])
        self.ring.add(time.time_ns(), key, serialize_message(st))

    def publish_status(self) -> None:
        """Publish the recorder's own status on diagnostics (ERROR while dumps fail)."""
        d = self.dumper
        if d is None:
            return
        cap = d.limits[0] if d.limits else 0
        values = {'dumps_written': str(len(d.written)), 'dumps_failed': str(d.failed),
                  'last_error': d.last_error, 'dumps_pruned': str(d.pruned),
                  'disk_bytes': str(d.disk_bytes), 'max_disk_bytes': str(cap),
                  'directory': self.directory}
        if d.failing:
            level, msg = DiagnosticStatus.ERROR, 'the last dump failed: ' + d.last_error
        else:
            level, msg = DiagnosticStatus.OK, '{} dump(s) written'.format(len(d.written))
        arr = DiagnosticArray()
        arr.header.stamp = self.node.get_clock().now().to_msg()
        arr.status = [DiagnosticStatus(level=level, name='m4k_bridge: flight recorder',
                                       message=msg, hardware_id='m4k',
                                       values=[KeyValue(key=k, value=v)
                                               for k, v in values.items()])]
        self._diag_pub.publish(arr)

    def close(self) -> None:
        """Write pending dumps now and stop the dump thread."""
        if self.dumper is not None:
            self.dumper.close()


