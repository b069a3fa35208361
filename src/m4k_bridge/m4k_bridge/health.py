"""The bridge's health bookkeeping (pure: no rclpy, no ROS messages, no sockets).

What the bridge node knows about the RT link besides the ROS plumbing: whether the RT process
is there (the outage state machine: an outage is reported once when it starts and once when it
ends, with the gap, and counted), the bridge's own counters (malformed, lost and unexpected
datagrams, cmd_vel forwarded / rejected / clamped, LED overrides, sonar faults, IMU samples
not ready), and from them the inputs of the ``m4k_bridge: rt link``, ``m4k_bridge: cmd_vel`` and
``m4k_drivers: <device>`` diagnostics.

:class:`BridgeHealth` is fed plain values -- CLOCK_MONOTONIC nanoseconds passed in, the ports'
counters (anything shaped like :class:`PortState`, :class:`m4k_bridge.ports.PortPump`
among them), decoded payloads -- and returns :class:`Event` (what to log, at which severity)
and :class:`Status` (what :func:`m4k_bridge.diagnostics.make_status` turns into a
DiagnosticStatus). Tests drive its time and its links without a ROS context.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass
from typing import Any, Iterable, Literal, Mapping, Protocol

from m4k_rt import protocol

__all__ = ['BridgeHealth', 'DEVICE_PORTS', 'Event', 'PortState', 'STALE_FLOOR_S',
           'STALE_PERIODS', 'Status']

# Devices the bridge sees through their data ports: role -> (device, period expected [s]).
DEVICE_PORTS: Mapping[str, tuple[str, float]] = {
    'imu_out': ('imu', 0.01), 'sonar_out': ('sonar', 0.03), 'lrf_out': ('lrf', 0.2),
    'led_in': ('led', 1.0), 'cmd': ('motor', 0.05)}
# A device judged by data arrival is STALE after this many expected periods without data, and
# never sooner than STALE_FLOOR_S (a 10 ms IMU must not flap on one late executor wake-up).
STALE_PERIODS = 10
STALE_FLOOR_S = 1.0
# How long an ODOMETRY's guard flag stands in for RT_STATUS's (see :meth:`guard_fallback`).
_GUARD_FALLBACK_NS = 1_000_000_000
# Counters the ``rt link`` status lists (prefixes of the keys).
_LINK_COUNTERS = ('malformed_', 'lost_', 'unexpected_', 'inbox_')

Severity = Literal['info', 'warning', 'error']


class PortState(Protocol):
    """What the health reads of one bridge port (a PortPump's counters, read-only)."""

    @property
    def linked(self) -> bool:
        """Return True while the RT side of the port is linked."""

    @property
    def links(self) -> int:
        """Return how many times the port was (re)linked."""

    @property
    def lost(self) -> int:
        """Return how many links broke."""

    @property
    def last_link_error(self) -> str:
        """Return why the last link attempt failed ('' when none)."""

    @property
    def received(self) -> int:
        """Return the datagrams received."""

    @property
    def sent(self) -> int:
        """Return the datagrams sent."""

    @property
    def dropped_unlinked(self) -> int:
        """Return the sends dropped while no RT peer was linked."""

    @property
    def dropped_overflow(self) -> int:
        """Return the sends dropped because the outbox was full."""

    @property
    def last_rx_ns(self) -> int:
        """Return CLOCK_MONOTONIC of the last datagram received (0 = never)."""

    @property
    def error(self) -> BaseException | None:
        """Return the exception that ended the port's reader, if any."""


@dataclass(frozen=True)
class Event:
    """One thing to log: ``kind`` for code, ``severity`` the logger method, ``message`` text.

    Kinds: ``linked`` (first link, ``gap_s`` since start-up), ``outage_start``,
    ``outage_end`` (``gap_s`` = last datagram before to first datagram after), ``port_failed``.
    """

    kind: str
    severity: Severity
    message: str
    gap_s: float = 0.0


@dataclass(frozen=True)
class Status:
    """The inputs of one DiagnosticStatus (``level`` a protocol LEVEL_* value)."""

    name: str
    level: int
    message: str
    values: dict[str, Any]
    hardware_id: str


def _age_s(now_ns: int, then_ns: int) -> float:
    return (now_ns - then_ns) * 1e-9 if then_ns else float('inf')


def _newest_rx_ns(ports: Mapping[str, PortState]) -> int:
    """Return the newest datagram arrival over all ports (0 = nothing ever arrived)."""
    return max((p.last_rx_ns for p in ports.values()), default=0)


class BridgeHealth:
    """The outage state machine, the bridge's counters, and the statuses built from them.

    ``counters`` keys: ``malformed_<role>``, ``lost_<role>`` (sequence gaps),
    ``unexpected_<role>``, ``inbox_overflow`` (listed in the ``rt link`` status);
    ``cmd_vel_forwarded``, ``cmd_vel_rejected_nonfinite``, ``cmd_vel_clamped``,
    ``led_forwarded``, ``led_rejected_nonfinite`` (the ``cmd_vel`` status); ``sonar_faults``,
    ``imu_not_ready`` (their device statuses).
    """

    def __init__(self, now_ns: int, runtime_dir: str) -> None:
        """Start waiting for the RT process at ``now_ns`` (CLOCK_MONOTONIC)."""
        self.runtime_dir = runtime_dir
        self.counters: collections.Counter[str] = collections.Counter()
        self.rt_alive = False
        self.outages = 0
        self.last_gap_s = 0.0
        self.outage_start_ns = now_ns    # the last datagram before the outage (or start-up)
        self._outage_seen_ns = 0         # when the outage was noticed
        self._last_rx_seen = 0
        self._lost_seen = 0
        self._failed_ports: set[str] = set()
        self._last_seq: dict[str, int] = {}
        self.last_cmd_ns = 0
        # When a command was last rejected / clamped: the cmd_vel status is WARN only while
        # the newest such event is inside the window (as the RT task statuses judge a window
        # of samples, not the whole session).
        self.last_cmd_problem_ns = 0
        self.cmd_vel_type_mismatch = ''   # 'publisher type vs subscribed type'; '' = none
        self.last_odom: protocol.Odometry | None = None
        self.last_odom_ns = 0
        self.led_shown: protocol.Led | None = None

    # --- feeding ------------------------------------------------------------------------------

    def count(self, key: str, n: int = 1) -> int:
        """Add ``n`` to a counter; return its new value."""
        self.counters[key] += n
        return self.counters[key]

    def on_cmd_problem(self, key: str, now_ns: int) -> int:
        """Count a rejected or clamped command (``key``) at ``now_ns``; return the count."""
        self.last_cmd_problem_ns = now_ns
        return self.count(key)

    def on_seq(self, role: str, seq: int) -> None:
        """Account a datagram's sequence number: a gap counts ``lost_<role>``."""
        prev = self._last_seq.get(role)
        if prev is not None:
            lost = protocol.seq_gap(prev, seq)
            if lost:
                self.counters['lost_' + role] += lost
        self._last_seq[role] = seq

    def on_cmd_vel_forwarded(self, now_ns: int) -> None:
        """Account a velocity command sent to the RT process at ``now_ns``."""
        self.counters['cmd_vel_forwarded'] += 1
        self.last_cmd_ns = now_ns

    def on_odometry(self, odom: protocol.Odometry, rx_ns: int) -> None:
        """Keep the last ODOMETRY (its flags feed the motor status and the guard fallback)."""
        self.last_odom, self.last_odom_ns = odom, rx_ns

    def on_sonar(self, status: int) -> None:
        """Count a sonar reading whose status is a fault (beyond 'no echo')."""
        if status > protocol.SONAR_NO_ECHO:
            self.counters['sonar_faults'] += 1

    def on_led_shown(self, led: protocol.Led) -> None:
        """Keep the colour the RT LED task reports as shown."""
        self.led_shown = led

    # --- the outage state machine -------------------------------------------------------------

    def watch(self, now_ns: int, ports: Mapping[str, PortState],
              stale_timeout_s: float) -> list[Event]:
        """Advance the outage state machine; return what to log (each transition once).

        An outage starts when a port's link broke since the last call (the RT side closed or
        died: XDDP reports it at once, even if the RT process is back before this call) or when
        nothing arrived for ``stale_timeout_s``; it ends with the first datagram after it was
        noticed, on a linked port. A port whose reader failed is reported once.
        """
        events = []
        last = _newest_rx_ns(ports)
        lost = sum(p.lost for p in ports.values())
        broke, self._lost_seen = lost > self._lost_seen, lost
        linked = any(p.linked for p in ports.values())
        fresh = bool(last) and now_ns - last < stale_timeout_s * 1e9
        if self.rt_alive and (broke or not fresh):
            self.rt_alive = False
            self.outages += 1
            self.outage_start_ns = self._last_rx_seen or now_ns
            self._outage_seen_ns = now_ns
            events.append(Event('outage_start', 'warning', (
                'lost the RT process ({}); ports re-linking, odom, imu, scan and sonar pause '
                'until it is back').format('link broken' if broke else
                                           'no datagram for {} s'.format(stale_timeout_s))))
        elif not self.rt_alive and linked and fresh and last > self._outage_seen_ns:
            self.rt_alive = True
            gap = (last - self.outage_start_ns) * 1e-9
            if self.outages:
                self.last_gap_s = gap
                events.append(Event('outage_end', 'warning', (
                    'RT process is back after a {:.1f} s gap (outage {}); ports re-linked'
                    ).format(gap, self.outages), gap))
            else:
                events.append(Event('linked', 'info',
                                    'linked to the RT process after {:.1f} s'.format(gap), gap))
        self._last_rx_seen = last
        for role, port in ports.items():
            if port.error is not None and role not in self._failed_ports:
                self._failed_ports.add(role)
                events.append(Event('port_failed', 'error',
                                    'port {!r} reader failed: {!r}'.format(role, port.error)))
        return events

    # --- reading ------------------------------------------------------------------------------

    def link_age_s(self, now_ns: int, ports: Mapping[str, PortState]) -> float:
        """Return the seconds since the last datagram on any port (inf: never)."""
        return _age_s(now_ns, _newest_rx_ns(ports))

    def guard_fallback(self, now_ns: int) -> bool:
        """Return the collision guard as the last ODOMETRY (under 1 s old) flags it.

        For an RT process whose RT_STATUS does not carry the guard.
        """
        odom = self.last_odom
        return bool(odom is not None and odom.flags & protocol.ODOM_GUARD
                    and now_ns - self.last_odom_ns < _GUARD_FALLBACK_NS)

    def device_statuses(self, now_ns: int, ports: Mapping[str, PortState],
                        port_labels: Mapping[str, Any],
                        reported: Iterable[tuple[str, int, str, dict[str, Any]]]
                        ) -> list[Status]:
        """Return one status per device.

        ``reported``: (device, level, message, values) from the forwarded DEVICE_STATUS
        (:meth:`m4k_bridge.diagnostics.RtMonitor.device_levels`); a device with a report
        takes its level, message and values, only a device that never reported is judged by
        data arrival on its port (STALE after ``STALE_PERIODS`` expected periods, at least
        ``STALE_FLOOR_S``, or while the RT process is lost). Either way the motor is ERROR
        while ODOMETRY flags it stale (no encoder feedback reaches the RT side).
        ``port_labels``: role -> the configured port, shown as ``port``.
        """
        by_device = {name: (level, msg, values) for name, level, msg, values in reported}
        out = []
        for role, (device, period) in DEVICE_PORTS.items():
            port = ports[role]
            age = _age_s(now_ns, port.last_rx_ns)
            values: dict[str, Any] = {'port': port_labels[role], 'data_age_s': age,
                                      'received': port.received}
            rep = by_device.pop(device, None)
            if rep is not None:
                level, msg = rep[0], rep[1]
                values.update(rep[2])
                values['source'] = 'device_status'
            else:
                stale_after = max(STALE_PERIODS * period, STALE_FLOOR_S)
                if not self.rt_alive or age > stale_after:
                    level, msg = protocol.LEVEL_STALE, 'no data for {:.1f} s'.format(age)
                else:
                    level, msg = protocol.LEVEL_OK, 'data flowing'
                values['source'] = 'data_arrival'
            odom = self.last_odom
            if device == 'motor' and odom is not None and self.rt_alive:
                values['odom_flags'] = odom.flags
                if odom.flags & protocol.ODOM_MOTOR_STALE and level < protocol.LEVEL_ERROR:
                    level, msg = protocol.LEVEL_ERROR, 'motor stale (no encoder feedback)'
            if device == 'sonar':
                values['range_faults'] = self.counters['sonar_faults']
                values['dropped_not_a_range'] = self.counters['sonar_dropped']
            if device == 'imu':
                values['not_ready'] = self.counters['imu_not_ready']
            if device == 'led' and self.led_shown is not None:
                values['shown'] = tuple(self.led_shown)
            out.append(Status('m4k_drivers: ' + device, level, msg, values, device))
        for name, (level, msg, values) in sorted(by_device.items()):
            values['source'] = 'device_status'
            out.append(Status('m4k_drivers: ' + name, level, msg, values, name))
        return out

    def link_status(self, now_ns: int, ports: Mapping[str, PortState]) -> Status:
        """Return the ``m4k_bridge: rt link`` status: linked, lost (re-linking) or waiting."""
        pv = ports.values()
        values: dict[str, Any] = {
            'runtime_dir': self.runtime_dir,
            'linked_ports': sum(p.linked for p in pv),
            'outages': self.outages, 'last_gap_s': self.last_gap_s,
            'relinks': sum(max(p.links - 1, 0) for p in pv),
            # the bridge's own side of the links (RtStatus.ports holds the RT side's)
            'bridge_sent': sum(p.sent for p in pv),
            'bridge_received': sum(p.received for p in pv),
            'bridge_dropped_unlinked': sum(p.dropped_unlinked for p in pv),
            'bridge_dropped_overflow': sum(p.dropped_overflow for p in pv),
            'last_datagram_age_s': self.link_age_s(now_ns, ports)}
        for key in sorted(self.counters):
            if key.startswith(_LINK_COUNTERS):
                values[key] = self.counters[key]
        if self.rt_alive:
            level, msg = protocol.LEVEL_OK, 'linked'
        elif self.outages:
            level = protocol.LEVEL_STALE
            msg = 'RT process lost {:.1f} s ago; re-linking'.format(
                (now_ns - self.outage_start_ns) * 1e-9)
        else:
            level = protocol.LEVEL_STALE
            errs = {p.last_link_error for p in pv if p.last_link_error}
            msg = 'waiting for the RT process' + (': ' + sorted(errs)[0] if errs else '')
        return Status('m4k_bridge: rt link', level, msg, values, 'm4k_rt')

    def cmd_status(self, now_ns: int, cmd_vel_timeout_s: float, dropped_no_rt: int,
                   window_s: float = 10.0) -> Status:
        """Return the ``m4k_bridge: cmd_vel`` status.

        WARN while a publisher of the other message type is on the cmd_vel topic
        (:attr:`cmd_vel_type_mismatch`), or when a command was rejected or clamped within the
        last ``window_s`` seconds (the counters stay cumulative); otherwise OK, 'idle' when no
        command came for ``cmd_vel_timeout_s`` (the RT actuator brakes after its own timeout),
        'commanded' before. ``dropped_no_rt``: commands the cmd port dropped unlinked.
        """
        c = self.counters
        age = _age_s(now_ns, self.last_cmd_ns)
        values: dict[str, Any] = {'forwarded': c['cmd_vel_forwarded'],
                  'rejected_nonfinite': c['cmd_vel_rejected_nonfinite'],
                  'clamped': c['cmd_vel_clamped'], 'last_cmd_age_s': age,
                  'dropped_no_rt': dropped_no_rt,
                  'led_forwarded': c['led_forwarded'],
                  'led_rejected_nonfinite': c['led_rejected_nonfinite']}
        values['type_mismatch'] = self.cmd_vel_type_mismatch or 'none'
        recent = (self.last_cmd_problem_ns
                  and now_ns - self.last_cmd_problem_ns <= window_s * 1e9)
        if self.cmd_vel_type_mismatch:
            level, msg = protocol.LEVEL_WARN, (
                'a cmd_vel publisher of another type never matches: {}'.format(
                    self.cmd_vel_type_mismatch))
        elif recent:
            level, msg = protocol.LEVEL_WARN, 'commands rejected or clamped in the last {:g} s'\
                .format(window_s)
        elif age > cmd_vel_timeout_s:
            level, msg = protocol.LEVEL_OK, 'idle (RT actuator brakes after its timeout)'
        else:
            level, msg = protocol.LEVEL_OK, 'commanded'
        return Status('m4k_bridge: cmd_vel', level, msg, values, 'm4k_bridge')
