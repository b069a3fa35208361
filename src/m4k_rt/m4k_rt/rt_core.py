"""The RT process: load config, harden, bind ports, build bodies, run the tasks until a signal.

Start-up order matters: everything that allocates, imports, opens files or prints happens
here, before the first task starts -- config, instance lock, hardening report (stderr), port
binding, body factories, GC freeze, forbidden-call audit hook and console guard. Inside the
loops the only way information leaves the process is the ``monitor`` task, which ships
timing samples and counters as datagrams on the ``status`` port (the bridge) and the ``stat``
port (``rt_stat``, opened on demand). No file I/O happens in the RT process after start-up.

Exit codes: 0 clean stop, 1 runtime failure (hardening required but degraded, a port could
not be bound, a body failed to build, a task did not stop), 2 configuration error or another
stack owning the runtime directory.
"""

import argparse
import dataclasses
import fcntl
import importlib
import json
import math
import os
import sys
import threading
from typing import Any, Mapping, Sequence

from m4k_rt import config, cycleprof, modeswitch, protocol, rosargs, sched, tasks, timing
from m4k_rt.stopsignals import run_stoppable, StopSignals
from m4k_rt.task import RtTask
from m4k_rt.tasks import register_body
from m4k_rt.tasks.portio import PortReader
from m4k_rt.tasks.state import DEVICE_SLOTS
from m4k_rt.timerfd import monotonic_ns

__all__ = ['InstanceLock', 'LockError', 'SharedState', 'StatsShipper', 'main', 'register_body']

BODY_MODULES_ENV = 'M4K_BODY_MODULES'
DRAIN_MONITOR = 1024  # datagrams drained per monitor port and cycle (1 s, lowest priority)
DEVICE_STALE_S = 3.0  # a device's last DEVICE_STATUS older than this is forwarded as STALE
# Which monitor ports a datagram goes to.
_TO_ALL = 0
_TO_STAT = 1      # only ports flagged extra (``stat``)
_TO_STATUS = 2    # only the others (``status``: the bridge)


class LockError(RuntimeError):
    """Another RT core owns the runtime directory."""


class InstanceLock:
    """An flock on ``<runtime_dir>/<owner>.lock`` holding the owner's pid.

    rt_core takes ``rt_core.lock``; bringup takes ``bringup.lock`` first, which closes the race
    between two stacks starting at once.
    """

    def __init__(self, runtime_dir: str, owner: str = 'rt_core') -> None:
        """Take the lock or raise :class:`LockError` naming the owner's pid."""
        self.path = os.path.join(runtime_dir, owner + '.lock')
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            try:
                pid = os.pread(fd, 32, 0).decode().strip() or '?'
            finally:
                os.close(fd)
            raise LockError('another m4k stack owns {} ({}pid {})'.format(
                runtime_dir, '' if owner == 'rt_core' else owner + ' ', pid)) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, '{}\n'.format(os.getpid()).encode(), 0)
        self._fd = fd

    def release(self) -> None:
        """Drop the lock (idempotent)."""
        if self._fd >= 0:
            fd, self._fd = self._fd, -1
            os.close(fd)


@dataclasses.dataclass
class SharedState:
    """What body factories get besides their own config and ports."""

    config: config.RtConfig
    hardening: sched.Hardening
    tasks: list[RtTask] = dataclasses.field(default_factory=list)
    stop_event: threading.Event = dataclasses.field(default_factory=threading.Event)
    audit_installed: bool = False    # the forbidden-call audit hook (RT_STATUS flags bit)
    robot: Any = None                # tasks.state.RobotState, set by the first robot body
    ports: dict[str, Any] = dataclasses.field(default_factory=dict)  # label -> RtXddpSocket
    runtime_dir: str = ''            # the sockets' directory (the e-stop request file's too)


class StatsShipper:
    """The monitor body: ship ring samples and counters of every task as datagrams.

    Runs at the lowest RT priority. Samples since the previous batch go out as TASK_STATS
    (chunked to ``batch`` samples and to the datagram limit), then TASK_HEALTH (with the
    body's ``unexpected`` count when it keeps one: valid datagrams of a kind its ports do not
    carry, this monitor's own included) and
    FORBIDDEN_SITE on ports flagged ``extra`` (the ``stat`` port), then -- on the other ports
    (``status``) -- one DEVICE_STATUS per device that ever reported (its last report, level
    STALE when older than ``device_stale_ns``, stamped with its arrival time) and one
    PORT_STATS per XDDP port of the process (``shared.ports``: its RT-side counters), then
    RT_STATUS, which closes a batch. Nothing is encoded when no port has a peer; cursors move
    on regardless.
    """

    def __init__(self, shared: SharedState, ports: Sequence[tuple[Any, bool]],
                 batch: int = 128, max_datagram: int = 4096,
                 device_stale_ns: int = int(DEVICE_STALE_S * 1e9)) -> None:
        """Preallocate the datagram buffer; ``ports`` are (socket, extra) pairs."""
        self.shared = shared
        self.ports = list(ports)
        self.device_stale_ns = device_stale_ns
        # (device name as bytes, RobotState attribute of its report, attribute of its arrival)
        self._devices = [(name.encode(), status, rx)
                         for name, (status, rx) in DEVICE_SLOTS.items()]
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
            size = protocol.encode_into(
                buf, 0, protocol.Kind.RT_STATUS, self.seq, now, 1 if fifo_all else 0,
                int(h.mem_locked), int(h.degraded or not fifo_all), guard, flags,
                len(self.shared.tasks),
                0 if cycles_min == 0xFFFFFFFF else cycles_min & 0xFFFFFFFF)
            self._send(size, _TO_ALL)
        self.batches += 1


def make_monitor(task: config.TaskConfig, ports: Mapping[str, Any],
                 shared: SharedState) -> StatsShipper:
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


register_body('monitor', make_monitor)


def _err(msg: str) -> None:
    sys.stderr.write('rt_core: {}\n'.format(msg))
    sys.stderr.flush()


def _parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog='rt_core', description='m4k real-time core process.')
    ap.add_argument('--config', metavar='FILE', help='user overlay YAML (merged last)')
    ap.add_argument('--config-dir', metavar='DIR', help='config directory (default: found)')
    ap.add_argument('--require-rt', action='store_true',
                    help='exit 1 when SCHED_FIFO, mlockall or other hardening is not granted')
    ap.add_argument('--tasks', metavar='A,B', help='run only these tasks (monitor always runs)')
    ap.add_argument('--echo', action='store_true', help='use echo bodies for all but monitor')
    ap.add_argument('--duration', type=float, metavar='S', help='stop after S seconds')
    ap.add_argument('--body-module', action='append', default=[], metavar='MOD',
                    help='import MOD first (it may call register_body); also $' +
                    BODY_MODULES_ENV)
    ap.add_argument('--cycle-profile', metavar='FILE', default=cycleprof.env_path(),
                    help='time the parts of every task cycle (m4k_rt.cycleprof) and write '
                    'the breakdown as JSON to FILE at exit; also $' + cycleprof.ENV)
    return rosargs.parse_args(ap, argv)


def _select(cfg: config.RtConfig, names: str | None,
            echo: bool) -> list[config.TaskConfig]:
    chosen = list(cfg.tasks)
    if names:
        wanted = [n.strip() for n in names.split(',') if n.strip()]
        known = {t.name for t in cfg.tasks}
        for n in wanted:
            if n not in known:
                raise config.ConfigError('--tasks', 'unknown task {!r} (configured: {})'.format(
                    n, ', '.join(sorted(known))), n)
        chosen = [t for t in cfg.tasks if t.name in wanted or t.body == 'monitor']
    if echo:
        chosen = [t if t.body == 'monitor' else dataclasses.replace(t, body='echo')
                  for t in chosen]
    return chosen


def main(argv: Sequence[str] | None = None) -> int:
    """Run the RT process; return the exit code."""
    return run_stoppable('rt_core', lambda stop: _main(_parse_args(argv), stop))


def _main(args: argparse.Namespace, stop: StopSignals) -> int:
    mods = list(args.body_module) + [m for m in os.environ.get(BODY_MODULES_ENV, '').split(',')
                                     if m.strip()]
    for mod in mods:
        try:
            importlib.import_module(mod.strip())
        except Exception as exc:  # noqa: BLE001 -- report any plug-in failure as one line
            _err('cannot import body module {!r}: {}'.format(mod, exc))
            return 2
    try:
        cfg = config.load(args.config, args.config_dir, body_exists=tasks.body_exists)
        chosen = _select(cfg, args.tasks, args.echo)
    except config.ConfigError as exc:
        _err('config error: {}'.format(exc))
        return 2
    rt = cfg.runtime
    cycleprof.enable(bool(args.cycle_profile))  # before any task, reader or writer is built
    from m4k_rt import xddp  # bound here so a config error exits before any socket work
    try:
        runtime_dir = xddp.ensure_runtime_dir(rt.runtime_dir, rt.group)
    except OSError as exc:
        _err('cannot create runtime dir: {}'.format(exc))
        return 1
    try:
        lock = InstanceLock(runtime_dir)
    except LockError as exc:
        _err(str(exc))
        return 2
    socks: list[Any] = []
    try:
        return _run(args, cfg, chosen, runtime_dir, socks, stop)
    finally:
        for s in socks:
            s.close()
        lock.release()


def _run(args: argparse.Namespace, cfg: config.RtConfig, chosen: list[config.TaskConfig],
         runtime_dir: str, socks: list[Any], stop: StopSignals) -> int:
    from m4k_rt import xddp
    rt = cfg.runtime
    if stop.stopping:
        return 0
    hard = sched.harden(priority=max(t.priority for t in chosen), mlockall=rt.mlockall,
                        cpu_dma_latency=rt.cpu_dma_latency,
                        switch_interval_s=rt.switch_interval_s)
    try:
        for line in hard.lines():
            _err(line)
        if (args.require_rt or rt.require_rt) and hard.degraded:
            _err('--require-rt: refusing to run degraded')
            return 1
        shared = SharedState(cfg, hard, stop_event=stop.event, runtime_dir=runtime_dir)
        built: list[tuple[config.TaskConfig, Any]] = []
        for t in chosen:
            ports = {}
            for label in t.ports:
                try:
                    s = xddp.rt_xddp_bind(cfg.ports[label], label, poolsz=rt.poolsz,
                                          max_datagram=rt.max_datagram, runtime_dir=runtime_dir,
                                          max_ports=rt.max_ports, group=rt.group)
                except OSError as exc:
                    _err('cannot bind port {} ({!r}) for task {}: {}'.format(
                        cfg.ports[label], label, t.name, exc))
                    return 1
                socks.append(s)
                ports[label] = s
                shared.ports[label] = s
            try:
                body = tasks.get_factory(t.body)(t, ports, shared)
            except Exception as exc:  # noqa: BLE001 -- one line naming the task, then exit
                _err('task {}: body {!r} failed to build: {}: {}'.format(
                    t.name, t.body, type(exc).__name__, exc))
                return 1
            built.append((t, body))
            if stop.stopping:  # nothing runs yet: outputs were never driven
                return 0
        start = timing.first_release(monotonic_ns(), 1_000_000,
                                     lead_ns=int(rt.start_delay_ms * 1e6))
        for i, (t, body) in enumerate(built):
            shared.tasks.append(RtTask(t.name, t.priority, t.period_ns, body, cpu=t.cpu,
                                       start_ns=start + t.offset_ns,
                                       ring_capacity=rt.ring_capacity, index=i))
        return _serve(args, shared)
    finally:
        hard.close()


def _serve(args: argparse.Namespace, shared: SharedState) -> int:
    modeswitch.install()
    modeswitch.install_console_guard()
    shared.audit_installed = True
    sched.freeze_gc(shared.hardening)
    stop = shared.stop_event
    try:
        for t in shared.tasks:
            t.start()
        _err('gc frozen and disabled; running {} tasks: {}'.format(len(shared.tasks), ', '.join(
            '{}({} ms, prio {}{})'.format(t.name, t.period_ns / 1e6, t.priority,
                                          '' if t.fifo else ', NOT FIFO: ' + str(t.sched_error))
            for t in shared.tasks)))
        stop.wait(args.duration)
    finally:
        for t in shared.tasks:
            t.stop()
        stuck = [t.name for t in shared.tasks if not t.join(2.0 * t.period_ns / 1e9 + 1.0)]
        modeswitch.uninstall_console_guard()
        sched.unfreeze_gc()
    for t in shared.tasks:
        if isinstance(t.body, StatsShipper):
            t.body.ship()  # the tail of every ring, now that no task runs
    for t in shared.tasks:
        c = t.counters()
        _err('task {name}: cycles {cycles} overruns {overruns} misses {deadline_misses} '
             'body errors {body_errors} forbidden {forbidden_calls} csw vol+ {nvcsw_extra} '
             'invol {nivcsw} pf {minflt}/{majflt}'.format(**c)
             + ('' if not t.last_error else ' last error {!r} at {}'.format(
                 t.last_error, t.last_error_site)))
    if args.cycle_profile:
        _write_profile(args.cycle_profile, shared.tasks)
    if stuck:
        _err('tasks did not stop in time: {}'.format(', '.join(stuck)))
        return 1
    return 0


def _write_profile(path: str, rt_tasks: Sequence[RtTask]) -> None:
    """Write every task's cycle breakdown (µs per cycle) as JSON; one line each to stderr."""
    out = {'tasks': {t.name: dict(t.profile.summary(), period_ns=t.period_ns)
                     for t in rt_tasks if t.profile is not None}}
    for name, s in out['tasks'].items():
        _err('task {}: cycle profile (us per cycle) {}, thread CPU {}'.format(
            name, ' '.join('{} {:.1f}'.format(k, v) for k, v in s.get('parts_us', {}).items()),
            'n/a' if s.get('thread_cpu_per_cycle_us') is None
            else '{:.1f}'.format(s['thread_cpu_per_cycle_us'])))
    try:
        with open(path, 'w', encoding='utf-8') as f:
            json.dump(out, f, indent=1)
            f.write('\n')
    except OSError as exc:
        _err('cannot write the cycle profile to {}: {}'.format(path, exc))


if __name__ == '__main__':
    sys.exit(main())
