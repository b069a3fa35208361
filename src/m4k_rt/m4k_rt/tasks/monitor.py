"""The ``monitor`` body: the one way information leaves the RT process while the tasks run.

It ships every task's timing samples and counters as datagrams on the ``status`` port (the
bridge) and the ``stat`` port (``rt_stat``, opened on demand); :mod:`m4k_rt.rt_core` registers
it under ``monitor`` and hands it the process's shared object (:class:`MonitorShared` is what
this body reads of it).
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Protocol, Sequence

from m4k_rt import config, protocol, sched
from m4k_rt.task import RtTask
from m4k_rt.tasks.portio import PortReader
from m4k_rt.tasks.state import DEVICE_SLOTS
from m4k_rt.timerfd import monotonic_ns

__all__ = ['DEVICE_STALE_S', 'DRAIN_MONITOR', 'MonitorShared', 'StatsShipper', 'make_monitor']

DRAIN_MONITOR = 1024  # datagrams drained per monitor port and cycle (1 s, lowest priority)
DEVICE_STALE_S = 3.0  # a device's last DEVICE_STATUS older than this is forwarded as STALE
# Which monitor ports a datagram goes to.
_TO_ALL = 0
_TO_STAT = 1      # only ports flagged extra (``stat``)
_TO_STATUS = 2    # only the others (``status``: the bridge)


class MonitorShared(Protocol):
    """What the monitor reads of the RT process's shared object (``rt_core.SharedState``)."""

    config: config.RtConfig
    hardening: sched.Hardening
    tasks: list[RtTask]
    audit_installed: bool
    robot: Any
    ports: dict[str, Any]


class StatsShipper:
    """The monitor body: ship ring samples and counters of every task as datagrams.

    Runs at the lowest RT priority. Samples since the previous batch go out as TASK_STATS
    (chunked to ``batch`` samples and to the datagram limit), then TASK_HEALTH (with the
    body's ``unexpected`` count when it keeps one: valid datagrams of a kind its ports do not
    carry, this monitor's own included) and
    FORBIDDEN_SITE on ports flagged ``extra`` (the ``stat`` port), then -- on the other ports
    (``status``) -- one DEVICE_STATUS per device that ever reported (its last report, level
    STALE when older than ``device_stale_ns``, stamped with its arrival time) and one
    PORT_STATS per XDDP port of the process (``shared.ports``: its RT-side counters), then --
    on every port -- one HOST_DROPS per device whose driver host ever sent one (its last
    counters, stamped with their arrival), then (``status``) SAFETY_STATUS and, once per
    latched motor fault, its FAULT_TRACE rows, then RT_STATUS, which closes a batch. Nothing is
    encoded when no port has a peer; cursors move on regardless.
    """

    def __init__(self, shared: MonitorShared, ports: Sequence[tuple[Any, bool]],
                 batch: int = 128, max_datagram: int = 4096,
                 device_stale_ns: int = int(DEVICE_STALE_S * 1e9)) -> None:
        """Preallocate the datagram buffer; ``ports`` are (socket, extra) pairs."""
        self.shared = shared
        self.ports = list(ports)
        self.device_stale_ns = device_stale_ns
        # (device name as bytes, RobotState attribute of its report, attribute of its arrival)
        self._devices = [(name.encode(), status, rx)
                         for name, (status, rx) in DEVICE_SLOTS.items()]
        self._drop_names = [(name, name.encode()) for name in DEVICE_SLOTS]
        per = (max_datagram - protocol.encoded_size(protocol.Kind.TASK_STATS, 0)) \
            // protocol.TASK_STATS_SAMPLE.size
        self.batch = max(1, min(batch, per, protocol.MAX_STATS_SAMPLES))
        site_size = protocol.encoded_size(protocol.Kind.FORBIDDEN_SITE)
        self._buf = bytearray(max(max_datagram, site_size))
        self._view = memoryview(self._buf)
        self._cursors: list[int] = []
        self._lost: list[int] = []
        self._names: list[bytes] = []
        self.seq = 0
        self.batches = 0
        # The NRT side only reads these ports: what it writes is drained, counted and dropped
        # (malformed on the socket, valid ones here), so it can neither fill the socket buffer
        # unseen nor pass unnoticed.
        self._readers = [PortReader(sock, 256) for sock, _ in self.ports]
        self.unexpected = 0
        self._robot: Any = None
        self._port_rows: list[tuple[bytes, int, Any]] = []   # (label, port, socket)
        self.trace_sent = 0         # the number of the last motor fault whose trace went out

    def _prepare(self) -> None:
        n = len(self.shared.tasks)
        if len(self._cursors) != n:
            self._cursors = [0] * n
            self._lost = [0] * n
            self._names = [t.name.encode() for t in self.shared.tasks]
        if self._robot is None:
            self._robot = self.shared.robot
        if len(self._port_rows) != len(self.shared.ports):
            self._port_rows = sorted(((label.encode(), sock.port, sock)
                                      for label, sock in self.shared.ports.items()),
                                     key=lambda row: row[1])

    def __call__(self, ctx: Any) -> None:
        """Run one monitor cycle."""
        self.ship()

    def _send(self, size: int, to: int) -> None:
        view = self._view[:size]
        for sock, extra in self.ports:
            if sock.connected and (to == _TO_ALL or extra == (to == _TO_STAT)):
                sock.send(view)
        self.seq = (self.seq + 1) & 0xFFFFFFFF

    def _ship_devices(self, now: int) -> None:
        """Forward each device's last DEVICE_STATUS (STALE when too old) on ``status``."""
        robot = self._robot
        if robot is None:
            return
        buf = self._buf
        for name, status_attr, rx_attr in self._devices:
            rx = getattr(robot, rx_attr)   # written after the report: non-zero -> report set
            if not rx:
                continue                   # never reported: the bridge uses its data fallback
            d = getattr(robot, status_attr)
            level = d.level if now - rx <= self.device_stale_ns else protocol.LEVEL_STALE
            size = protocol.encode_into(buf, 0, protocol.Kind.DEVICE_STATUS, self.seq, rx,
                                        name, d.state, level, d.faults, d.last_error)
            self._send(size, _TO_STATUS)

    def _ship_host_drops(self) -> None:
        """Forward each device's last HOST_DROPS on every port, stamped with its arrival.

        Both consumers want them: the bridge's diagnostics and ``rt_stat``'s drop table.
        """
        robot = self._robot
        if robot is None:
            return
        buf = self._buf
        drops = robot.host_drops
        for name, wire_name in self._drop_names:
            got = drops.get(name)
            if got is None:
                continue                   # that device's host never reported (or is older)
            d, rx = got
            size = protocol.encode_into(buf, 0, protocol.Kind.HOST_DROPS, self.seq, rx,
                                        wire_name, *d[1:])
            self._send(size, _TO_ALL)

    def _ship_ports(self, now: int) -> None:
        """Send every port's RT-side counters as one PORT_STATS each on ``status``."""
        buf = self._buf
        kind = protocol.Kind.PORT_STATS
        for label, port, sock in self._port_rows:
            c = sock.counters
            size = protocol.encode_into(
                buf, 0, kind, self.seq, now, label, port, 1 if sock.connected else 0, c.sent,
                c.received, c.dropped_no_peer, c.dropped_full, c.dropped_oversize, c.malformed,
                c.peer_restarts)
            self._send(size, _TO_STATUS)

    def _ship_safety(self, robot: Any, now: int) -> None:
        """Send SAFETY_STATUS: the guard's stated caps and the supervision / e-stop state."""
        plan = robot.guard_plan
        sv = robot.motor_fault_cause
        flags = ((protocol.SAFETY_GUARD_ENABLED if plan.enabled else 0)
                 | (protocol.SAFETY_SLOW_DOWN if plan.slow_down else 0)
                 | (protocol.SAFETY_SUPERVISION if plan.supervision else 0)
                 | (protocol.SAFETY_TEST_WEAKENED if plan.weaken else 0)
                 | (protocol.SAFETY_MOTOR_FAULT if sv else 0)
                 | (protocol.SAFETY_ESTOP_OPEN if robot.estop_open else 0)
                 | (protocol.SAFETY_E_STOP if robot.e_stop_engaged else 0)
                 | (protocol.SAFETY_GUARD_STOP if robot.guard_active else 0)
                 | (protocol.SAFETY_SLOWING if robot.guard_slowing else 0))
        sensor = plan.sensor_speed if math.isfinite(plan.sensor_speed) else 0.0
        creep = plan.reverse_creep if math.isfinite(plan.reverse_creep) else 0.0
        size = protocol.encode_into(
            self._buf, 0, protocol.Kind.SAFETY_STATUS, self.seq, now, plan.top_speed, sensor,
            plan.reaction_time, plan.brake_deceleration, plan.margin,
            robot.guard_trip_distance, plan.weaken, creep, flags, sv,
            robot.motor_faults & 0xFFFFFFFF)
        self._send(size, _TO_STATUS)

    def _ship_trace(self, trace: Any, now: int) -> None:
        """Send the fault trace frozen at the last latch, one FAULT_TRACE per row, once."""
        fault = trace.fault
        rows = trace.rows
        for i in range(rows):
            t_ns, flags, values = trace.row(i)
            size = protocol.encode_into(self._buf, 0, protocol.Kind.FAULT_TRACE, self.seq, now,
                                        fault & 0xFFFFFFFF, trace.cause, i, rows, t_ns,
                                        *values, flags)
            self._send(size, _TO_STATUS)
        if trace.fault == fault:    # (else a newer latch froze meanwhile: sent next cycle)
            self.trace_sent = fault

    def ship(self) -> None:
        """Send one batch: samples since the last batch, counters, call sites, status."""
        self._prepare()
        for r in self._readers:
            r.start_cycle()
            r.budget = DRAIN_MONITOR
            while r.next() is not None:
                self.unexpected += 1
        linked = [sock.poll_peer() for sock, _ in self.ports]
        extra_linked = any(ok and extra for ok, (_, extra) in zip(linked, self.ports,
                                                                   strict=True))
        status_linked = any(ok and not extra for ok, (_, extra) in zip(linked, self.ports,
                                                                       strict=True))
        now = monotonic_ns()
        buf = self._buf
        pack = protocol.TASK_STATS_SAMPLE.pack_into
        step = protocol.TASK_STATS_SAMPLE.size
        cycles_min = 0xFFFFFFFF
        fifo_all = True
        for i, t in enumerate(self.shared.tasks):
            first, end, lost = t.ring.available(self._cursors[i])
            self._lost[i] += lost
            self._cursors[i] = end
            fifo_all = fifo_all and t.fifo
            if t.cycles < cycles_min:
                cycles_min = t.cycles
            if not any(linked):
                continue
            ru = t.rusage
            cpu = -1 if t.cpu is None else t.cpu
            ring = t.ring
            cap = ring.capacity
            rel, start, t_end, exp = ring.t_rel, ring.t_start, ring.t_end, ring.expirations
            while True:
                count = min(self.batch, end - first)
                size = protocol.encode_task_stats_head_into(
                    buf, 0, self.seq, now, self._names[i], t.index, t.priority, cpu,
                    t.period_ns, t.cycles & 0xFFFFFFFF, ru.nvcsw, ru.nivcsw, ru.minflt,
                    t.sites.total, count)
                for s in range(first, first + count):   # straight from the ring's arrays
                    k = s % cap
                    pack(buf, size, rel[k], start[k], t_end[k], exp[k])
                    size += step
                self._send(size, _TO_ALL)
                first += count
                if first >= end:
                    break
            if extra_linked:
                size = protocol.encode_task_health_into(
                    buf, 0, self.seq, now, t.name, t.index, t.overruns, t.deadline_misses,
                    t.body_errors, ru.majflt, ru.nvcsw_extra, self._lost[i], int(t.fifo),
                    t.priority, getattr(t.body, 'unexpected', 0))
                self._send(size, _TO_STAT)
                if t.sites.total:
                    for site in t.sites.sites():
                        size = protocol.encode_forbidden_site_into(
                            buf, 0, self.seq, now, t.name, t.index,
                            protocol.EVENT_CODES[site.event], site.calls, site.line,
                            t.sites.total, site.file, site.func)
                        self._send(size, _TO_STAT)
        if status_linked:
            self._ship_devices(now)
            self._ship_ports(now)
        if any(linked):
            self._ship_host_drops()
        if any(linked):
            h = self.shared.hardening
            flags = ((protocol.RT_FLAG_GC_FROZEN if h.gc_frozen else 0)
                     | (protocol.RT_FLAG_DMA_LATENCY if h.dma_latency_held else 0)
                     | (protocol.RT_FLAG_AUDIT if self.shared.audit_installed else 0))
            # The collision guard state is the actuator's (its single-writer RobotState
            # field); without an actuator that has run a cycle there is none to report.
            robot = self._robot
            guard = 0
            if robot is not None and robot.actuator_cycles:
                flags |= protocol.RT_FLAG_GUARD_VALID
                guard = 1 if robot.guard_active else 0
            if status_linked and robot is not None and robot.guard_plan is not None:
                self._ship_safety(robot, now)
            trace = robot.fault_trace if robot is not None else None
            if status_linked and trace is not None and trace.fault != self.trace_sent:
                self._ship_trace(trace, now)
            size = protocol.encode_into(
                buf, 0, protocol.Kind.RT_STATUS, self.seq, now, 1 if fifo_all else 0,
                int(h.mem_locked), int(h.degraded or not fifo_all), guard, flags,
                len(self.shared.tasks),
                0 if cycles_min == 0xFFFFFFFF else cycles_min & 0xFFFFFFFF)
            self._send(size, _TO_ALL)
        self.batches += 1


def make_monitor(task: config.TaskConfig, ports: Mapping[str, Any],
                 shared: MonitorShared) -> StatsShipper:
    """Build the monitor body: ``status`` gets stats, devices and status; ``stat`` stats.

    ``params.device_stale_s`` (default 3 s): a device whose last DEVICE_STATUS is older is
    forwarded with level STALE.
    """
    rt = shared.config.runtime
    stale = (task.params or {}).get('device_stale_s', DEVICE_STALE_S)
    if (isinstance(stale, bool) or not isinstance(stale, (int, float))
            or not math.isfinite(stale) or stale <= 0):
        raise ValueError('tasks.{}.params.device_stale_s: must be a number > 0 (seconds), '
                         'got {!r}'.format(task.name, stale))
    pairs = [(ports[label], label != 'status') for label in task.ports]
    return StatsShipper(shared, pairs, rt.stats_batch, rt.max_datagram, int(stale * 1e9))
