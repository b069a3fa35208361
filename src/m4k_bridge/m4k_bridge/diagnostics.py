"""RT timing and health -> m4k_msgs/RtStatus and diagnostic_msgs (pure: no rclpy, no sockets).

The RT monitor task ships each task's per-cycle samples in TASK_STATS batches, plus RT_STATUS,
the last DEVICE_STATUS and HOST_DROPS of each device (and, on ``stat``, the TASK_HEALTH extra
kind).
:class:`RtMonitor` keeps a sliding window of samples per task (``stats_window`` seconds of
releases) and computes the paper's statistics with :func:`m4k_rt.timing.analyze` -- the same
code the recorder and the benchmarks use -- then the Liu-Layland and response-time tests of
:mod:`m4k_rt.timing`.

Diagnostic levels follow REP-107: OK, WARN (deadline misses, overruns or forbidden calls in
the window), ERROR (the task stopped cycling while the RT process is alive), STALE (nothing
heard within ``stale_s``).
"""

from __future__ import annotations

import collections
import math
from typing import Any, Iterable, Mapping

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

from m4k_bridge.hostdrops import HostDropMonitor
from m4k_msgs.msg import RtStatus, TaskTiming, TimingStats, XddpPort
from m4k_rt import protocol, timing

__all__ = ['LEVELS', 'RtMonitor', 'TaskWindow', 'degraded_reasons', 'level_byte', 'make_status',
           'timing_stats']

LEVELS = {int(v): v.name for v in protocol.Level}
# DEVICE_STATUS.state and .last_error names (protocol.DeviceState / DeviceError own the codes).
DEVICE_STATES = {int(v): v.name.lower() for v in protocol.DeviceState}
DEVICE_ERRORS = {int(v): v.name.lower().replace('_', ' ') for v in protocol.DeviceError}
_NS = 1e-9


def level_byte(level: int) -> bytes:
    """Return the DiagnosticStatus level byte for a protocol LEVEL_* value."""
    return bytes((min(max(int(level), 0), 3),))


def make_status(name: str, level: int, message: str, values: Mapping[str, Any],
                hardware_id: str = 'm4k') -> DiagnosticStatus:
    """Build a DiagnosticStatus with key-values rendered as text."""
    st = DiagnosticStatus(name=name, level=level_byte(level), message=message,
                          hardware_id=hardware_id)
    st.values = [KeyValue(key=str(k), value=_fmt(v)) for k, v in values.items()]
    return st


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return 'nan' if math.isnan(v) else '{:.6g}'.format(v)
    return str(v)


def timing_stats(s: timing.Stats) -> TimingStats:
    """Convert nanosecond Stats into a TimingStats message in seconds (zeros when empty)."""
    if s.n == 0:
        return TimingStats()
    return TimingStats(samples=s.n, avg=s.avg * _NS, std=s.std * _NS, min=s.min * _NS,
                       max=s.max * _NS, p50=s.p50 * _NS, p99=s.p99 * _NS, p999=s.p999 * _NS)


def degraded_reasons(rs: protocol.RtStatus) -> list[str]:
    """Return what RT_STATUS says is missing from the RT hardening."""
    out = []
    if rs.policy != 1:
        out.append('SCHED_FIFO not granted to every RT thread')
    if not rs.mem_locked:
        out.append('memory not locked (mlockall off or refused)')
    if not rs.flags & protocol.RT_FLAG_GC_FROZEN:
        out.append('garbage collector not frozen')
    if not rs.flags & protocol.RT_FLAG_DMA_LATENCY:
        out.append('/dev/cpu_dma_latency not held')
    return out or ['RT hardening degraded (see the rt_core log)']


class TaskWindow:
    """The last ``window_ns`` of releases of one task, plus its latest counters."""

    def __init__(self, name: str, window_ns: int) -> None:
        self.name = name
        self.window_ns = window_ns
        self.rows: collections.deque[tuple[int, int, int, int]] = collections.deque()
        self.stats: protocol.TaskStats | None = None
        self.health: protocol.TaskHealth | None = None
        self.last_site = ''
        self.rx_ns = 0               # CLOCK_MONOTONIC of the last batch (0 = never)
        self.prev_cycles = -1
        self.stalled = False         # cycles did not advance between two batches
        self.duplicates = 0

    def add(self, st: protocol.TaskStats, rx_ns: int) -> None:
        """Append the new samples of a TASK_STATS batch and trim the window."""
        if self.stats is not None:
            self.stalled = st.cycles == self.stats.cycles and not st.samples
            if st.cycles < self.stats.cycles:  # the RT process restarted: start afresh
                self.rows.clear()
        self.stats = st
        self.rx_ns = rx_ns
        last = self.rows[-1][0] if self.rows else None
        for s in st.samples:
            if last is not None and s.t_rel <= last:
                self.duplicates += 1
                continue
            self.rows.append((s.t_rel, s.t_start, s.t_end, s.expirations))
            last = s.t_rel
        if self.rows:
            oldest = self.rows[-1][0] - self.window_ns
            while self.rows and self.rows[0][0] < oldest:
                self.rows.popleft()

    def analyze(self) -> timing.TaskTiming:
        """Return the timing analysis of the window."""
        period = self.stats.period_ns if self.stats is not None and self.stats.period_ns else 1
        if not self.rows:
            return timing.analyze([], [], [], [], period, self.name)
        cols = list(zip(*self.rows, strict=True))
        return timing.analyze(cols[0], cols[1], cols[2], cols[3], period, self.name)


class RtMonitor:
    """Accumulate what the RT process reports and turn it into ROS messages."""

    def __init__(self, window_s: float = 10.0, stale_s: float = 3.0) -> None:
        self.window_ns = int(window_s * 1e9)
        self.stale_ns = int(stale_s * 1e9)
        self.tasks: dict[str, TaskWindow] = {}
        self.rt_status: protocol.RtStatus | None = None
        self.rt_status_rx_ns = 0
        # device -> (last DEVICE_STATUS, bridge rx ns, RT arrival ns = its header stamp)
        self.devices: dict[str, tuple[protocol.DeviceStatus, int, int]] = {}
        self.ports: dict[int, tuple[protocol.PortStats, int]] = {}  # port -> (stats, rx ns)
        self.host_drops = HostDropMonitor(window_s, stale_s)

    def set_window(self, window_s: float) -> None:
        """Change the sliding window (takes effect with the next batch)."""
        self.window_ns = int(window_s * 1e9)
        for t in self.tasks.values():
            t.window_ns = self.window_ns
        self.host_drops.window_ns = self.window_ns

    def _task(self, name: str) -> TaskWindow:
        t = self.tasks.get(name)
        if t is None:
            t = self.tasks[name] = TaskWindow(name, self.window_ns)
        return t

    def feed(self, kind: int, payload: Any, rx_ns: int, stamp_ns: int | None = None) -> bool:
        """Account one decoded datagram; return False when the kind is not one of ours.

        ``stamp_ns`` is the datagram's header stamp (CLOCK_MONOTONIC, same host); for
        DEVICE_STATUS the monitor sets it to when the RT device task received the report.
        """
        if kind == protocol.Kind.TASK_STATS:
            self._task(payload.name).add(payload, rx_ns)
        elif kind == protocol.Kind.RT_STATUS:
            self.rt_status, self.rt_status_rx_ns = payload, rx_ns
        elif kind == protocol.Kind.DEVICE_STATUS:
            self.devices[payload.device] = (payload, rx_ns,
                                            rx_ns if stamp_ns is None else stamp_ns)
        elif kind == protocol.Kind.PORT_STATS:
            self.ports[payload.port] = (payload, rx_ns)
        elif kind == protocol.Kind.HOST_DROPS:
            self.host_drops.feed(payload, rx_ns, rx_ns if stamp_ns is None else stamp_ns)
        elif kind == protocol.Kind.TASK_HEALTH:
            self._task(payload.name).health = payload
        elif kind == protocol.Kind.FORBIDDEN_SITE:
            self._task(payload.name).last_site = '{} at {}:{} in {}'.format(
                payload.event, payload.file, payload.line, payload.func)
        else:
            return False
        return True

    def _ordered(self) -> list[tuple[TaskWindow, protocol.TaskStats]]:
        # The tasks that reported, with their last TASK_STATS; highest priority first, as
        # RtStatus.tasks documents.
        reported = [(t, t.stats) for t in self.tasks.values() if t.stats is not None]
        return sorted(reported, key=lambda ts: (-ts[1].priority, ts[1].task_index))

    def task_timing(self, t: TaskWindow) -> tuple[TaskTiming, timing.TaskTiming]:
        """Return the TaskTiming message of one task and the analysis behind it."""
        a = t.analyze()
        st = t.stats
        assert st is not None
        period_s = st.period_ns * _NS
        msg = TaskTiming(name=t.name, priority=st.priority, cpu=st.cpu, period=period_s,
                         cycles=st.cycles)
        msg.release_latency = timing_stats(a.latency)
        msg.period_measured = timing_stats(a.period)
        msg.jitter = timing_stats(a.jitter)
        msg.response_time = timing_stats(a.response)
        wcrt = a.wcrt_ns
        msg.utilization = 0.0 if math.isnan(wcrt) or not st.period_ns else wcrt / st.period_ns
        h = t.health
        msg.overruns = h.overruns if h is not None else a.overruns
        msg.deadline_misses = h.deadline_misses if h is not None else a.deadline_misses
        msg.body_errors = h.body_errors if h is not None else 0
        # Without TASK_HEALTH, approximate "voluntary switches beyond one per cycle".
        msg.voluntary_switches = (h.nvcsw_extra if h is not None
                                  else max(0, st.nvcsw - st.cycles))
        msg.involuntary_switches = st.nivcsw
        msg.page_faults = st.minflt + (h.majflt if h is not None else 0)
        msg.forbidden_calls = st.forbidden_calls
        msg.last_forbidden_call = t.last_site
        return msg, a

    def collision_guard(self, now_ns: int) -> bool | None:
        """Return the RT collision guard state from a fresh RT_STATUS, else None.

        None means "unknown here": no RT_STATUS yet, the last one is older than the stale
        timeout, or it comes from an RT process without an actuator (or from an older one
        whose ``guard_active`` was the forbidden-call audit flag): RT_FLAG_GUARD_VALID clear.
        """
        rs = self.rt_status
        if (rs is None or not rs.flags & protocol.RT_FLAG_GUARD_VALID
                or now_ns - self.rt_status_rx_ns > self.stale_ns):
            return None
        return bool(rs.guard_active)

    def rt_status_msg(self, now_ns: int, link_age_s: float,
                      guard_fallback: bool = False) -> RtStatus:
        """Build RtStatus (without header and ports, which the node fills in).

        ``collision_guard_active`` comes from RT_STATUS (see :meth:`collision_guard`);
        ``guard_fallback`` (the caller's inference from ODOMETRY flags) is used only when
        RT_STATUS does not tell.
        """
        msg = RtStatus()
        rs = self.rt_status
        if rs is not None:
            msg.policy = rs.policy
            msg.memory_locked = bool(rs.mem_locked)
            msg.degraded = bool(rs.degraded)
            if rs.degraded:
                msg.degraded_reasons = degraded_reasons(rs)
        guard = self.collision_guard(now_ns)
        msg.collision_guard_active = guard_fallback if guard is None else guard
        msg.rt_link_age = float(link_age_s)
        tasks = []
        rta_in = []
        misses = 0
        for t, st in self._ordered():
            m, a = self.task_timing(t)
            tasks.append(m)
            misses += a.deadline_misses
            if not math.isnan(a.wcrt_ns) and st.period_ns:
                rta_in.append(timing.RtaTask(t.name, a.wcrt_ns, st.period_ns, st.priority))
        msg.tasks = tasks
        if rta_in:
            u = timing.utilization_test([(r.name, r.wcet_ns, r.period_ns) for r in rta_in])
            msg.total_utilization = u.total
            msg.liu_layland_bound = u.bound
            rta_ok = all(r.schedulable for r in timing.response_time_analysis(rta_in))
            msg.schedulable = misses == 0 and (u.passes or rta_ok)
        return msg

    def task_statuses(self, now_ns: int, prefix: str = 'm4k_rt') -> list[DiagnosticStatus]:
        """Return one DiagnosticStatus per RT task."""
        out = []
        for t, st in self._ordered():
            m, a = self.task_timing(t)
            age = (now_ns - t.rx_ns) * _NS
            values = {'period_s': m.period, 'priority': m.priority, 'cycles': m.cycles,
                      'window_samples': a.cycles,
                      'jitter_max_s': m.jitter.max, 'jitter_p99_s': m.jitter.p99,
                      'latency_max_s': m.release_latency.max,
                      'response_max_s': m.response_time.max, 'utilization': m.utilization,
                      'overruns': m.overruns, 'deadline_misses': m.deadline_misses,
                      'window_deadline_misses': a.deadline_misses,
                      'forbidden_calls': m.forbidden_calls, 'last_report_age_s': age}
            if age > self.stale_ns * _NS:
                level, msg = protocol.LEVEL_STALE, 'no timing report for {:.1f} s'.format(age)
            elif t.stalled:
                level, msg = protocol.LEVEL_ERROR, 'task stopped cycling'
            elif a.deadline_misses or a.overruns or st.forbidden_calls:
                level = protocol.LEVEL_WARN
                msg = '{} deadline misses, {} overruns in window, {} forbidden calls'.format(
                    a.deadline_misses, a.overruns, st.forbidden_calls)
            else:
                level, msg = protocol.LEVEL_OK, 'running'
            out.append(make_status('{}: task {}'.format(prefix, t.name), level, msg, values,
                                   hardware_id='m4k_rt'))
        return out

    def host_drop_statuses(self, now_ns: int,
                           prefix: str = 'm4k_drivers') -> list[DiagnosticStatus]:
        """Return one ``<prefix>: <device> host drops`` status per device that reported.

        From the driver host's drop counters (HOST_DROPS); :mod:`m4k_bridge.hostdrops`
        judges them.
        """
        return [make_status('{}: {} host drops'.format(prefix, name), level, msg, values,
                            hardware_id='driver_host')
                for name, level, msg, values in self.host_drops.levels(now_ns)]

    def device_levels(self, now_ns: int) -> Iterable[tuple[str, int, str, dict[str, Any]]]:
        """Yield (device, level, message, values) from the forwarded DEVICE_STATUS reports.

        The level is the report's (REP-107: 0 OK, 1 WARN, 2 ERROR, 3 STALE -- the RT monitor
        already sends STALE when the driver host stopped reporting); STALE as well when the
        monitor itself stopped forwarding (nothing within ``stale_s``). Values: ``state`` and
        ``last_error`` by name, ``faults``, ``age_s`` (since the RT side got the report).
        """
        for name, (d, rx, stamp) in sorted(self.devices.items()):
            age = max(now_ns - stamp, 0) * _NS
            values = {'state': DEVICE_STATES.get(d.state, str(d.state)), 'faults': d.faults,
                      'last_error': DEVICE_ERRORS.get(d.last_error, str(d.last_error)),
                      'age_s': age}
            if now_ns - rx > self.stale_ns:
                level = protocol.LEVEL_STALE
                msg = 'no device report from the RT process for {:.1f} s'.format(
                    (now_ns - rx) * _NS)
            elif d.level == protocol.LEVEL_STALE:
                level, msg = d.level, 'driver silent for {:.1f} s'.format(age)
            else:
                level = d.level
                msg = '{} ({})'.format(LEVELS.get(level, level), values['state'])
                if d.last_error:
                    msg += ', last error: {}'.format(values['last_error'])
            yield name, level, msg, values

    def port_msgs(self, now_ns: int) -> list[XddpPort]:
        """Return the RT side's per-port counters (PORT_STATS) as XddpPort, by port number.

        A port not reported within ``stale_s`` of the newest report belonged to an earlier
        RT process and is dropped; when every report is stale (the RT process is gone) the
        last counters stay, with ``linked`` false. Ports above 255 do not fit the message.
        """
        if not self.ports:
            return []
        newest = max(rx for _, rx in self.ports.values())
        for port in [n for n, (_, rx) in self.ports.items() if newest - rx > self.stale_ns]:
            del self.ports[port]
        fresh = now_ns - newest <= self.stale_ns
        out = []
        for port, (ps, _) in sorted(self.ports.items()):
            if port > 255:
                continue
            out.append(XddpPort(
                port=port, label=ps.label, linked=fresh and bool(ps.linked), sent=ps.sent,
                received=ps.received, dropped_no_peer=ps.dropped_no_peer,
                dropped_full=ps.dropped_full, dropped_oversize=ps.dropped_oversize,
                malformed=ps.malformed, peer_restarts=ps.peer_restarts))
        return out
